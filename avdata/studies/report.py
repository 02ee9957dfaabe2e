"""Study reports: mean +/- standard deviation over trials per case (Markdown, CSV) and plots."""

from __future__ import annotations

import io
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any, cast

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import yaml

from avdata.errors import InputError, one_line, shown
from avdata.executors.folder import OutputFolder
from avdata.executors.store import staging_folder
from avdata.inputs import require_file
from avdata.outputs import write_atomically
from avdata.storage import Location
from avdata.studies.config import CASE_AXES, METRICS, OPTIONAL_METRICS

__all__ = ["aggregate", "write_report"]


def aggregate(results: pa.Table, case_order: list[str] | None = None) -> list[dict[str, object]]:
    """One row per case (and dataset, in a multi-dataset study): its axes and per metric the mean and std.

    The standard deviation is the sample one (ddof 1) over the trials.

    Args:
        results: ``results.parquet`` (one row per case and trial).
        case_order: cases in this order (default: first appearance).

    Returns:
        Rows with ``case``, ``dataset`` (when the results have several), ``trials``, ``axis_*`` values and
        ``<metric>_mean`` / ``<metric>_std``.
    """
    if "case" not in results.column_names:
        raise InputError(f"results: expected a 'case' column, got {results.column_names}")
    data = results.to_pydict()
    cases = case_order or list(dict.fromkeys(data["case"]))
    datasets = list(dict.fromkeys(data.get("dataset") or [None]))
    per_dataset = len(datasets) > 1
    rows: list[dict[str, object]] = []
    for case, dataset in ((c, d) for c in cases for d in datasets):
        idx = [i for i, c in enumerate(data["case"]) if c == case and (not per_dataset or data["dataset"][i] == dataset)]
        if not idx:
            continue
        row: dict[str, object] = {"case": case, **({"dataset": dataset} if per_dataset else {}), "trials": len(idx)}
        for axis in CASE_AXES:
            if f"axis_{axis}" in data:
                row[axis] = data[f"axis_{axis}"][idx[0]]
        if "detector" in data:
            row["detector"] = data["detector"][idx[0]]
        for metric in METRICS:
            if metric not in data:
                continue
            values = np.array([np.nan if data[metric][i] is None else data[metric][i] for i in idx], dtype=float)
            finite = values[np.isfinite(values)]
            row[f"{metric}_mean"] = float(finite.mean()) if len(finite) else math.nan
            row[f"{metric}_std"] = float(finite.std(ddof=1)) if len(finite) > 1 else (0.0 if len(finite) else math.nan)
        rows.append(row)
    return rows


def _cell(mean: float, std: float) -> str:
    return "N/A" if not math.isfinite(mean) else f"{mean:.2f} +/- {std:.2f}"


def write_report(out: str | Path | Location) -> list[Path] | list[Location]:
    """Writes ``report.md``, ``report.csv``, one PNG per planned plot and ``report.html`` into ``out``; returns the files.

    ``out`` in an object store: the report is made in a local staging folder from ``results.parquet`` and
    ``study.yaml`` (fetched), then each file is published whole, in that order (:class:`OutputFolder`); the page
    has no pictures of the trial scenes there (they are drawn from local trial folders).
    """
    folder = OutputFolder.of(out)
    if folder.store is None:
        return _write_report(Path(folder.root))
    with staging_folder() as staging:
        for name in ("results.parquet", "study.yaml"):
            found = folder.read_bytes(name)
            if found is not None:
                (staging / name).write_bytes(found)
        if not (staging / "results.parquet").is_file():
            raise InputError(f"{folder.store / 'results.parquet'}: expected the results of 'avdata study run', got no "
                             "such object")
        made = _write_report(staging)
        for path in made:
            folder.write(path.name, path.read_bytes())
    return [folder.store / path.name for path in made]


def _write_report(out: Path) -> list[Path]:
    """:func:`write_report` into the local folder ``out``."""
    results_path = out / "results.parquet"
    # require_file, not Path.is_file: that raised for a name too long (a traceback)
    require_file(results_path, "results file of 'avdata study run'",
                 missing="expected the results of 'avdata study run', got no such file")
    try:
        results = pq.read_table(results_path)
    except (OSError, pa.ArrowInvalid) as exc:
        raise InputError(f"{out}: cannot read the study results ({exc.__class__.__name__}: {exc})") from None
    study = _read_study(out / "study.yaml")
    _check_results(results, results_path)
    case_order = [c["name"] for c in study.get("cases", [])]
    rows = aggregate(results, case_order)
    metrics = [m for m in METRICS if rows and f"{m}_mean" in rows[0]
               and (m not in OPTIONAL_METRICS or any(math.isfinite(cast(float, r[f"{m}_mean"])) for r in rows))]
    axes = [a for a in CASE_AXES if rows and a in rows[0]]
    written = []
    keys = ["case", *(["dataset"] if rows and "dataset" in rows[0] else []), "trials"]
    if keys[1] == "dataset":  # a transfer table: which components ran, not the collaboration axes
        axes = [a for a in ("detector",) if a in rows[0]]
    header = [*keys, *axes, *metrics]
    lines = [f"# Study {study.get('name', out.name)}", "", str(study.get("description", "")).strip(), "",
             _trials_line(study), "",
             "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        cells = [str(row[k]) for k in keys] + ["-" if row.get(a) is None else str(row.get(a)) for a in axes]
        cells += [_cell(float(row[f"{m}_mean"]), float(row[f"{m}_std"])) for m in metrics]  # type: ignore[arg-type]  # summary rows hold numbers
        lines.append("| " + " | ".join(cells) + " |")
    write_atomically(out / "report.md", "\n".join(lines) + "\n")
    written.append(out / "report.md")
    csv_header = [*keys, *axes] + [f"{m}_{s}" for m in metrics for s in ("mean", "std")]
    csv = [",".join(csv_header)] + [",".join("" if row.get(c) is None else str(row.get(c)) for c in csv_header) for row in rows]
    write_atomically(out / "report.csv", "\n".join(csv) + "\n")
    written.append(out / "report.csv")
    for metric, axis in study.get("plots", []) or []:
        absent = [c for c, ok in ((metric, metric in metrics), (f"axis_{axis}", axis in axes)) if not ok]
        if absent:
            raise InputError(f"{results_path}: plot {metric} vs {axis}: expected column(s) {absent}, got none")
        written.append(_plot(out, rows, metric, axis, axes))
    from avdata.viz.study_page import write_study_page  # the web page of report.csv and the plots (avdata.viz)

    written.append(write_study_page(out, written))
    return written


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _list_of(item: Callable[[Any], bool]) -> Callable[[Any], bool]:
    return lambda value: isinstance(value, list) and all(item(v) for v in value)


#: The fields of ``study.yaml`` the report reads: field -> (what it must be, its check).
_STUDY_FIELDS: dict[str, tuple[str, Callable[[Any], bool]]] = {
    "cases": ("a list of cases with a name", _list_of(lambda c: isinstance(c, dict) and isinstance(c.get("name"), str))),
    "plots": ("a list of [metric, axis] pairs",
              _list_of(lambda p: isinstance(p, list) and len(p) == 2 and all(isinstance(n, str) for n in p))),
    "seed": ("an integer", _is_int),
    "trials": ("an integer", _is_int),
    "dataset": ("a dataset path or null", lambda d: d is None or isinstance(d, str)),
    "scenes": ("a list of scene names", _list_of(lambda n: isinstance(n, str))),
    "datasets": ("a list of datasets with a name and scenes",
                 _list_of(lambda d: isinstance(d, dict) and isinstance(d.get("name"), str)
                          and _list_of(lambda n: isinstance(n, str))(d.get("scenes")))),
}


def _read_study(path: Path) -> dict[str, Any]:
    """``study.yaml`` as ``avdata study run`` wrote it, the fields the report reads checked.

    It lies in the output folder and can be damaged between run and report: ``cases: 5``, ``seed: x`` or a list
    for the whole file were tracebacks.
    """
    try:
        study = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise InputError(f"{path}: expected the study file of 'avdata study run', got {exc.__class__.__name__}: "
                         f"{one_line(exc)}") from None
    if not isinstance(study, dict):
        raise InputError(f"{path}: expected the study file of 'avdata study run' (a mapping), got {shown(study)}")
    for name, (expected, ok) in _STUDY_FIELDS.items():
        if name in study and not ok(study[name]):
            raise InputError(f"{path}: field {name}: expected {expected}, got {shown(study[name])}")
    return study


def _check_results(results: pa.Table, path: Path) -> None:
    """Refuses results that would average into a wrong report: a (case, trial) twice, a NaN, an edited row.

    The runner stores a metric that does not apply as null, so a NaN or infinity is damage; a row whose
    ``checksum`` does not match its content was changed after the run.
    """
    from avdata.studies.runner import result_checksum

    missing = [c for c in ("case", "trial", "checksum") if c not in results.column_names]
    if missing:  # the runner writes every row's checksum: without the column, edited rows would pass unseen
        raise InputError(f"{path}: expected columns 'case', 'trial' and 'checksum', got no {missing}")
    seen: set[tuple[object, object]] = set()
    for i, row in enumerate(results.to_pylist()):
        key = (row["case"], row["trial"])
        if key in seen:
            raise InputError(f"{path}: row {i}: case {key[0]!r} trial {key[1]} appears twice")
        seen.add(key)
        bad = [m for m in METRICS if isinstance(row.get(m), float) and not math.isfinite(row[m])]
        if bad:
            raise InputError(f"{path}: row {i} (case {key[0]!r}, trial {key[1]}): expected finite metrics or null, "
                             f"got {bad[0]} = {row[bad[0]]}")
        if row["checksum"] != result_checksum(row):
            raise InputError(f"{path}: row {i} (case {key[0]!r}, trial {key[1]}): checksum does not match the row "
                             "(edited after the run?)")


def _trials_line(study: dict[str, Any]) -> str:
    if study.get("datasets"):
        return "Mean +/- standard deviation over the scenes of each dataset: " + "; ".join(
            f"{d['name']} ({len(d['scenes'])} scene{'s' if len(d['scenes']) != 1 else ''})" for d in study["datasets"]) + "."
    if study.get("dataset"):
        return (f"Mean +/- standard deviation over trials: the scenes {', '.join(study.get('scenes', []))} of "
                f"{study['dataset']}.")
    first = int(study.get("seed", 0))
    last = first + int(study.get("trials", 1)) - 1
    return (f"Mean +/- standard deviation over trials: generated scenes with seeds {first}..{last},"
            f" {study.get('frames')} frames each (preset {study.get('preset')}).")


def _plot(out: Path, rows: list[dict[str, object]], metric: str, axis: str, axes: list[str]) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # Lines are labelled only by the axes that vary between cases; constant settings would be noise.
    others = [a for a in axes if a != axis and len({repr(r.get(a)) for r in rows}) > 1]
    fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
    groups: dict[tuple[Any, ...], list[dict[str, object]]] = {}
    baselines = []
    for row in rows:
        if row.get(axis) is None:  # no value on this axis (e.g. no collaboration): a horizontal reference line
            baselines.append(row)
            continue
        groups.setdefault(tuple(row.get(a) for a in others), []).append(row)
    for key, members in groups.items():
        members.sort(key=lambda r: float(r[axis]))  # type: ignore[arg-type]  # summary rows hold numbers
        x = [float(r[axis]) for r in members]  # type: ignore[arg-type]  # summary rows hold numbers
        y = [float(r[f"{metric}_mean"]) for r in members]  # type: ignore[arg-type]  # summary rows hold numbers
        e = [float(r[f"{metric}_std"]) for r in members]  # type: ignore[arg-type]  # summary rows hold numbers
        label = ", ".join(f"{a}={v}" for a, v in zip(others, key, strict=True)) or metric
        ax.errorbar(x, y, yerr=e, marker="o", capsize=3, label=label)
        for r, xi, yi in zip(members, x, y, strict=True):
            ax.annotate(str(r["case"]), (xi, yi), textcoords="offset points", xytext=(5, 5), fontsize=7)
    for row in baselines:
        ax.axhline(float(row[f"{metric}_mean"]), linestyle="--", color="grey", label=f"{row['case']} (no {axis})")  # type: ignore[arg-type]  # summary rows hold numbers
    ax.set_xlabel(axis)
    ax.set_ylabel(f"{metric} (mean +/- std over trials)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    path = out / f"plot_{metric}_vs_{axis}.png"
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    plt.close(fig)
    write_atomically(path, buffer.getvalue())  # a folder in its place is one line (OutputError)
    return path
