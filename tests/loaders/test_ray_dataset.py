"""``ray_dataset``: the same items as ``FrameDataset`` (numpy instead of tensors), one read task per scene,
on a real KITTI object conversion and a real local Ray instance."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.kitti import KittiObjectConverter
from avdata.errors import AvdataError
from avdata.loaders import FrameDataset, ray_dataset
from avdata.loaders.ray_dataset import as_numpy
from tests.realdata import REALDATA

ray = pytest.importorskip("ray")

REAL = REALDATA / "kitti" / "object"


@pytest.fixture(scope="module")
def kitti(tmp_path_factory: pytest.TempPathFactory) -> Path:
    dst = tmp_path_factory.mktemp("kitti") / "out"
    run_conversion(KittiObjectConverter(ConvertConfig(src=REAL, dst=dst, quiet=True, options={"scene_size": 1})))
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield dst
    ray.shutdown()


def assert_same(got: Any, expected: Any, where: str = "item") -> None:
    if isinstance(expected, np.ndarray):
        assert isinstance(got, np.ndarray) and got.dtype == expected.dtype, where
        np.testing.assert_array_equal(got, expected, err_msg=where)
    elif isinstance(expected, dict):
        assert isinstance(got, dict) and set(got) == set(expected), where
        for key in expected:
            assert_same(got[key], expected[key], f"{where}[{key!r}]")
    elif isinstance(expected, list | tuple):
        assert len(got) == len(expected), where
        for i, (a, b) in enumerate(zip(got, expected, strict=True)):
            assert_same(a, b, f"{where}[{i}]")
    else:
        assert got == expected and type(got) is type(expected), where


@pytest.mark.parametrize("options", [
    {"sensors": ["ego/velodyne", "ego/cam2"], "frame": "ego/cam2"},
    {"sensors": "ego/velodyne", "frame": "world", "classes": ["car", "pedestrian"], "with_velocity": True},
])
def test_items_equal_frame_dataset(kitti: Path, options: dict[str, Any]) -> None:
    frames = FrameDataset(kitti, **options)
    rows = ray_dataset(kitti, **options).take_all()
    assert sorted((r["scene"], r["frame_index"]) for r in rows) == frames.keys()
    assert len(frames) == 3 and len({r["scene"] for r in rows}) == 3
    by_key = {(r["scene"], r["frame_index"]): r for r in rows}
    for i, key in enumerate(frames.keys()):
        expected = as_numpy(frames[i])
        assert expected["points"]["ego/velodyne"].shape[0] > 100_000
        assert_same(by_key[key], expected)


def test_one_read_task_per_scene_and_options_checked_up_front(kitti: Path) -> None:
    dataset = ray_dataset(kitti, sensors="ego/velodyne")
    assert dataset.materialize().num_blocks() == 3  # one block per scene file
    with pytest.raises(AvdataError, match="expected a sensor matching"):
        ray_dataset(kitti, sensors="ego/nosuchlidar")
