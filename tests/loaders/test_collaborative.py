"""Collaborative items: agents, poses, communication range and rate, early fusion, noise."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from avdata.loaders import Collaboration, FrameDataset, FrameOptions, LabelFilter
from tests.loaders.conftest import PERIOD_NS, T0_NS, lidar_points, world_T_ego, world_T_infra

AGENTS = ["ego", "infra_00", "infra_01", "infra_02"]


def collaborative(dataset: Path, labels: LabelFilter | None = None, **link) -> FrameDataset:
    """Every lidar of the ego and the infrastructure; ``link`` goes to the Collaboration."""
    options = FrameOptions(sensors=("*/lidar*",), labels=labels or LabelFilter(),
                           collaboration=Collaboration(agents=("ego", "infra_*"), **link))
    return FrameDataset(dataset, options, scenes=["v2i"])


def test_agents_poses_and_distances(dataset: Path) -> None:
    ds = collaborative(dataset)
    for k in range(3):
        item = ds[k]
        t = T0_NS + k * PERIOD_NS
        assert item["agents"] == AGENTS
        ego_T_world = np.linalg.inv(world_T_ego(t).as_matrix())
        expected = [np.eye(4)] + [ego_T_world @ world_T_infra(a).as_matrix() for a in AGENTS[1:]]
        np.testing.assert_allclose(item["agent_poses"].numpy(), np.stack(expected), atol=1e-9)
        ego_y = 5.0 + k
        distances = [0.0, np.hypot(20.0, 20.0 - ego_y), np.hypot(60.0, 50.0 - ego_y), 125.0 - ego_y]
        np.testing.assert_allclose(item["agent_distance_m"].numpy(), distances, atol=1e-9)
        assert item["agent_received"].tolist() == [True] * 4
        assert sorted(item["points"]) == ["ego/lidar_top", "infra_00/lidar", "infra_01/lidar", "infra_02/lidar"]


@pytest.mark.parametrize(
    ("comm_range_m", "received"),
    [(None, [True, True, True, True]), (80.0, [True, True, True, False]), (50.0, [True, True, False, False]),
     (10.0, [True, False, False, False])],
)
def test_comm_range_restricts_which_agents_arrive(dataset: Path, comm_range_m, received) -> None:
    item = collaborative(dataset, comm_range_m=comm_range_m)[0]
    assert item["agent_received"].tolist() == received
    arrived = {a for a, r in zip(AGENTS, received, strict=True) if r}
    assert sorted(item["points"]) == sorted(f"{a}/lidar" if a != "ego" else "ego/lidar_top" for a in arrived)


@pytest.mark.parametrize(
    ("rate_hz", "per_frame"),
    [
        (10.0, [[True] * 4] * 3),
        (5.0, [[True] * 4, [True, False, False, False], [True] * 4]),
        (3.0, [[True] * 4, [True, False, False, False], [True, False, False, False]]),
        ({"infra_00": 5.0}, [[True] * 4, [True, False, True, True], [True] * 4]),
    ],
)
def test_rate_restricts_which_frames_an_agent_sends(dataset: Path, rate_hz, per_frame) -> None:
    ds = collaborative(dataset, rate_hz=rate_hz)
    assert [ds[k]["agent_received"].tolist() for k in range(3)] == per_frame


def test_early_fusion_concatenates_received_clouds_with_agent_index(dataset: Path) -> None:
    separate = collaborative(dataset, comm_range_m=80.0)[1]
    fused = collaborative(dataset, comm_range_m=80.0, fusion="early")[1]
    assert list(fused["points"]) == ["fused"]
    # the ego cloud has no object_id field, so only the common fields survive
    assert fused["point_fields"]["fused"] == ("x", "y", "z", "intensity", "agent_index")
    cloud = fused["points"]["fused"]
    parts = [separate["points"][s] for s in ("ego/lidar_top", "infra_00/lidar", "infra_01/lidar")]
    assert len(cloud) == sum(len(p) for p in parts)
    expected = torch.cat([torch.cat([p[:, :4], torch.full((len(p), 1), float(i))], dim=1) for i, p in enumerate(parts)])
    assert torch.equal(cloud, expected)


def test_visible_by_and_visibility_filter_use_only_arriving_agents(dataset: Path) -> None:
    everyone = collaborative(dataset)[0]
    assert everyone["object_ids"] == ["a", "b", "c", "d"]
    # rows: ego, infra_00, infra_01 (no visibility labels), infra_02
    assert everyone["visible_by"].int().tolist() == [[1, 1, 0, 1], [1, 0, 0, 1], [0, 0, 0, 0], [0, 0, 1, 0]]
    near = collaborative(dataset, LabelFilter(visible_to="infra_*/lidar"), comm_range_m=50.0)[0]
    assert near["object_ids"] == ["a", "d"]
    assert near["visible_by"].int().tolist() == [[1, 1], [1, 1], [0, 0], [0, 0]]
    far = collaborative(dataset, LabelFilter(visible_to="infra_*/lidar", min_points=5))[0]
    assert far["object_ids"] == ["a", "c"]


def test_point_noise_is_deterministic_and_only_on_other_agents(dataset: Path) -> None:
    clean = collaborative(dataset)[2]
    noisy = collaborative(dataset, noise_std_m=0.5, seed=3)
    first, again = noisy[2], noisy[2]
    assert torch.equal(first["points"]["infra_00/lidar"], again["points"]["infra_00/lidar"])
    assert torch.equal(first["points"]["ego/lidar_top"], clean["points"]["ego/lidar_top"])
    other_seed = collaborative(dataset, noise_std_m=0.5, seed=4)[2]
    assert not torch.equal(first["points"]["infra_00/lidar"], other_seed["points"]["infra_00/lidar"])
    differences = torch.cat([first["points"][s][:, :3] - clean["points"][s][:, :3]
                             for s in ("infra_00/lidar", "infra_01/lidar", "infra_02/lidar")])
    assert len(differences) > 150
    assert float(differences.std()) == pytest.approx(0.5, abs=0.08)
    assert float(differences.mean().abs()) < 0.08
    for s in ("infra_00/lidar",):
        assert torch.equal(first["points"][s][:, 3], torch.from_numpy(lidar_points(s, 2)["intensity"]))
