"""SequenceDataset windows and trajectories in the ego frame of the last observed frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from avdata.errors import AvdataError
from avdata.loaders import Collaboration, FrameOptions, LabelFilter, SequenceDataset
from tests.loaders.conftest import INFRA_T_LIDAR, PERIOD_NS, T0_NS, lidar_points


def test_windows_stay_inside_scenes_and_follow_the_stride(dataset: Path) -> None:
    assert len(SequenceDataset(dataset, past_frames=2, future_frames=1)) == 2
    assert len(SequenceDataset(dataset, past_frames=2, future_frames=2)) == 0
    single = SequenceDataset(dataset, past_frames=1, scenes=["v2i"])
    assert [single[i]["frame_indices"].tolist() for i in range(len(single))] == [[0], [1], [2]]
    strided = SequenceDataset(dataset, past_frames=1, stride=2, scenes=["v2i"])
    assert [strided[i]["frame_indices"].tolist() for i in range(len(strided))] == [[0], [2]]
    with pytest.raises(AvdataError, match="past_frames"):
        SequenceDataset(dataset, past_frames=0)


@pytest.mark.parametrize("scene", ["v2i", "offset"])
def test_trajectories_in_ego_frame_of_last_observed_frame(dataset: Path, scene: str) -> None:
    # present = frame 1: ego at world (10, 6) facing +y. Car a at world (10, 25 + 0.5 k) heading +x
    # is ahead at 19 + 0.5 k m, heading -90 deg; cyclist d at world (6, 45 - 0.3 k) heading -y is
    # at (39 - 0.3 k, 4), heading 180 deg. The offset scene stores labels in the ego frame: same answer.
    item = SequenceDataset(dataset, past_frames=2, future_frames=1, scenes=[scene])[0]
    t1 = T0_NS + PERIOD_NS
    assert item["timestamp_ns"] == t1 and item["frame"] == "ego"
    assert item["timestamps_ns"].tolist() == [T0_NS, t1, T0_NS + 2 * PERIOD_NS]
    assert item["object_ids"] == ["a", "b", "c", "d"]
    a, d = 0, 3
    np.testing.assert_allclose(item["past"][a, :, :3].numpy(), [[19.0, 0.0, 0.8], [19.5, 0.0, 0.8]], atol=1e-4)
    np.testing.assert_allclose(item["future"][a, :, :3].numpy(), [[20.0, 0.0, 0.8]], atol=1e-4)
    np.testing.assert_allclose(item["past"][a, :, 3].numpy(), [-np.pi / 2] * 2, atol=1e-6)
    np.testing.assert_allclose(item["past"][d, :, :2].numpy(), [[39.0, 4.0], [38.7, 4.0]], atol=1e-4)
    np.testing.assert_allclose(np.cos(item["future"][d, :, 3].numpy()), [-1.0], atol=1e-6)
    assert item["past_valid"].all() and item["future_valid"].all()
    assert item["past"].dtype == torch.float32 and item["past"].shape == (4, 2, 4)
    assert item["future"].shape == (4, 1, 4)


def test_observed_frames_are_expressed_at_the_present(dataset: Path) -> None:
    item = SequenceDataset(dataset, past_frames=2, sensors="ego/lidar_top", scenes=["v2i"])[0]
    past, present = item["frames"]
    assert past["frame_index"] == 0 and present["frame_index"] == 1
    # the ego moved 1 m forward between frames 0 and 1: the lidar (1 m ahead of the origin) of frame 0
    # sat exactly at the present ego origin
    raw = lidar_points("ego/lidar_top", 0)
    np.testing.assert_allclose(past["points"]["ego/lidar_top"][:, 0].numpy(), raw["x"], atol=1e-5)
    np.testing.assert_allclose(past["boxes"][0, :3].numpy(), item["past"][0, 0, :3].numpy(), atol=1e-5)


def test_filters_choose_the_objects_at_the_present_frame(dataset: Path) -> None:
    options = FrameOptions(labels=LabelFilter(classes=("cyclist", "car"), max_range_m=30.0))
    item = SequenceDataset(dataset, options, past_frames=1, future_frames=2, scenes=["v2i"])[0]
    assert item["object_ids"] == ["a"]
    assert item["object_labels"].tolist() == [1]
    assert item["future"].shape == (1, 2, 4)


def test_collaborative_sequences_fuse_every_observed_frame_at_the_present(dataset: Path) -> None:
    options = FrameOptions(sensors=("*/lidar*",),
                           collaboration=Collaboration(agents=("ego", "infra_*"), fusion="early", comm_range_m=50.0))
    item = SequenceDataset(dataset, options, past_frames=2, future_frames=1, scenes=["v2i"])[0]
    past, present = item["frames"]
    assert past["agents"] == present["agents"] == ["ego", "infra_00", "infra_01", "infra_02"]
    for frame_item in (past, present):
        assert frame_item["frame"] == "ego" and list(frame_item["points"]) == ["fused"]
        assert set(frame_item["points"]["fused"][:, -1].unique().tolist()) == {0.0, 1.0}
    # infra_00 stands still: its cloud of frame 0 seen from the present ego equals its cloud of frame 0
    # moved with the present pose, i.e. the present item's infra_00 pose applied to the raw points
    raw = lidar_points("infra_00/lidar", 0)
    xyz = np.stack([raw["x"], raw["y"], raw["z"]], axis=1).astype(np.float64)
    ego_T_lidar = present["agent_poses"][1].numpy() @ INFRA_T_LIDAR.as_matrix()
    expected = (ego_T_lidar @ np.c_[xyz, np.ones(len(xyz))].T).T[:, :3]
    mine = past["points"]["fused"][:, -1] == 1.0
    np.testing.assert_allclose(past["points"]["fused"][mine, :3].numpy(), expected, atol=1e-4)
