"""``avdata track --executor ray`` on a real local Ray instance: the same bytes as the local executor."""

from __future__ import annotations

from pathlib import Path

import pytest

from avdata.cli import main
from tests.perception.test_track_cli import DETECTIONS, kitti_dataset

ray = pytest.importorskip("ray")

pytestmark = pytest.mark.usefixtures("local_ray")


def test_track_on_ray_is_byte_identical_to_local(tmp_path: Path) -> None:
    dataset = kitti_dataset(tmp_path, ("0006",))
    for cls in ("Car", "Pedestrian", "Cyclist"):
        (tmp_path / "dets" / f"pointrcnn_{cls}_val").mkdir(parents=True)
        (tmp_path / "dets" / f"pointrcnn_{cls}_val" / "0006.txt").symlink_to(DETECTIONS / f"pointrcnn_{cls}_val" / "0006.txt")
    common = ["--detections", str(tmp_path / "dets"), "--format", "ab3dmot", "--output-format", "nuscenes", "--quiet"]
    assert main(["track", str(dataset), str(tmp_path / "local"), *common]) == 0
    assert main(["track", str(dataset), str(tmp_path / "ray"), *common, "--executor", "ray"]) == 0
    files = ("tracking_results.json", ".avdata-track/training_0006.json")
    assert [(tmp_path / "ray" / f).read_bytes() for f in files] == [(tmp_path / "local" / f).read_bytes() for f in files]
