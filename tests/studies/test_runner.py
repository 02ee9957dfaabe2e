"""A small study end to end: determinism, resumability, the report, and what each case must mean."""

from __future__ import annotations

import math
import re
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
        assert base["sensors_in_range"] is None and base["collaborative_detections"] is None
        # Range 0: nobody in range, nothing received, so the ego tracks exactly as without collaboration.
        assert deaf["sensors_in_range"] == 0 and deaf["collaborative_detections"] == 0
        for metric in ("HOTA", "MOTA", "MOTP", "IDF1"):
            assert deaf[metric] == base[metric]
        # Unlimited range: all 4 infrastructure lidars; half the rate receives about half as many detections.
        assert ideal["sensors_in_range"] == 4 and ideal["collaborative_detections"] > 0
        assert slow["collaborative_detections"] < 0.75 * ideal["collaborative_detections"]
        # Perfect infrastructure detections help the ego's short-range lidar.
        assert ideal["HOTA"] > base["HOTA"]


def test_same_study_same_numbers_and_resume(study_out: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    again = tmp_path / "again"
    run_study(load_study(STUDY), again, workers=2, progress=False)
    a, b = _rows(study_out), _rows(again)
    for key in a:
        for name, value in a[key].items():
            other = b[key][name]
            assert (value == other) or (isinstance(value, float) and math.isnan(value) and math.isnan(other)), (key, name)
    stamp = (again / "runs" / "ideal__trial-0.json").stat().st_mtime_ns
    table = (again / "results.parquet").read_bytes()
    capsys.readouterr()
    run_study(load_study(STUDY), again, workers=1, progress=True)  # nothing changed: every result is kept
    assert (again / "runs" / "ideal__trial-0.json").stat().st_mtime_ns == stamp
    assert (again / "results.parquet").read_bytes() == table  # kept results give the columns of fresh ones
    # Without a terminal, one progress line per finished trial and run, with counts (issue 32: a study run was
    # silent between its first and last lines).
    lines = capsys.readouterr().err.splitlines()
    assert [line.split(" (")[0] for line in lines] == (
        [f"study small: trials: {i}/2 trials" for i in (1, 2)] + [f"study small: runs: {i}/8 runs" for i in range(1, 9)])
    assert "ideal__trial-0 finished" in "\n".join(lines)


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
    """One Ray task per trial and per (case, trial), on a local Ray instance: the same bytes as the local pool."""
    out = tmp_path / "ray"
    assert main(["study", "run", str(STUDY), str(out), "--executor", "ray", "--quiet", "--no-report"]) == 0
    assert (out / "results.parquet").read_bytes() == (study_out / "results.parquet").read_bytes()
    a, b = _rows(study_out), _rows(out)
    assert sorted(a) == sorted(b)
    for key in a:
        for name, value in a[key].items():
            other = b[key][name]
            assert (value == other) or (isinstance(value, float) and math.isnan(value) and math.isnan(other)), (key, name)


def _copy(study_out: Path, tmp_path: Path) -> Path:
    import shutil

    return Path(shutil.copytree(study_out, tmp_path / "copy"))


def test_run_results_keep_frames_and_stage_times(study_out: Path) -> None:
    import json

    stored = json.loads((study_out / "runs" / "ideal__trial-0.json").read_text())
    assert stored["frames"]["frame_index"] == list(range(8))
    frames, result = stored["frames"], stored["result"]
    assert sum(frames["tp"]) / (sum(frames["tp"]) + sum(frames["fp"])) == pytest.approx(result["precision"])
    assert sum(frames["tp"]) / (sum(frames["tp"]) + sum(frames["fn"])) == pytest.approx(result["recall"])
    assert 0.9 < result["recall"] <= 1.0 and result["detector"] == "simulated" and result["tracker"] == "kalman"
    assert set(stored["seconds"]) == {"detect", "track", "predict", "evaluate"}


def test_edited_run_result_is_redone(study_out: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """S35: a resumed study does not keep an edited runs/*.json (its checksum no longer matches)."""
    import json

    out = _copy(study_out, tmp_path)
    path = out / "runs" / "ideal__trial-0.json"
    stored = json.loads(path.read_text())
    true_hota = stored["result"]["HOTA"]
    stored["result"]["HOTA"] = 0.999
    path.write_text(json.dumps(stored))
    run_study(load_study(STUDY), out, progress=False)
    assert "checksum does not match" in capsys.readouterr().err
    assert _rows(out)[("ideal", 0)]["HOTA"] == true_hota
    assert json.loads(path.read_text())["result"]["HOTA"] == true_hota


def _rewrite(out: Path, edit) -> None:
    import pyarrow as pa

    rows = pq.read_table(out / "results.parquet").to_pylist()
    pq.write_table(pa.Table.from_pylist(edit(rows)), out / "results.parquet")


@pytest.mark.parametrize(("edit", "message"), [
    (lambda rows: rows + rows[:1], r"case '\w+' trial 0 appears twice"),  # S34
    (lambda rows: [{**r, "HOTA": math.nan} if r["case"] == "ideal" else r for r in rows], "got HOTA = nan"),  # S34
    (lambda rows: [{**r, "MOTA": 0.99} if r["case"] == "slow" else r for r in rows], "checksum does not match"),
    # Without the checksum column an edited row was averaged into the report without a word.
    (lambda rows: [{**{k: v for k, v in r.items() if k != "checksum"}, "HOTA": 0.99} for r in rows],
     r"expected columns 'case', 'trial' and 'checksum', got no \['checksum'\]"),
])
def test_report_refuses_damaged_results(study_out: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                        edit, message: str) -> None:
    out = _copy(study_out, tmp_path)
    _rewrite(out, lambda rows: sorted(edit(rows), key=lambda r: (r["case"], r["trial"])))
    assert main(["study", "report", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "results.parquet" in err[0]
    assert re.search(message, err[0]), err[0]


@pytest.mark.parametrize(("text", "message"), [
    # Each was a traceback (TypeError, ValueError, AttributeError) in the report.
    ("cases: 5\n", "field cases: expected a list of cases with a name, got 5"),
    ("cases: [5]\n", r"field cases: expected a list of cases with a name, got \[5\]"),
    ("plots: [[HOTA]]\n", r"field plots: expected a list of \[metric, axis\] pairs, got \[\['HOTA'\]\]"),
    ("seed: x\n", "field seed: expected an integer, got 'x'"),
    ("datasets: 5\n", "field datasets: expected a list of datasets with a name and scenes, got 5"),
    ("[1, 2]\n", r"expected the study file of 'avdata study run' \(a mapping\), got \[1, 2\]"),
    ("", r"expected the study file of 'avdata study run' \(a mapping\), got None"),
])
def test_report_refuses_a_damaged_study_file(study_out: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                             text: str, message: str) -> None:
    out = _copy(study_out, tmp_path)
    (out / "study.yaml").write_text(text)
    assert main(["study", "report", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"avdata: error: {out / 'study.yaml'}: ")
    assert re.search(message, err[0]), err[0]


def test_report_plot_path_that_is_a_folder_is_one_line(study_out: Path, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    out = _copy(study_out, tmp_path)
    (out / "plot_HOTA_vs_rate_hz.png").unlink(missing_ok=True)
    (out / "plot_HOTA_vs_rate_hz.png").mkdir()
    assert main(["study", "report", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "plot_HOTA_vs_rate_hz.png" in err[0]


@pytest.mark.parametrize(("predictor", "message"), [
    # NaN positions became ADE/FDE null, reported "N/A" as if prediction did not apply; a string was a ValueError.
    ("nan_predictor", r"^predictor: expected finite positions, got \d+ non-finite$"),
    ("text_predictor", r"^predictor: expected an array of numbers, got 'soon'$"),
])
def test_a_users_predictor_that_gives_no_positions_is_one_line(study_out: Path, predictor: str, message: str) -> None:
    from avdata.errors import InputError
    from avdata.schema import DatasetReader
    from avdata.studies.config import CaseConfig
    from avdata.studies.runner import run_pipeline

    trial = study_out / "trials" / "trial-0"
    case = CaseConfig(name="p", predictor=f"tests.studies.components:{predictor}")
    with pytest.raises(InputError, match=message):
        run_pipeline(trial, DatasetReader(trial).scenes[0], case)
