"""``report.html`` of a trade study: the summary table of ``report.csv``, the plots, one section per case.

Called by :func:`avdata.studies.write_report` after it wrote ``report.csv`` and the plots, so the page shows
exactly their numbers. Each case's section lists its settings and its result on every trial (from
``results.parquet``); the last section shows a rendered frame of each trial's generated scenes (at most
:data:`TRIAL_PICTURES` trials).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from pathlib import Path

import pyarrow.parquet as pq
import yaml

from avdata.errors import InputError
from avdata.viz.html import Cell, Picture, Section, Table, png_picture, write_html_report

__all__ = ["TRIAL_PICTURES", "write_study_page"]

#: Trials whose scenes are drawn (the first ones): a few pictures, not one per trial of a 10-trial study.
TRIAL_PICTURES = 3


def _text(value: object) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return "N/A" if not math.isfinite(value) else f"{value:.4g}"
    return str(value)


def _mean_std(mean: str, std: str) -> Cell:
    """A cell "mean +/- std" rounded for reading, sorting by the exact mean of report.csv."""
    if not mean or not math.isfinite(float(mean)):
        return "N/A"
    return f"{float(mean):.4g} +/- {float(std):.2g}", float(mean)


def write_study_page(out: str | Path, files: Sequence[Path]) -> Path:
    """Writes ``OUT/report.html`` from ``report.csv``, ``results.parquet``, ``study.yaml`` and the PNGs in ``files``.

    Returns:
        The path of the page.
    """
    from avdata.viz.render import frame_pictures

    out = Path(out)
    try:
        summary = list(csv.reader(io.StringIO((out / "report.csv").read_text())))
        results = pq.read_table(out / "results.parquet").to_pylist()
        study = yaml.safe_load((out / "study.yaml").read_text()) or {}
    except (OSError, ValueError, yaml.YAMLError) as error:
        raise InputError(f"{out}: cannot read the study report's inputs ({type(error).__name__}: {error})") from None
    header, rows = summary[0], summary[1:]
    metrics = [c.removesuffix("_mean") for c in header if c.endswith("_mean")]
    settings = [c for c in header if not c.endswith(("_mean", "_std"))]
    cases_table = Table("Cases", [*settings, *metrics], [
        [*(row[header.index(c)] for c in settings),
         *(_mean_std(row[header.index(f"{m}_mean")], row[header.index(f"{m}_std")]) for m in metrics)] for row in rows])
    sections = [Section("Summary", text=[str(study.get("description", "")).strip(),
                                         "Mean +/- sample standard deviation over trials (report.csv holds the "
                                         "exact values; a click on a column header sorts by it)."],
                        tables=[cases_table],
                        pictures=[png_picture(path.stem, path) for path in files if path.suffix == ".png"])]
    axes = [c.removeprefix("axis_") for c in (results[0] if results else {}) if c.startswith("axis_")]
    for case in [row[0] for row in rows]:
        trials = [r for r in results if r["case"] == case]
        described = ", ".join(f"{a} {_text(trials[0].get(f'axis_{a}'))}" for a in axes) if trials else ""
        sections.append(Section(f"Case {case}", text=[f"Settings: {described}."] if described else [], tables=[
            Table(f"{case}: each trial", ["trial", "scene", *metrics],
                  [[str(r["trial"]), str(r["scene"]), *(_text(r.get(m)) for m in metrics)] for r in trials])]))
    pictures: list[Picture] = []
    notes: list[str] = []
    for trial in sorted((out / "trials").glob("trial-*"), key=lambda p: int(p.name.split("-")[-1]))[:TRIAL_PICTURES]:
        drawn, trial_notes = frame_pictures(trial, count=1)
        pictures += [Picture(caption, png) for caption, png in drawn]
        notes += trial_notes
    if study.get("dataset"):
        notes.append(f"The trials are scenes of {study['dataset']}; see 'avdata render' for their frames.")
    sections.append(Section("Trial scenes", text=["The first frame of each trial's generated scene, as 'avdata render' "
                                                  "draws it (bird's-eye view and cameras)."],
                            pictures=pictures, notes=notes))
    return write_html_report(out / "report.html", f"Study {study.get('name', out.name)}", sections)
