"""``ray_dataset``: the same items as ``FrameDataset`` in Arrow-typed rows (never pickled), one read task per
scene, on a real KITTI object conversion and a real local Ray instance."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.kitti import KittiObjectConverter
from avdata.errors import AvdataError
from avdata.loaders import Collaboration, FrameDataset, FrameOptions, ray_dataset
from avdata.loaders.ray_dataset import as_row
from tests.realdata import REALDATA

ray = pytest.importorskip("ray")

REAL = REALDATA / "kitti" / "object"


@pytest.fixture(scope="module")
def kitti(tmp_path_factory: pytest.TempPathFactory) -> Path:
    dst = tmp_path_factory.mktemp("kitti") / "out"
    run_conversion(KittiObjectConverter(ConvertConfig(src=REAL, dst=dst, quiet=True, options={"scene_size": 1})))
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    # A column Arrow cannot hold raises instead of being pickled (Ray's default logs a warning and pickles).
    context = ray.data.DataContext.get_current()
    context.enable_fallback_to_arrow_object_ext_type = False
    yield dst
    context.enable_fallback_to_arrow_object_ext_type = None
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
        expected = as_row(frames[i])
        assert expected["points.ego/velodyne"].shape[0] > 100_000
        assert_same(by_key[key], expected)
    schema = ray_dataset(kitti, **options).schema()
    types = dict(zip(schema.names, map(str, schema.types), strict=True))
    assert "Tensor" in types["points.ego/velodyne"] and "Tensor" in types["boxes"]
    assert not [name for name, kind in types.items() if "pickled" in kind or "Object" in kind]


def test_one_read_task_per_scene_and_options_checked_up_front(kitti: Path) -> None:
    dataset = ray_dataset(kitti, sensors="ego/velodyne")
    assert dataset.materialize().num_blocks() == 3  # one block per scene file
    with pytest.raises(AvdataError, match="expected a sensor matching"):
        ray_dataset(kitti, sensors="ego/nosuchlidar")


def test_a_frame_without_a_sensor_has_an_empty_cloud_not_a_pickle(kitti: Path, dataset: Path) -> None:
    # infra_00 at 5 Hz in a 10 Hz scene sends in frames 0 and 2 only
    options = FrameOptions(sensors=("*/lidar*",),
                           collaboration=Collaboration(agents=("ego", "infra_00"), rate_hz={"infra_00": 5.0}))
    rows = ray_dataset(dataset, options=options, scenes=["v2i"]).take_all()
    rows.sort(key=lambda row: row["frame_index"])
    frames = FrameDataset(dataset, options, scenes=["v2i"])
    assert [len(row["points.infra_00/lidar"]) for row in rows] == [len(frames[0]["points"]["infra_00/lidar"]), 0,
                                                                    len(frames[2]["points"]["infra_00/lidar"])]
    assert rows[1]["points.infra_00/lidar"].shape == (0, 5) and rows[1]["points.infra_00/lidar"].dtype == np.float32
    assert [row["sensor_timestamps_ns.infra_00/lidar"] is None for row in rows] == [False, True, False]
    assert_same(rows[2], as_row(frames[2]))


@pytest.mark.parametrize("fusion", ["intermediate", "late"])
def test_intermediate_and_late_layouts_equal_frame_dataset(kitti: Path, dataset: Path, fusion: str) -> None:
    # latency and a slower rate make the received agents (and so the columns) differ from frame to frame
    options = FrameOptions(sensors=("*/lidar*",), collaboration=Collaboration(
        agents=("ego", "infra_*"), fusion=fusion, latency_ms={"infra_01": 100.0}, rate_hz={"infra_02": 5.0},
        pose_noise=(0.2, 0.2, 0.0, 1.0), seed=3))
    frames = FrameDataset(dataset, options, scenes=["v2i"])
    rows = {row["frame_index"]: row for row in ray_dataset(dataset, options=options, scenes=["v2i"]).take_all()}
    assert sorted(rows) == [0, 1, 2]
    layout_keys = ["pairwise_T", "agent_mask", "agent_frames"] + (["agent_boxes.ego"] if fusion == "late" else [])
    for frame_index, row in rows.items():
        expected = as_row(frames[frame_index])
        assert all(key in expected for key in layout_keys)
        assert_same({key: row[key] for key in expected}, expected, f"frame {frame_index}")
        # a column another frame of the scene has is empty (arrays) or None here, never made up
        for key in set(row) - set(expected):
            assert row[key] is None or len(row[key]) == 0, key
    # infra_01 waits a frame, infra_02 sends every other frame: each frame receives a different set
    assert rows[0]["agents"] == ["ego", "infra_00", "infra_02", "infra_01"]
    assert rows[1]["agents"] == ["ego", "infra_00", "infra_01", "infra_02"]
    assert len(rows[0]["points.infra_01"]) == 0 < len(rows[1]["points.infra_01"])
