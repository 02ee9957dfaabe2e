"""Every picture command on every kind of dataset: the demo, a generated scene and each real sample converted.

The real samples cover the awkward cases: near-constant features (the demo's fixed sizes), a single frame
(V2XSet), no labels and no sensors (KITTI raw calibration and timestamps only), no camera (Argoverse 2), ego
poses only (Waymo v2). Each must give its pictures and reports, never a traceback.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from avdata.cli import main
from tests.viz.conftest import REAL_SAMPLES

DATASETS = ["demo", "generated", *REAL_SAMPLES]


@pytest.fixture(scope="module")
def every_dataset(demo_dataset: Path, generated: Path, real_datasets: dict[str, Path]) -> dict[str, Path]:
    return {"demo": demo_dataset, "generated": generated, **real_datasets}


@pytest.mark.parametrize("name", DATASETS)
def test_render_view_rerun_and_stats_work_on(every_dataset: dict[str, Path], tmp_path: Path, name: str, capsys) -> None:
    dataset = every_dataset[name]
    assert main(["render", str(dataset), str(tmp_path / "frame.png")]) == 0
    picture = cv2.imread(str(tmp_path / "frame.png"))
    assert picture is not None and picture.shape[1] == 960 and picture.std() > 0
    assert main(["view", str(dataset), "--out", str(tmp_path / "layout.json")]) == 0
    assert "3D!scene" in json.loads((tmp_path / "layout.json").read_text())["configById"]
    if importlib.util.find_spec("rerun") is not None:  # the optional extra (in the test extra)
        assert main(["view", "--rerun", str(dataset), "--save", str(tmp_path / "scene.rrd")]) == 0
        assert (tmp_path / "scene.rrd").stat().st_size > 0
    assert main(["stats", str(dataset), "--out", str(tmp_path / "stats")]) == 0
    page = (tmp_path / "stats" / "report.html").read_text()
    assert f"<td>{dataset.name}</td>" in page and "Frames of" in page
    assert "Traceback" not in capsys.readouterr().err


def test_stats_of_all_datasets_side_by_side_in_a_browser(every_dataset: dict[str, Path], chromium: str,
                                                         tmp_path: Path) -> None:
    from tests.viz.browser import Browser

    out = tmp_path / "stats"
    assert main(["stats", *(str(every_dataset[n]) for n in DATASETS), "--out", str(out)]) == 0
    markdown = (out / "stats.md").read_text()
    md_rows = [[c.strip() for c in line.strip("|").split("|")] for line in markdown.splitlines()
               if line.startswith("| ") and not line.startswith("|---")]
    plots = sorted(p.name for p in out.glob("*.png"))
    with Browser(chromium) as browser:
        page = browser.open_page(out / "report.html")
        assert page.errors == [] and page.requests == []
        widths = page.evaluate("Array.from(document.images).map(i => [i.alt, i.naturalWidth])")
        assert all(width > 0 for _, width in widths), widths
        # Every plot, and a rendered frame of each dataset that has one (KITTI raw has neither lidar nor camera,
        # but its frames still draw: an empty bird's-eye view).
        assert sorted(alt.replace(" ", "_") + ".png" for alt, _ in widths if ":" not in alt) == plots
        assert sorted({alt.split(":")[0] for alt, _ in widths if ":" in alt}) == sorted(p.name for p in every_dataset.values())
        tables = page.evaluate("Array.from(document.querySelectorAll('table')).map(t => Array.from(t.rows).map("
                               "r => Array.from(r.cells).map(c => c.textContent)))")
        assert [row for table in tables for row in table] == md_rows
        # A click on "frames" sorts the datasets by their frame count, numerically (not as text).
        frames = page.evaluate("document.querySelector('table th:nth-child(3)').click();"
                               "Array.from(document.querySelector('table').tBodies[0].rows).map(r => r.cells[2].textContent)")
        assert [int(f) for f in frames] == sorted(int(f) for f in frames)
        shot = page.screenshot(tmp_path / "stats.png")
    picture = cv2.imread(str(shot))
    assert picture is not None and picture.shape[1] == 1280 and np.ptp(picture) > 0
