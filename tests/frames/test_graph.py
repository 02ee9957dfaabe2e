"""FrameGraph: tf2-shaped lookups, interpolation and its errors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation, Slerp

from avdata.errors import AvdataError, ConnectivityError, ExtrapolationError, UnknownFrameError
from avdata.frames import FrameGraph, Transform


def random_transform(rng: np.random.Generator) -> Transform:
    return Transform.from_quat_wxyz(rng.normal(size=4), rng.normal(scale=5.0, size=3))


def test_lookup_through_five_level_chain_equals_product_of_matrices() -> None:
    rng = np.random.default_rng(42)
    graph = FrameGraph()
    names = ["world", "a", "a/b", "a/b/c", "a/b/c/d", "a/b/c/d/e"]
    edges = [random_transform(rng) for _ in range(5)]
    for parent, child, edge in zip(names, names[1:], edges, strict=False):
        graph.add_static(parent, child, edge)
    expected = np.linalg.multi_dot([e.as_matrix() for e in edges])
    np.testing.assert_allclose(graph.lookup("world", "a/b/c/d/e").as_matrix(), expected, atol=1e-9)
    np.testing.assert_allclose(graph.lookup("a/b/c/d/e", "world").as_matrix(), np.linalg.inv(expected), atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31), st.integers(0, 7), st.integers(0, 7))
def test_lookup_there_and_back_is_identity(seed: int, i: int, j: int) -> None:
    rng = np.random.default_rng(seed)
    graph = FrameGraph()
    graph.add_frame("f0")
    for k in range(1, 8):
        graph.add_static(f"f{rng.integers(0, k)}", f"f{k}", random_transform(rng))
    there = graph.lookup(f"f{i}", f"f{j}")
    back = graph.lookup(f"f{j}", f"f{i}")
    assert (there @ back).allclose(Transform.identity(), atol=1e-9)


def test_siblings_resolve_through_common_ancestor() -> None:
    graph = FrameGraph()
    ego_T_lidar = Transform.from_yaw(np.pi / 2, [1.0, 0.0, 2.0])
    ego_T_cam = Transform.from_euler("ZYX", [0.1, 0.2, 0.3], [2.0, 0.5, 1.5])
    graph.add_static("ego", "ego/lidar", ego_T_lidar)
    graph.add_static("ego", "ego/cam", ego_T_cam)
    cam_T_lidar = graph.lookup("ego/cam", "ego/lidar")
    assert cam_T_lidar.allclose(ego_T_cam.inverse() @ ego_T_lidar, atol=1e-12)


def test_stamped_edge_interpolates_with_slerp_and_lerp() -> None:
    rng = np.random.default_rng(7)
    poses = [random_transform(rng) for _ in range(3)]
    times = np.array([1_000, 2_000, 4_000])
    graph = FrameGraph()
    graph.add_stamped("world", "ego", times, Transform.stack(poses))
    graph.add_static("ego", "ego/lidar", Transform.from_yaw(0.3, [1.0, 0.0, 1.8]))
    query = np.array([1_000, 1_500, 2_000, 3_000, 4_000])
    world_T_ego = graph.lookup("world", "ego", query)
    slerp = Slerp(times, Rotation.from_matrix(np.stack([p.rotation for p in poses])))
    np.testing.assert_allclose(world_T_ego.rotation, slerp(query).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(world_T_ego.translation[1], (poses[0].translation + poses[1].translation) / 2, atol=1e-12)
    np.testing.assert_allclose(world_T_ego.translation[3], (poses[1].translation + poses[2].translation) / 2, atol=1e-12)
    single = graph.lookup("world", "ego/lidar", 1_500)
    assert single.allclose(world_T_ego[1] @ Transform.from_yaw(0.3, [1.0, 0.0, 1.8]), atol=1e-12)


def test_extrapolation_is_refused_beyond_tolerance_and_held_within() -> None:
    graph = FrameGraph()
    graph.add_stamped("world", "ego", np.array([100, 200]),
                      Transform.stack([Transform.from_yaw(0.0, [0, 0, 0]), Transform.from_yaw(0.0, [1, 0, 0])]))
    with pytest.raises(ExtrapolationError, match=r"'world' -> 'ego'.*requested time 250 ns.*\[100, 200\] ns"):
        graph.lookup("world", "ego", 250)
    with pytest.raises(ExtrapolationError, match="into the past"):
        graph.lookup("world", "ego", 50)
    held = graph.lookup("world", "ego", 250, max_extrapolation_ns=60)
    np.testing.assert_allclose(held.translation, [1.0, 0.0, 0.0])
    with pytest.raises(ExtrapolationError, match="without a time"):
        graph.lookup("world", "ego")


def test_unknown_and_disconnected_frames_raise_named_errors() -> None:
    graph = FrameGraph()
    graph.add_static("world", "ego", Transform.identity())
    graph.add_static("map", "infra_1", Transform.identity())
    with pytest.raises(UnknownFrameError, match="unknown frame 'ego/radar'"):
        graph.lookup("world", "ego/radar")
    with pytest.raises(ConnectivityError, match="no common ancestor"):
        graph.lookup("ego", "infra_1")
    assert not graph.can_lookup("ego", "infra_1")
    assert graph.can_lookup("ego", "world")


def test_tree_is_checked_on_insert() -> None:
    graph = FrameGraph()
    graph.add_static("a", "b", Transform.identity())
    graph.add_static("b", "c", Transform.identity())
    with pytest.raises(AvdataError, match="loop"):
        graph.add_static("c", "a", Transform.identity())
    with pytest.raises(AvdataError, match="already has parent"):
        graph.add_static("x", "c", Transform.identity())
    with pytest.raises(AvdataError, match="two different"):
        graph.add_stamped("world", "ego", np.array([5, 5]),
                          Transform.stack([Transform.identity(), Transform.from_yaw(1.0)]))


def test_stamped_samples_merge_in_time_order() -> None:
    graph = FrameGraph()
    graph.add_stamped("world", "ego", np.array([300]), Transform.from_yaw(0.0, [3.0, 0.0, 0.0]))
    graph.add_stamped("world", "ego", np.array([100]), Transform.from_yaw(0.0, [1.0, 0.0, 0.0]))
    np.testing.assert_array_equal(graph.stamped_edge("ego").timestamps_ns, [100, 300])
    np.testing.assert_allclose(graph.lookup("world", "ego", 200).translation, [2.0, 0.0, 0.0])


def _moving_ego_graph() -> FrameGraph:
    rng = np.random.default_rng(7)
    graph = FrameGraph()
    stamps = np.arange(0, 1_000_000_001, 100_000_000, dtype=np.int64)
    poses = Transform.stack([random_transform(rng) for _ in stamps])
    graph.add_stamped("world", "ego", stamps, poses)
    graph.add_static("ego", "ego/lidar", random_transform(rng))
    graph.add_static("ego", "ego/cam", random_transform(rng))
    graph.add_static("world", "infra", random_transform(rng))
    graph.add_static("infra", "infra/lidar", random_transform(rng))
    return graph


def _fixed_by_hand(graph: FrameGraph, target: str, t_target: int, source: str, t_source: int) -> Transform:
    # The rule the loaders used before it moved to FrameGraph: one lookup at a shared time, else through world.
    if t_target == t_source:
        return graph.lookup(target, source, t_target)
    return graph.lookup(target, "world", t_target) @ graph.lookup("world", source, t_source)


@pytest.mark.parametrize(("target", "source"), [("ego", "ego/lidar"), ("ego/cam", "ego/lidar"), ("world", "ego/lidar"),
                                                ("ego/cam", "infra/lidar"), ("infra/lidar", "ego")])
def test_lookup_fixed_batched_equals_the_old_rule_one_query_at_a_time(target: str, source: str) -> None:
    graph = _moving_ego_graph()
    # shared times (on and between samples) and differing ones, the sensor before and after the target
    t_target = np.array([100_000_000, 150_000_000, 300_000_000, 420_000_000, 500_000_000, 900_000_000])
    t_source = np.array([100_000_000, 150_000_000, 320_000_000, 400_000_000, 480_000_000, 900_000_000])
    batched = graph.lookup_fixed(target, t_target, source, t_source)
    assert batched.shape == (6,)
    for i, (a, b) in enumerate(zip(t_target.tolist(), t_source.tolist(), strict=True)):
        one = graph.lookup_fixed(target, a, source, b)
        assert one.shape == ()
        by_hand = _fixed_by_hand(graph, target, a, source, b)
        np.testing.assert_array_equal(one.rotation, by_hand.rotation)
        np.testing.assert_array_equal(one.translation, by_hand.translation)
        np.testing.assert_allclose(batched[i].as_matrix(), by_hand.as_matrix(), atol=1e-12)
    # a scalar target time broadcasts against source times
    np.testing.assert_allclose(graph.lookup_fixed(target, 300_000_000, source, t_source).as_matrix(),
                               np.stack([_fixed_by_hand(graph, target, 300_000_000, source, int(t)).as_matrix()
                                         for t in t_source]), atol=1e-12)


def test_lookup_fixed_compensates_motion_between_two_frames_on_one_moving_body() -> None:
    # Camera and lidar hang statically under the moving ego: a cloud taken 200 ms before the image is seen from
    # where the camera is at the image time, not as if the ego had stood still (viz drew it the latter way).
    graph = _moving_ego_graph()
    t_image, t_cloud = 500_000_000, 300_000_000
    fixed = graph.lookup_fixed("ego/cam", t_image, "ego/lidar", t_cloud)
    expected = (graph.lookup("ego/cam", "ego", None) @ graph.lookup("ego", "world", t_image)
                @ graph.lookup("world", "ego", t_cloud) @ graph.lookup("ego", "ego/lidar", None))
    np.testing.assert_allclose(fixed.as_matrix(), expected.as_matrix(), atol=1e-9)
    assert not fixed.allclose(graph.lookup("ego/cam", "ego/lidar", None), atol=1e-3)
    with pytest.raises(ExtrapolationError, match="world"):
        graph.lookup_fixed("ego/cam", 5_000_000_000, "ego/lidar", t_cloud)
    with pytest.raises(UnknownFrameError, match="nowhere"):
        graph.lookup_fixed("ego/cam", t_image, "ego/lidar", t_cloud, fixed="nowhere")
