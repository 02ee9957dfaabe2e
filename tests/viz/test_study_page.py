"""``report.html`` of a study: the numbers of report.csv and results.parquet, the plots and trial frames, in a browser."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import cv2
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import yaml

from avdata.cli import main
from avdata.studies.runner import result_checksum

CASES = {"far": 80.0, "near": 40.0}


@pytest.fixture
def study_out(tmp_path: Path, generated: Path) -> Path:
    """A finished study's folder: two cases x two trials of results, its study.yaml, and one trial dataset."""
    out = tmp_path / "study"
    (out / "trials").mkdir(parents=True)
    (out / "trials" / "trial-0").symlink_to(generated, target_is_directory=True)
    rows = [{"case": case, "trial": trial, "scene": f"scene_{trial}", "axis_comm_range_m": comm, "axis_rate_hz": 10.0,
             "HOTA": 0.5 + 0.1 * trial + comm / 1000, "FDE": 1.25 - 0.2 * trial}
            for case, comm in CASES.items() for trial in (0, 1)]
    rows = [row | {"checksum": result_checksum(row)} for row in rows]  # as the runner writes them: the report checks it
    pq.write_table(pa.Table.from_pylist(rows), out / "results.parquet")
    (out / "study.yaml").write_text(yaml.safe_dump({
        "name": "page-test", "description": "two ranges", "preset": "v2i-town", "trials": 2, "seed": 0, "frames": 3,
        "cases": [{"name": c, "comm_range_m": r} for c, r in CASES.items()], "plots": [["HOTA", "comm_range_m"]]}))
    return out


def test_study_report_writes_the_page(study_out: Path) -> None:
    assert main(["study", "report", str(study_out)]) == 0
    page = (study_out / "report.html").read_text()
    assert "<h2>Case far</h2>" in page and "<h2>Case near</h2>" in page and "Trial scenes" in page
    assert 'src="http' not in page and "Content-Security-Policy" in page
    assert page.count("data:image/png;base64,") == 2  # the HOTA plot and the trial's first frame


def test_study_page_in_a_browser_holds_report_csv(study_out: Path, chromium: str, tmp_path: Path) -> None:
    from tests.viz.browser import Browser

    assert main(["study", "report", str(study_out)]) == 0
    expected = list(csv.DictReader((study_out / "report.csv").open()))
    with Browser(chromium) as browser:
        page = browser.open_page(study_out / "report.html")
        assert page.errors == [] and page.requests == []
        assert all(w > 0 for w in page.evaluate("Array.from(document.images).map(i => i.naturalWidth)"))
        cases = page.evaluate(
            "(() => { const t = document.querySelector('table');"
            " const head = Array.from(t.tHead.rows[0].cells).map(c => c.textContent);"
            " return Array.from(t.tBodies[0].rows).map(r => Object.fromEntries(Array.from(r.cells).map("
            "(c, i) => [head[i], c.hasAttribute('data-sort') ? c.getAttribute('data-sort') : c.textContent]))); })()")
        trials = page.evaluate("Array.from(document.querySelectorAll('section')).slice(1, 3).map(s => Array.from("
                               "s.querySelector('table').tBodies[0].rows).map(r => Array.from(r.cells).map(c => c.textContent)))")
        page.screenshot(tmp_path / "study.png")
    assert [c["case"] for c in cases] == [row["case"] for row in expected] == list(CASES)
    for shown, row in zip(cases, expected, strict=True):
        assert float(shown["trials"]) == float(row["trials"]) and float(shown["comm_range_m"]) == float(row["comm_range_m"])
        for metric in ("HOTA", "FDE"):
            assert float(shown[metric]) == float(row[f"{metric}_mean"])  # exact: the page keeps report.csv's value
    results = pq.read_table(study_out / "results.parquet").to_pylist()
    for case_rows, case in zip(trials, CASES, strict=True):
        mine = [r for r in results if r["case"] == case]
        assert [int(r[0]) for r in case_rows] == [r["trial"] for r in mine]
        assert all(math.isclose(float(r[2]), m["HOTA"], rel_tol=1e-3) for r, m in zip(case_rows, mine, strict=True))
    assert cv2.imread(str(tmp_path / "study.png")).shape[1] == 1280
