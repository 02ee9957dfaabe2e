"""A small study end to end: determinism, resumability, the report, and what each case must mean."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from avdata.cli import main
from avdata.studies import load_study, run_study, write_report

STUDY = Path(__file__).with_name("small_study.yaml")


@pytest.fixture(scope="module")
def study_out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("study") / "out"
    assert main(["study", "run", str(STUDY), str(out), "--quiet"]) == 0
    return out


def _rows(out: Path) -> dict[tuple[str, int], dict]:
    table = pq.read_table(out / "results.parquet").to_pylist()
    return {(r["case"], r["trial"]): r for r in table}


def test_every_case_and_trial_has_a_result(study_out: Path) -> None:
    rows = _rows(study_out)
    assert sorted(rows) == [(c, t) for c in ("base", "deaf", "ideal", "slow") for t in (0, 1)]
    for row in rows.values():
        assert 0.0 <= row["HOTA"] <= 1.0 and row["MOTA"] <= 1.0
        assert row["seed"] == 3 + row["trial"]


def test_cases_mean_what_they_say(study_out: Path) -> None:
    rows = _rows(study_out)
    for trial in (0, 1):
        base, deaf, ideal, slow = (rows[(c, trial)] for c in ("base", "deaf", "ideal", "slow"))
        # No collaboration: the counts are not applicable.
        assert math.isnan(base["sensors_in_range"]) and math.isnan(base["collaborative_detections"])
        # Range 0: nobody in range, nothing received, so the ego tracks exactly as without collaboration.
        assert deaf["sensors_in_range"] == 0 and deaf["collaborative_detections"] == 0
        for metric in ("HOTA", "MOTA", "MOTP", "IDF1"):
            assert deaf[metric] == base[metric]
        # Unlimited range: all 4 infrastructure lidars; half the rate receives about half as many detections.
        assert ideal["sensors_in_range"] == 4 and ideal["collaborative_detections"] > 0
        assert slow["collaborative_detections"] < 0.75 * ideal["collaborative_detections"]
        # Perfect infrastructure detections help the ego's short-range lidar.
        assert ideal["HOTA"] > base["HOTA"]


def test_same_study_same_numbers_and_resume(study_out: Path, tmp_path: Path) -> None:
    again = tmp_path / "again"
    run_study(load_study(STUDY), again, workers=2, progress=False)
    a, b = _rows(study_out), _rows(again)
    for key in a:
        for name, value in a[key].items():
            other = b[key][name]
            assert (value == other) or (isinstance(value, float) and math.isnan(value) and math.isnan(other)), (key, name)
    stamp = (again / "runs" / "ideal__trial-0.json").stat().st_mtime_ns
    run_study(load_study(STUDY), again, workers=1, progress=False)  # nothing changed: every result is kept
    assert (again / "runs" / "ideal__trial-0.json").stat().st_mtime_ns == stamp


def test_report(study_out: Path) -> None:
    files = write_report(study_out)
    names = sorted(p.name for p in files)
    assert names == ["plot_HOTA_vs_rate_hz.png", "report.csv", "report.html", "report.md"]
    md = (study_out / "report.md").read_text()
    assert "| ideal | 2 |" in md and "N/A" in md  # base case: sensors in range not applicable
    csv = (study_out / "report.csv").read_text().splitlines()
    header = csv[0].split(",")
    hota = [float(line.split(",")[header.index("HOTA_mean")]) for line in csv[1:]]
    rows = _rows(study_out)
    assert hota[0] == pytest.approx(np.mean([rows[("ideal", t)]["HOTA"] for t in (0, 1)]))
    assert (study_out / "plot_HOTA_vs_rate_hz.png").stat().st_size > 1000


def test_report_without_results_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["study", "report", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "results.parquet" in err[0]


def test_shipped_c1_study_shows_the_published_direction(tmp_path: Path) -> None:
    """The shipped C1 study, shortened (2 trials of 30 frames): sensors in range fall with the communication
    range, and perfect infrastructure detections (C1-Ideal) lower the FDE below no collaboration (C1-Base)."""
    from dataclasses import replace

    study = replace(load_study(STUDY.parents[2] / "studies" / "v2i-comm-range.yaml"), trials=2, frames=30)
    rows = _rows_of(run_study(study, tmp_path / "c1", workers=2, progress=False))
    mean = lambda case, metric: float(np.mean([rows[(case, t)][metric] for t in (0, 1)]))  # noqa: E731
    in_range = [mean(c, "sensors_in_range") for c in ("C1-Ideal", "C1-2", "C1-3")]  # 100, 70, 50 m
    assert in_range[0] > in_range[1] > in_range[2]
    assert mean("C1-Ideal", "FDE") < mean("C1-Base", "FDE")
    assert mean("C1-Ideal", "HOTA") > mean("C1-Base", "HOTA")


def _rows_of(table) -> dict[tuple[str, int], dict]:
    return {(r["case"], r["trial"]): r for r in table.to_pylist()}


def test_ray_executor_gives_the_same_table(study_out: Path, tmp_path: Path) -> None:
    """One Ray task per trial and per (case, trial), on a local Ray instance: the same numbers as the local pool."""
    out = tmp_path / "ray"
    assert main(["study", "run", str(STUDY), str(out), "--executor", "ray", "--quiet", "--no-report"]) == 0
    a, b = _rows(study_out), _rows(out)
    assert sorted(a) == sorted(b)
    for key in a:
        for name, value in a[key].items():
            other = b[key][name]
            assert (value == other) or (isinstance(value, float) and math.isnan(value) and math.isnan(other)), (key, name)
