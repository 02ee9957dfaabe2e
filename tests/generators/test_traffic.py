"""Traffic: no two objects ever overlap, speeds and accelerations stay plausible, real class sizes."""

from __future__ import annotations

import numpy as np
import pytest

from avdata.generators.config import scenario_from_dict
from avdata.generators.simulator import SIM_STEP_S, SceneSimulator
from avdata.generators.sizes import CLASS_SPECS, sample_sizes


def overlapping_pairs(xy: np.ndarray, yaw: np.ndarray, length: np.ndarray, width: np.ndarray) -> np.ndarray:
    """(K, 2) index pairs of oriented rectangles that overlap (separating axis test, all pairs)."""
    c, s = np.cos(yaw), np.sin(yaw)
    axes = np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], axis=1)  # (N, 2 axes, 2)
    half = np.stack([length / 2, width / 2], axis=-1)  # (N, 2)
    n = len(xy)
    pair_axes = np.concatenate([np.broadcast_to(axes[:, None], (n, n, 2, 2)),
                                np.broadcast_to(axes[None, :], (n, n, 2, 2))], axis=2)  # (i, j, 4, 2)
    radius_i = (np.abs(np.einsum("ijkd,imd->ijkm", pair_axes, axes)) * half[:, None, None, :]).sum(-1)
    radius_j = (np.abs(np.einsum("ijkd,jmd->ijkm", pair_axes, axes)) * half[None, :, None, :]).sum(-1)
    distance = np.abs(np.einsum("ijkd,ijd->ijk", pair_axes, xy[None, :, :] - xy[:, None, :]))
    overlap = ~(distance > radius_i + radius_j).any(axis=-1)
    np.fill_diagonal(overlap, False)
    return np.argwhere(np.triu(overlap))


def test_separating_axis_check_detects_overlap_and_clearance():
    xy = np.array([[0.0, 0.0], [3.9, 0.0], [-0.5, 1.9], [10.0, 0.0]])
    pairs = overlapping_pairs(xy, np.array([0.0, 0.0, 0.0, np.pi / 4]), np.full(4, 4.0), np.full(4, 2.0))
    assert pairs.tolist() == [[0, 1], [0, 2]]


LONG_VEHICLES = {"car": 0.3, "truck": 0.3, "bus": 0.3, "cyclist": 0.1}


@pytest.mark.parametrize(("seed", "class_weights"), [(0, None), (1, LONG_VEHICLES)])
def test_no_two_objects_interpenetrate_in_dense_traffic(seed, class_weights):
    traffic = {"vehicles": 60, "pedestrians": 60, "crossing_pedestrians": 40, "warmup_s": 0.15}
    if class_weights:
        traffic["class_weights"] = class_weights
    config = scenario_from_dict({"seed": seed, "town": {"grid": [3, 3], "block_pitch_m": 70}, "traffic": traffic},
                                "test")
    sim = SceneSimulator(config, 0)
    try:
        moved = np.zeros(config.traffic.vehicles)
        max_speed = 0.0
        min_accel = 0.0
        for step in range(900):  # 45 s
            sim.advance(SIM_STEP_S)
            state = sim.traffic.state
            moved += state.speed_mps * SIM_STEP_S
            max_speed = max(max_speed, float(state.speed_mps.max()))
            min_accel = min(min_accel, float(state.accel_mps2.min()))
            if step % 5 == 0:
                center, yaw = sim._history[-1]
                pairs = overlapping_pairs(center[:, :2], yaw, sim.size_lwh[:, 0], sim.size_lwh[:, 1])
                assert len(pairs) == 0, f"t={step * SIM_STEP_S:.2f} s: {sim.classes[pairs[0]]} overlap"
        assert max_speed <= max(s.desired_speed_mps[1] for s in CLASS_SPECS.values()) + 1e-9
        assert min_accel >= -9.0 - 1e-9
        # Traffic flows: most vehicles travel more than a block length in 45 s.
        assert np.median(moved) > 60.0
    finally:
        sim.close()


def test_sizes_follow_the_cited_class_means():
    rng = np.random.default_rng(0)
    for name, spec in CLASS_SPECS.items():
        sizes = sample_sizes(np.full(4000, name), rng)
        np.testing.assert_allclose(sizes.mean(axis=0), spec.mean_lwh_m, rtol=0.01)
        # A normal clipped at 2 sigma keeps 0.959 of its standard deviation.
        np.testing.assert_allclose(sizes.std(axis=0) / sizes.mean(axis=0), spec.cv * 0.959, rtol=0.05)
        assert np.all(np.abs(sizes / spec.mean_lwh_m - 1.0) <= 2 * spec.cv + 1e-12)


def test_crossing_pedestrians_cross_during_walk_phases_only():
    config = scenario_from_dict({
        "seed": 5,
        "town": {"grid": [2, 2], "block_pitch_m": 70},
        "traffic": {"vehicles": 20, "pedestrians": 10, "crossing_pedestrians": 16, "warmup_s": 0.15},
    }, "test")
    sim = SceneSimulator(config, 0)
    try:
        traffic = sim.traffic
        start_side = traffic.crosser_at_end.copy()
        lanes = traffic.town.lanes
        for _ in range(1200):  # 60 s
            sim.advance(SIM_STEP_S)
            crossing_nodes = np.unique(traffic.town.crosswalk_node[traffic.crosser_line[traffic.crosser_crossing]])
            # While anyone crosses at an intersection, it shows no green and no vehicle is inside it.
            assert not traffic._green[crossing_nodes].any()
            inside = lanes.kind[traffic.state.lane] == 1
            assert not np.isin(lanes.node[traffic.state.lane[inside]], crossing_nodes).any()
        assert (traffic.crosser_at_end != start_side).sum() >= 6
    finally:
        sim.close()
