"""``ray_dataset`` over a dataset in S3 (moto's standalone server on 127.0.0.1): the read tasks open the scenes in the
workers by ranged requests, with the credentials and endpoint of their own environment, and give the local rows."""

from __future__ import annotations

from pathlib import Path

import pytest

from avdata.demo import write_demo
from avdata.loaders import FrameDataset, ray_dataset
from avdata.loaders.ray_dataset import as_row
from tests.loaders.test_ray_dataset import assert_same
from tests.storage.test_read import upload

ray = pytest.importorskip("ray")


def test_ray_dataset_reads_scenes_from_s3_in_its_workers(s3_server, tmp_path: Path) -> None:  # noqa: ANN001
    local = write_demo(tmp_path / "demo")
    uri = upload(s3_server, local, "ray")
    options = {"sensors": ["ego/lidar_top", "ego/cam_front"], "frame": "world"}
    # Workers inherit this process's environment (the fixture's AWS_* variables): no credential travels in a task.
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:
        rows = {row["frame_index"]: row for row in ray_dataset(uri, **options).take_all()}
    finally:
        ray.shutdown()
    frames = FrameDataset(local, **options)
    assert sorted(rows) == [frame_index for _, frame_index in frames.keys()]
    for i, (_, frame_index) in enumerate(frames.keys()):
        assert_same(rows[frame_index], as_row(frames[i]), f"frame {frame_index}")
