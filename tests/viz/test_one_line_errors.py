"""Bad arguments of the picture commands cost one line and exit 1, never a traceback or a huge allocation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from avdata.cli import main
from avdata.viz.html import Section, Table, html_report
from avdata.viz.stats import histogram_edges


@pytest.mark.parametrize(("range_m", "expected"), [
    ("inf", "render: expected finite positive range, scale and ring step, got inf, 8.0, 20.0"),
    ("nan", "render: expected finite positive range, scale and ring step, got nan, 8.0, 20.0"),
    ("1e9", "render: expected --range-m at most 512 m (a bird's-eye view of at most 8192 px at 8 px/m), got 1e+09"),
    # a view rounding to 0 px: OpenCV's traceback
    ("1e-30", "render: expected --range-m at least 1 m (a bird's-eye view of at least 16 px at 8 px/m), got 1e-30"),
    ("0.5", "render: expected --range-m at least 1 m (a bird's-eye view of at least 16 px at 8 px/m), got 0.5"),
])
def test_render_range(demo_dataset: Path, tmp_path: Path, capsys, range_m: str, expected: str) -> None:
    assert main(["render", str(demo_dataset), str(tmp_path / "x.png"), "--range-m", range_m]) == 1
    assert capsys.readouterr().err == f"avdata: error: {expected}\n"
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("out", ["passwd", "layout.png"])
def test_view_layout_must_be_a_json_file(demo_dataset: Path, tmp_path: Path, capsys, monkeypatch, out: str) -> None:
    # any other name overwrote that file with a layout ("" is refused by the parser: test_empty_values_are_refused)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "passwd").write_text("root:x:0:0\n")
    assert main(["view", str(demo_dataset), "--out", out]) == 1
    suffix = Path(out).suffix
    assert capsys.readouterr().err == f"avdata: error: {Path(out)}: expected a .json file for the layout, got suffix {suffix!r}\n"
    assert (tmp_path / "passwd").read_text() == "root:x:0:0\n" and sorted(p.name for p in tmp_path.iterdir()) == ["passwd"]


@pytest.mark.parametrize("argv", [["view", "{ds}", "--out", ""], ["render", "{ds}", "{tmp}/x.png", "--scene", ""],
                                  ["stats", "{ds}", "--out", ""], ["stats", "", "--out", "{tmp}/s"], ["render", "", "x.png"]])
def test_empty_values_are_refused(demo_dataset: Path, tmp_path: Path, capsys, monkeypatch, argv: list[str]) -> None:
    # '' is Path('.'): a dataset or report in the working folder, or (--scene '') the first scene, without a word
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_info:
        main([a.format(ds=demo_dataset, tmp=tmp_path) for a in argv])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].endswith(": expected a value, got ''")
    assert not list(tmp_path.iterdir())


def test_an_empty_scene_name_is_no_scene(demo_dataset: Path, tmp_path: Path) -> None:
    from avdata.errors import InputError
    from avdata.viz.layout import foxglove_layout

    with pytest.raises(InputError, match=r"expected a scene of \['demo-0000'\], got ''$"):
        foxglove_layout(demo_dataset, "")  # it was the first scene
    assert foxglove_layout(demo_dataset, None) == foxglove_layout(demo_dataset, "demo-0000")


def test_render_frame_is_refused_with_video(demo_dataset: Path, tmp_path: Path, capsys) -> None:
    # the video draws every frame: --frame 3 was ignored without a word
    assert main(["render", str(demo_dataset), str(tmp_path / "v.mp4"), "--video", "--frame", "3"]) == 1
    assert capsys.readouterr().err == "avdata: error: --frame 3: expected no frame index with --video (it draws every frame)\n"
    assert not list(tmp_path.iterdir())


def test_stats_out_in_a_dataset_or_too_long(demo_dataset: Path, tmp_path: Path, capsys) -> None:
    before = sorted(p.relative_to(demo_dataset) for p in demo_dataset.rglob("*"))
    long = tmp_path / ("x" * 300)  # Path.exists raised ENAMETOOLONG: a traceback
    for out in (demo_dataset, demo_dataset / "scenes", long):
        assert main(["stats", str(demo_dataset), "--out", str(out)]) == 1
    assert capsys.readouterr().err.splitlines() == [
        f"avdata: error: {demo_dataset}: expected an output outside DATASET, got DATASET itself",
        f"avdata: error: {demo_dataset / 'scenes'}: expected an output outside DATASET, got a path inside DATASET "
        f"{demo_dataset}",
        f"avdata: error: {long}: cannot create the output folder (File name too long)"]
    assert sorted(p.relative_to(demo_dataset) for p in demo_dataset.rglob("*")) == before  # the report was written in


def test_render_smallest_range_draws(demo_dataset: Path, tmp_path: Path) -> None:
    import cv2

    assert main(["render", str(demo_dataset), str(tmp_path / "x.png"), "--range-m", "1"]) == 0
    assert cv2.imread(str(tmp_path / "x.png")).shape[1] == 16


def test_outputs_in_the_way(demo_dataset: Path, tmp_path: Path, capsys) -> None:
    (tmp_path / "file").write_text("not a folder")
    (tmp_path / "folder.json").mkdir()
    assert main(["stats", str(demo_dataset), "--out", str(tmp_path / "file")]) == 1
    assert main(["view", str(demo_dataset), "--out", str(tmp_path / "folder.json")]) == 1
    assert capsys.readouterr().err.splitlines() == [
        f"avdata: error: {tmp_path / 'file'}: expected a folder to write into, got a file",
        f"avdata: error: {tmp_path / 'folder.json'}: cannot write this file (Is a directory)"]
    assert (tmp_path / "file").read_text() == "not a folder" and not list((tmp_path / "folder.json").iterdir())
    (tmp_path / "video.mp4").mkdir()
    assert main(["render", str(demo_dataset), str(tmp_path / "video.mp4"), "--video"]) == 1
    assert main(["render", str(demo_dataset), str(tmp_path / "file" / "v.mp4"), "--video"]) == 1
    assert capsys.readouterr().err.splitlines() == [
        f"avdata: error: {tmp_path / 'video.mp4'}: cannot write this file (a folder is in its place)",
        f"avdata: error: {tmp_path / 'file' / 'v.mp4'}: cannot write this file (a file is where its folder should be)"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "folder.json", "video.mp4"]


@pytest.mark.parametrize("values", [[1.8] * 5, [1.8, 1.8 + 1e-15, 1.8 - 2e-16], [0.0, 0.0], [1e9, 1e9 + 1e-6]])
def test_histogram_edges_of_near_constant_values(values: list[float]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    edges = histogram_edges([np.array(values)])
    assert len(edges) == 41 and np.all(np.diff(edges) > 0) and edges[0] <= min(values) and edges[-1] >= max(values)
    fig, ax = plt.subplots()
    counts, _, _ = ax.hist(values, bins=edges)  # matplotlib's "Too many bins for data range" before
    plt.close(fig)
    assert counts.sum() == len(values)


def test_page_escapes_text_and_loads_nothing_from_elsewhere() -> None:
    page = html_report("<b>t</b>", [Section("s & t", text=["<script>alert(1)</script>"],
                                            tables=[Table("x", ["a<"], [["1 +/- 2"], [("0.5", 0.123456789)]])])])
    assert "<script>alert(1)</script>" not in page and "&lt;script&gt;" in page and "<th>a&lt;</th>" in page
    assert 'data-sort="1.0"' in page and 'data-sort="0.123456789"' in page
    assert "default-src 'none'" in page and "http://" not in page and "https://" not in page
