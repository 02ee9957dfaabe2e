"""Intermediate and late fusion layouts, latency, pose noise, and their collate functions.

Hand-built expectations come from the frame tree of ``tests/loaders/conftest.py`` (poses written
there as formulas), never from the loader. The pairwise convention is OpenCOOD's
``get_pairwise_transformation`` (opencood/data_utils/datasets/intermediate_fusion_dataset.py):
``pairwise_t_matrix[i, j] = inv(T_j) @ T_i``, agent i's points into agent j's frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from avdata.errors import AvdataError
from avdata.frames import Transform
from avdata.loaders import Collaboration, FrameDataset, FrameOptions, LabelFilter, collate_intermediate, collate_late
from tests.loaders.conftest import (
    EGO_T_LIDAR,
    INFRA_T_LIDAR,
    PERIOD_NS,
    T0_NS,
    boxes_world,
    lidar_points,
    visibility_table,
    world_T_ego,
    world_T_infra,
)

AGENTS = ["ego", "infra_00", "infra_01", "infra_02"]
LIDARS = ["ego/lidar_top", "infra_00/lidar", "infra_01/lidar", "infra_02/lidar"]


def collaborative(dataset: Path, frame: str = "ego", labels: LabelFilter | None = None, **link) -> FrameDataset:
    options = FrameOptions(sensors=("*/lidar*",), frame=frame, labels=labels or LabelFilter(),
                           collaboration=Collaboration(agents=("ego", "infra_*"), **link))
    return FrameDataset(dataset, options, scenes=["v2i"])


def world_T_lidar(agent: str, time_ns: int) -> np.ndarray:
    if agent == "ego":
        return (world_T_ego(time_ns) @ EGO_T_LIDAR).as_matrix()
    return (world_T_infra(agent) @ INFRA_T_LIDAR).as_matrix()


def stored_xyz(sensor: str, k: int) -> np.ndarray:
    cloud = lidar_points(sensor, k)
    return np.stack([cloud["x"], cloud["y"], cloud["z"]], axis=1).astype(np.float64)


def apply(matrix: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    return xyz @ matrix[:3, :3].T + matrix[:3, 3]


def test_intermediate_layout_equals_the_hand_built_item(dataset: Path) -> None:
    k = 1
    t = T0_NS + k * PERIOD_NS
    item = collaborative(dataset, fusion="intermediate")[k]
    assert item["agents"] == AGENTS
    assert item["agent_frames"] == LIDARS
    assert sorted(item["points"]) == AGENTS
    for agent, sensor in zip(AGENTS, LIDARS, strict=True):  # each cloud stays in its own lidar frame, untouched
        cloud = lidar_points(sensor, k)
        expected = np.stack([cloud["x"], cloud["y"], cloud["z"], cloud["intensity"]], axis=1)
        assert item["points"][agent][:, :4].numpy().tobytes() == expected.tobytes()
    pairwise = item["pairwise_T"].numpy()
    assert pairwise.shape == (5, 5, 4, 4)
    assert item["agent_mask"].tolist() == [True, True, True, True, False]
    for i, a in enumerate(AGENTS):
        for j, b in enumerate(AGENTS):
            expected = np.linalg.inv(world_T_lidar(b, t)) @ world_T_lidar(a, t)
            np.testing.assert_allclose(pairwise[i, j], expected, atol=1e-9)
    np.testing.assert_array_equal(pairwise[4], np.tile(np.eye(4), (5, 1, 1)))
    np.testing.assert_array_equal(pairwise[:, 4], np.tile(np.eye(4), (5, 1, 1)))


def test_pairwise_direction_moves_an_agent_cloud_where_early_fusion_puts_it(dataset: Path) -> None:
    inter = collaborative(dataset, fusion="intermediate")[2]
    early = collaborative(dataset, frame="ego/lidar_top")[2]
    for i, (agent, sensor) in enumerate(zip(AGENTS, LIDARS, strict=True)):
        in_ego_lidar = apply(inter["pairwise_T"][i, 0].numpy(), inter["points"][agent][:, :3].double().numpy())
        np.testing.assert_allclose(in_ego_lidar, early["points"][sensor][:, :3].double().numpy(), atol=1e-4)


def test_unreceived_agents_come_last_and_are_masked(dataset: Path) -> None:
    item = collaborative(dataset, fusion="intermediate", comm_range_m=50.0, max_agents=4)[0]
    assert item["agents"] == ["ego", "infra_00", "infra_01", "infra_02"]
    assert item["agent_mask"].tolist() == [True, True, False, False]
    assert sorted(item["points"]) == ["ego", "infra_00"]
    np.testing.assert_array_equal(item["pairwise_T"][2:].numpy(), np.tile(np.eye(4), (2, 4, 1, 1)))
    with pytest.raises(AvdataError, match="max_agents=3"):
        collaborative(dataset, fusion="intermediate", max_agents=3)[0]


def test_late_layout_gives_each_agent_its_labels_in_its_own_frame(dataset: Path) -> None:
    k = 2
    t = T0_NS + k * PERIOD_NS
    item = collaborative(dataset, fusion="late")[k]
    world = boxes_world(k)
    for agent, sensor in zip(AGENTS, LIDARS, strict=True):
        lidar_T_world = Transform.from_matrix(np.linalg.inv(world_T_lidar(agent, t)))
        moved = world.transform(lidar_T_world, sensor)
        expected = np.concatenate([moved.center, moved.size_lwh, moved.yaw()[:, None]], axis=1)
        np.testing.assert_allclose(item["agent_boxes"][agent].numpy(), expected, atol=1e-4)
        assert item["agent_object_ids"][agent] == ["a", "b", "c", "d"]
        assert item["agent_labels"][agent].tolist() == item["labels"].tolist()


def test_early_layout_equals_the_hand_built_item(dataset: Path) -> None:
    k = 2
    t = T0_NS + k * PERIOD_NS
    item = collaborative(dataset, fusion="early")[k]
    ego_T_world = np.linalg.inv(world_T_ego(t).as_matrix())
    parts = []
    for index, (agent, sensor) in enumerate(zip(AGENTS, LIDARS, strict=True)):
        xyz = apply(ego_T_world @ world_T_lidar(agent, t), stored_xyz(sensor, k))
        intensity = lidar_points(sensor, k)["intensity"].astype(np.float64)
        parts.append(np.column_stack([xyz, intensity, np.full(len(xyz), float(index))]))
    assert item["point_fields"]["fused"] == ("x", "y", "z", "intensity", "agent_index")
    np.testing.assert_allclose(item["points"]["fused"].double().numpy(), np.concatenate(parts), atol=1e-4)


def test_late_layout_keeps_the_clouds_and_pairwise_transforms_of_the_intermediate_one(dataset: Path) -> None:
    k = 1
    t = T0_NS + k * PERIOD_NS
    late = collaborative(dataset, fusion="late")[k]
    for i, (agent, sensor) in enumerate(zip(AGENTS, LIDARS, strict=True)):
        expected = np.stack([lidar_points(sensor, k)[f] for f in ("x", "y", "z", "intensity")], axis=1)
        assert late["points"][agent][:, :4].numpy().tobytes() == expected.tobytes()
        for j, other in enumerate(AGENTS):
            hand = np.linalg.inv(world_T_lidar(other, t)) @ world_T_lidar(agent, t)
            np.testing.assert_allclose(late["pairwise_T"][i, j].numpy(), hand, atol=1e-9)
    assert late["agent_mask"].tolist() == [True] * 4 + [False]


def test_latency_of_one_frame_moves_points_exactly_by_the_ego_motion(dataset: Path) -> None:
    clean = collaborative(dataset)
    late = collaborative(dataset, latency_ms={"infra_*": 100.0})
    first = late[0]
    assert first["agent_received"].tolist() == [True, False, False, False]  # nothing sent 100 ms before frame 0
    for k in (1, 2):
        item, before = late[k], clean[k - 1]
        t, t_before = T0_NS + k * PERIOD_NS, T0_NS + (k - 1) * PERIOD_NS
        assert item["agent_received"].tolist() == [True] * 4
        assert item["agent_timestamps_ns"].tolist() == [t, t_before, t_before, t_before]
        assert item["sensor_timestamps_ns"]["infra_00/lidar"] == t_before
        assert torch.equal(item["points"]["ego/lidar_top"], clean[k]["points"]["ego/lidar_top"])  # the ego never waits
        ego_now_T_ego_before = np.linalg.inv(world_T_ego(t).as_matrix()) @ world_T_ego(t_before).as_matrix()
        for sensor in LIDARS[1:]:
            expected = apply(ego_now_T_ego_before, before["points"][sensor][:, :3].double().numpy())
            np.testing.assert_allclose(item["points"][sensor][:, :3].double().numpy(), expected, atol=1e-4)
            # one frame of ego motion at 10 m/s along the ego's x: 1 m
            moved = item["points"][sensor][:, :3].double().numpy() - before["points"][sensor][:, :3].double().numpy()
            np.testing.assert_allclose(moved, np.tile([-1.0, 0.0, 0.0], (len(moved), 1)), atol=1e-4)


def seen_by(sensor: str, frame_index: int) -> list[bool]:
    return [visibility_table(sensor, frame_index)[i][0] for i in ("a", "b", "c", "d")]


def test_latency_takes_labels_and_visibility_from_the_delayed_capture_of_the_points(dataset: Path) -> None:
    # infra_00 sees b and loses d from frame 1 on (conftest); one frame of latency must show frame 0's view
    assert seen_by("infra_00/lidar", 0) != seen_by("infra_00/lidar", 1)
    late = collaborative(dataset, fusion="late", latency_ms={"infra_*": 100.0})[1]
    clean = collaborative(dataset, fusion="late")[1]
    assert late["agent_timestamps_ns"].tolist()[1] == T0_NS  # the capture of frame 0 ...
    assert late["sensor_timestamps_ns"]["infra_00/lidar"] == T0_NS  # ... gives the points ...
    assert late["visible_by"][1].tolist() == seen_by("infra_00/lidar", 0)  # ... the per-sensor visibility ...
    assert clean["visible_by"][1].tolist() == seen_by("infra_00/lidar", 1)
    assert late["visible_by"][0].tolist() == clean["visible_by"][0].tolist()  # (the ego never waits)
    lidar_T_world = Transform.from_matrix(np.linalg.inv(world_T_lidar("infra_00", T0_NS)))
    then = boxes_world(0).transform(lidar_T_world, "infra_00/lidar")  # ... and the labels
    np.testing.assert_allclose(late["agent_boxes"]["infra_00"][:, :3].numpy(), then.center, atol=1e-4)
    assert not np.allclose(clean["agent_boxes"]["infra_00"][:, :3].numpy(), then.center, atol=1e-2)
    # a visibility filter through infra_00 keeps what its delayed capture saw
    only_infra = LabelFilter(visible_to="infra_00/lidar")
    assert collaborative(dataset, labels=only_infra, latency_ms={"infra_*": 100.0})[1]["object_ids"] == ["a", "d"]
    assert collaborative(dataset, labels=only_infra)[1]["object_ids"] == ["a", "b"]


def test_latency_holds_the_last_transmission_of_a_slower_agent(dataset: Path) -> None:
    ds = collaborative(dataset, latency_ms=50.0, rate_hz=5.0)
    # sends at frames 0 and 2; at t - 50 ms the last sending frame is 0 for frames 1 and 2
    assert [ds[k]["agent_received"].tolist() for k in range(3)] == [[True, False, False, False],
                                                                   [True, True, True, True],
                                                                   [True, False, False, False]]
    assert ds[1]["agent_timestamps_ns"].tolist() == [T0_NS + PERIOD_NS] + [T0_NS] * 3


@pytest.mark.parametrize("fusion", [None, "early", "intermediate", "late"])
def test_zero_noise_and_zero_latency_equal_the_clean_item(dataset: Path, fusion) -> None:
    clean = collaborative(dataset, fusion=fusion)[1]
    zero = collaborative(dataset, fusion=fusion, latency_ms=0.0, pose_noise=(0.0, 0.0, 0.0, 0.0), seed=7)[1]
    assert clean.keys() == zero.keys()
    for key, value in clean.items():
        if isinstance(value, dict):
            assert value.keys() == zero[key].keys()
            for name, inner in value.items():
                assert torch.equal(inner, zero[key][name]) if isinstance(inner, torch.Tensor) else inner == zero[key][name]
        elif isinstance(value, torch.Tensor):
            assert torch.equal(value, zero[key]), key
        else:
            assert value == zero[key], key


def test_pose_noise_statistics_match_the_sigmas_and_spare_the_ego(dataset: Path) -> None:
    sigmas = (0.5, 0.2, 0.1, 2.0)
    clean = collaborative(dataset)
    errors = []
    for seed in range(60):
        noisy = collaborative(dataset, pose_noise=sigmas, seed=seed)
        for k in range(3):
            item, truth = noisy[k], clean[k]
            assert torch.equal(item["agent_poses"][0], truth["agent_poses"][0])
            assert torch.equal(item["points"]["ego/lidar_top"], truth["points"]["ego/lidar_top"])
            world_T_ego_k = world_T_ego(T0_NS + k * PERIOD_NS).as_matrix()
            for a in range(1, 4):
                sent = world_T_ego_k @ item["agent_poses"][a].numpy()
                true = world_T_ego_k @ truth["agent_poses"][a].numpy()
                yaw = np.arctan2(sent[1, 0], sent[0, 0]) - np.arctan2(true[1, 0], true[0, 0])
                errors.append([*(sent[:3, 3] - true[:3, 3]), np.rad2deg((yaw + np.pi) % (2 * np.pi) - np.pi)])
    errors = np.array(errors)
    assert len(errors) == 540
    np.testing.assert_allclose(errors.std(axis=0), sigmas, rtol=0.1)
    assert np.all(np.abs(errors.mean(axis=0)) < 0.15 * np.array(sigmas))
    again = collaborative(dataset, pose_noise=sigmas, seed=59)[2]
    assert torch.equal(again["agent_poses"], noisy[2]["agent_poses"])
    assert torch.equal(again["points"]["infra_00/lidar"], noisy[2]["points"]["infra_00/lidar"])


def test_pose_noise_moves_clouds_and_pairwise_transforms_consistently(dataset: Path) -> None:
    noisy = collaborative(dataset, fusion="intermediate", pose_noise=(0.3, 0.3, 0.0, 1.0), seed=1)[1]
    early = collaborative(dataset, frame="ego/lidar_top", pose_noise=(0.3, 0.3, 0.0, 1.0), seed=1)[1]
    clean = collaborative(dataset, fusion="intermediate")[1]
    assert torch.equal(noisy["points"]["infra_00"], clean["points"]["infra_00"])  # own frame: no pose involved
    assert not torch.allclose(noisy["pairwise_T"][1, 0], clean["pairwise_T"][1, 0])
    moved = apply(noisy["pairwise_T"][1, 0].numpy(), noisy["points"]["infra_00"][:, :3].double().numpy())
    np.testing.assert_allclose(moved, early["points"]["infra_00/lidar"][:, :3].double().numpy(), atol=1e-4)


def test_predicted_poses_need_the_predicted_frame_for_moving_agents(dataset: Path) -> None:
    # the infrastructure's surveyed (static) poses have no GPS estimate: they are sent as recorded
    clean = collaborative(dataset, fusion="intermediate")[0]
    predicted = collaborative(dataset, fusion="intermediate", pose_source="predicted")[0]
    assert torch.equal(clean["pairwise_T"], predicted["pairwise_T"])
    with pytest.raises(AvdataError, match="pose_source"):
        Collaboration(agents=("*",), pose_source="gps")
    with pytest.raises(AvdataError, match="pose_noise"):
        Collaboration(agents=("*",), pose_noise=(0.1, 0.1, 0.1))


def test_collate_intermediate_and_late_follow_opencood_record_len(dataset: Path) -> None:
    items = [collaborative(dataset, fusion="late", comm_range_m=50.0)[k] for k in range(2)]
    items.append(collaborative(dataset, fusion="late")[2])
    batch = collate_late(items)
    assert batch["record_len"].tolist() == [2, 2, 4]
    assert batch["pairwise_T"].shape == (3, 5, 5, 4, 4)
    assert batch["agent_mask"].tolist()[2] == [True, True, True, True, False]
    order = [(0, "ego"), (0, "infra_00"), (1, "ego"), (1, "infra_00"), (2, "ego"), (2, "infra_00"), (2, "infra_01"),
             (2, "infra_02")]
    assert len(batch["points"]) == len(order)
    for r, (b, agent) in enumerate(order):
        assert torch.equal(batch["points"][r], items[b]["points"][agent])
        n = len(items[b]["agent_boxes"][agent])
        assert torch.equal(batch["agent_boxes"][r, :n], items[b]["agent_boxes"][agent])
        assert batch["agent_boxes_mask"][r].tolist() == [True] * n + [False] * (batch["agent_boxes"].shape[1] - n)
        assert batch["agent_object_ids"][r] == items[b]["agent_object_ids"][agent]
    assert batch["boxes"].shape == (3, 4, 7) and batch["boxes_mask"].all()
    inter = collate_intermediate([collaborative(dataset, fusion="intermediate")[0]])
    assert inter["record_len"].tolist() == [4] and "agent_boxes" not in inter
    with pytest.raises(AvdataError, match="fusion='late'"):
        collate_late([collaborative(dataset, fusion="intermediate")[0]])
