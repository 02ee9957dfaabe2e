"""The Foxglove layout: the documented layout file shape, and every topic it names exists with the right schema."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader

from avdata.cli import main
from avdata.schema import DatasetReader
from avdata.viz.layout import PANEL_ID, foxglove_layout


def _leaves(node: object) -> list[str]:
    if isinstance(node, str):
        return [node]
    assert isinstance(node, dict) and set(node) == {"first", "second", "direction", "splitPercentage"}, node
    assert node["direction"] in ("row", "column") and 0 < node["splitPercentage"] < 100
    return _leaves(node["first"]) + _leaves(node["second"])


def _schemas(mcap: Path) -> dict[str, str]:
    with open(mcap, "rb") as handle:
        summary = make_reader(handle).get_summary()
    return {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}


def _check(root: Path) -> dict:
    layout = foxglove_layout(root)
    # Foxglove's layout file (Layouts > Import from file): these five keys, panel ids "Type!suffix".
    assert set(layout) == {"configById", "globalVariables", "userNodes", "playbackConfig", "layout"}
    leaves = _leaves(layout["layout"])
    assert sorted(leaves) == sorted(layout["configById"]) and len(set(leaves)) == len(leaves)
    assert all(PANEL_ID.match(panel) for panel in leaves)
    ds = DatasetReader(root)
    reader = ds.scene(ds.scenes[0])
    schemas = _schemas(reader.path)
    three_d = layout["configById"]["3D!scene"]
    assert three_d["followTf"] in reader.graph.frames
    for topic in three_d["topics"]:
        assert schemas[topic] in ("foxglove.PointCloud", "foxglove.SceneUpdate"), topic
    assert schemas["/labels/markers"] == "foxglove.SceneUpdate" and "/labels/markers" in three_d["topics"]
    images = [p for p in leaves if p.startswith("Image!")]
    for panel in images:
        mode = layout["configById"][panel]["imageMode"]
        assert schemas[mode["imageTopic"]] == "foxglove.CompressedImage"
        assert schemas[mode["calibrationTopic"]] == "foxglove.CameraCalibration"
    assert layout["configById"]["RawMessages!labels"]["topicPath"] == "/labels/objects"
    json.dumps(layout)  # plain JSON
    return layout


def test_layout_of_generated_v2i(generated: Path) -> None:
    layout = _check(generated)
    points = [t for t in layout["configById"]["3D!scene"]["topics"] if t.endswith("/points")]
    assert points == ["/ego/lidar_top/points", "/infra_00/lidar/points", "/infra_01/lidar/points"]
    assert [p for p in layout["configById"] if p.startswith("Image!")] == ["Image!ego_cam_front"]


def test_layout_of_real_kitti(kitti_object: Path) -> None:
    layout = _check(kitti_object)
    assert layout["configById"]["3D!scene"]["topics"]["/ego/velodyne/points"]["colorField"] == "intensity"


def test_view_command(generated: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "layout.json"
    assert main(["view", str(generated), "--out", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].startswith("1. ") and lines[1].endswith(".mcap") and lines[2].startswith("2. ") and str(out) in lines[2]
    assert json.loads(out.read_text()) == foxglove_layout(generated)
    assert main(["view", str(generated), "--scene", "nope", "--out", str(out)]) == 1
