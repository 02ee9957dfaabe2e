"""RSS minimum safe distances, each formula branch worked by hand (rho 0.5 s, a_acc 3.5, b_min 4, b_max 8,
b_correct 3; lateral a 0.2, b 0.8, mu 0.1), and the dataset-level evaluation on hand-made tables."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

from avdata.errors import InputError
from avdata.eval.safety import (
    RssParameters,
    evaluate_safety,
    lateral_safe_distance,
    longitudinal_safe_distance,
    longitudinal_safe_distance_opposite,
    longitudinal_safe_distance_same_direction,
    rss_violations,
)


def test_same_direction_by_hand() -> None:
    # 10*0.5 + 0.5*3.5*0.25 + (10 + 1.75)^2 / 8 - 10^2 / 16 = 5 + 0.4375 + 17.2578125 - 6.25
    assert longitudinal_safe_distance_same_direction(np.array([10.0]), np.array([10.0]))[0] == pytest.approx(16.4453125)
    # A fast car in front: 0.4375 + 1.75^2 / 8 - 400 / 16 < 0, clipped to 0.
    assert longitudinal_safe_distance_same_direction(np.array([0.0]), np.array([20.0]))[0] == 0.0


def test_opposite_directions_by_hand() -> None:
    # v1 = 10 (correct lane), v2 = 5: (10 + 11.75)/2*0.5 + 11.75^2/6 + (5 + 6.75)/2*0.5 + 6.75^2/8
    expected = 5.4375 + 138.0625 / 6 + 2.9375 + 45.5625 / 8
    assert longitudinal_safe_distance_opposite(np.array([10.0]), np.array([-5.0]))[0] == pytest.approx(expected)


def test_lateral_by_hand() -> None:
    # Both drifting towards each other: left 0.5 m/s, right -0.3 m/s along the left-to-right axis.
    # left reach (0.5 + 0.6)/2*0.5 + 0.6^2/1.6 = 0.5; right reach (-0.3 - 0.4)/2*0.5 - 0.4^2/1.6 = -0.275
    assert lateral_safe_distance(np.array([0.5]), np.array([-0.3]))[0] == pytest.approx(0.1 + 0.775)
    # Drifting apart: only the margin mu.
    assert lateral_safe_distance(np.array([-1.0]), np.array([1.0]))[0] == pytest.approx(0.1)
    # Both still: mu + (0.1/2*0.5 + 0.01/1.6) - (-0.1/2*0.5 - 0.01/1.6) = 0.1 + 0.0625
    assert lateral_safe_distance(np.array([0.0]), np.array([0.0]))[0] == pytest.approx(0.1625)


def test_longitudinal_branches() -> None:
    same = longitudinal_safe_distance_same_direction(np.array([10.0]), np.array([4.0]))[0]
    # Object ahead, both forward: Def. 1 with the ego behind.
    assert longitudinal_safe_distance(np.array([20.0]), np.array([10.0]), np.array([4.0]))[0] == pytest.approx(same)
    # Object behind, both forward: Def. 1 with the object behind (rear 10, front 4: the ego is the front car).
    assert longitudinal_safe_distance(np.array([-20.0]), np.array([4.0]), np.array([10.0]))[0] == pytest.approx(same)
    # Object ahead coming towards the ego: Def. 3 with the ego in its correct lane.
    opposite = longitudinal_safe_distance_opposite(np.array([10.0]), np.array([5.0]))[0]
    assert longitudinal_safe_distance(np.array([30.0]), np.array([10.0]), np.array([-5.0]))[0] == pytest.approx(opposite)
    # Object behind moving away backwards while the ego drives on: no distance needed.
    assert longitudinal_safe_distance(np.array([-30.0]), np.array([10.0]), np.array([-5.0]))[0] == 0.0
    # Both reversing, object behind: the object leads the motion; the reversing ego follows it.
    rev = longitudinal_safe_distance_same_direction(np.array([3.0]), np.array([2.0]))[0]
    assert longitudinal_safe_distance(np.array([-15.0]), np.array([-3.0]), np.array([-2.0]))[0] == pytest.approx(rev)


def test_violation_needs_both_directions_unsafe() -> None:
    ego_v = np.array([[10.0, 0.0], [10.0, 0.0]])
    rel = np.array([[10.0, 0.0], [10.0, 3.5]])  # same lane 10 m ahead; the next lane to the left
    viol = rss_violations(np.array([4.5, 1.9]), ego_v, rel, np.zeros(2), np.tile([4.5, 1.9], (2, 1)),
                          np.array([[10.0, 0.0], [10.0, 0.0]]))
    # Same lane: gap 10 - 4.5 = 5.5 m < 16.45 m and lateral overlap -> dangerous. Next lane: lateral gap
    # 3.5 - 1.9 = 1.6 m > 0.1625 m -> safe although longitudinally too close.
    assert viol.tolist() == [True, False]


def _frames(n: int, speed: float) -> pa.Table:
    t = np.arange(n) * 100_000_000
    return pa.table({"scene": ["s"] * n, "frame_index": np.arange(n), "timestamp_ns": t,
                     "world_T_ego_x_m": speed * t * 1e-9, "world_T_ego_y_m": np.zeros(n), "world_T_ego_z_m": np.zeros(n),
                     "world_T_ego_qw": np.ones(n), "world_T_ego_qx": np.zeros(n), "world_T_ego_qy": np.zeros(n),
                     "world_T_ego_qz": np.zeros(n)})


def _objects(n: int, gap_m: float, speed: float, ids: str = "car") -> pa.Table:
    t = np.arange(n) * 0.1
    return pa.table({"scene": ["s"] * n, "frame_index": np.arange(n), "object_id": [ids] * n,
                     "x_world_m": gap_m + speed * t, "y_world_m": np.zeros(n), "length_m": np.full(n, 4.5),
                     "width_m": np.full(n, 1.9), "yaw_world_rad": np.zeros(n), "vx_world_mps": np.full(n, speed),
                     "vy_world_mps": np.zeros(n)})


def test_evaluate_safety_on_tables() -> None:
    frames = _frames(5, 10.0)
    close = _objects(5, 10.0, 10.0)  # 10 m ahead at the same speed: dangerous every frame
    result = evaluate_safety(frames, close)
    assert (result.frames, result.pairs, result.violating_frames, result.violating_pairs) == (5, 5, 5, 5)
    # Tracks that see the car 30 m ahead: every violation missed; tracks on the car: none missed.
    far = _objects(5, 40.0, 10.0)
    missed = evaluate_safety(frames, close, far)
    assert (missed.missed_violations, missed.invented_violations, missed.track_violating_pairs) == (5, 0, 0)
    caught = evaluate_safety(frames, close, close)
    assert (caught.missed_violations, caught.invented_violations, caught.track_violating_pairs) == (0, 0, 5)
    invented = evaluate_safety(frames, far, close)  # truth is safe, the tracker thinks it is close
    assert invented.invented_violations == 5 and invented.violating_pairs == 0
    # The ego's own box is not an object it can collide with.
    assert evaluate_safety(frames, close, exclude_ids=frozenset({"car"})).pairs == 0
    assert result.as_dict()["violating_frame_fraction"] == 1.0


def test_bad_inputs_name_the_row() -> None:
    bad = _objects(3, 10.0, 10.0)
    bad = bad.set_column(bad.schema.get_field_index("x_world_m"), "x_world_m", pa.array([1.0, np.nan, 3.0]))
    with pytest.raises(InputError, match=r"finite values.*'x_world_m': nan.*scene 's' frame 1"):
        evaluate_safety(_frames(3, 10.0), bad)
    with pytest.raises(InputError, match="vx_world_mps"):
        evaluate_safety(_frames(3, 10.0), _objects(3, 10.0, 10.0).drop(["vx_world_mps"]))
    with pytest.raises(InputError, match="frames.parquet"):
        evaluate_safety(_frames(2, 10.0), _objects(3, 10.0, 10.0))
    with pytest.raises(InputError, match="min_brake_mps2"):
        RssParameters(min_brake_mps2=0.0)
