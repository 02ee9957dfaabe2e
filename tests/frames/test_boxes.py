"""Boxes3D against each source's own formula, on real label files where the repo has them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.feather as feather
import pytest
from scipy.spatial.transform import Rotation

from avdata.errors import AvdataError
from avdata.frames import RH_T_CARLA, Boxes3D, FrameGraph, Transform
from tests.realdata import REALDATA


def kitti_devkit_corners(h: float, w: float, l: float, x: float, y: float, z: float, ry: float) -> np.ndarray:
    """KITTI devkit ``compute_box_3d`` (rectified camera frame), corners as (8, 3)."""
    rot = np.array([[np.cos(ry), 0, np.sin(ry)], [0, 1, 0], [-np.sin(ry), 0, np.cos(ry)]])
    x_c = [l / 2, l / 2, -l / 2, -l / 2, l / 2, l / 2, -l / 2, -l / 2]
    y_c = [0, 0, 0, 0, -h, -h, -h, -h]
    z_c = [w / 2, -w / 2, -w / 2, w / 2, w / 2, -w / 2, -w / 2, w / 2]
    return (rot @ np.vstack([x_c, y_c, z_c])).T + np.array([x, y, z])


def nuscenes_devkit_corners(center: list, wlh: list, quat_wxyz: list) -> np.ndarray:
    """nuScenes devkit ``Box.corners()`` written out, corners as (8, 3)."""
    w, l, h = wlh
    x_c = l / 2 * np.array([1, 1, 1, 1, -1, -1, -1, -1])
    y_c = w / 2 * np.array([1, -1, -1, 1, 1, -1, -1, 1])
    z_c = h / 2 * np.array([1, 1, -1, -1, 1, 1, -1, -1])
    rotation = Rotation.from_quat(quat_wxyz, scalar_first=True).as_matrix()
    return (rotation @ np.vstack([x_c, y_c, z_c])).T + np.array(center)


def read_kitti_labels(path: Path) -> np.ndarray:
    rows = [line.split() for line in path.read_text().splitlines() if line.strip()]
    return np.array([[float(v) for v in row[8:15]] for row in rows if row[0] != "DontCare"])


@pytest.mark.parametrize("frame", ["000000", "000001", "000002"])
def test_kitti_boxes_match_devkit_corner_formula_on_real_labels(frame: str) -> None:
    labels = read_kitti_labels(REALDATA / "kitti/object/training/label_2" / f"{frame}.txt")
    assert len(labels) > 0
    boxes = Boxes3D.from_kitti_camera(labels[:, 0:3], labels[:, 3:6], labels[:, 6], "ego/cam0")
    ours = boxes.corners()
    # KITTI corner j has signs (x: length, z: width, y: 0 bottom / -h top); ours are (length, width, height up).
    kitti_to_ours = [3, 2, 6, 7, 0, 1, 5, 4]
    for box, label in zip(ours, labels, strict=True):
        h, w, l, x, y, z, ry = label
        np.testing.assert_allclose(box[kitti_to_ours], kitti_devkit_corners(h, w, l, x, y, z, ry), atol=1e-9)
    hwl, bottom, ry = boxes.to_kitti_camera()
    np.testing.assert_allclose(hwl, labels[:, 0:3], atol=1e-12)
    np.testing.assert_allclose(bottom, labels[:, 3:6], atol=1e-12)
    np.testing.assert_allclose(ry, labels[:, 6], atol=1e-12)


def test_nuscenes_boxes_match_devkit_corner_formula_on_real_lyft_annotations() -> None:
    table = REALDATA / "nuscenes_schema/lyft/v1.01-train/v1.01-train/sample_annotation.json"
    rows = json.loads(table.read_text())
    assert rows
    boxes = Boxes3D.from_nuscenes([r["translation"] for r in rows], [r["size"] for r in rows],
                                  [r["rotation"] for r in rows], "world")
    for box, row in zip(boxes.corners(), rows, strict=True):
        np.testing.assert_allclose(box, nuscenes_devkit_corners(row["translation"], row["size"], row["rotation"]),
                                   atol=1e-9)
    center, wlh, quat = boxes.to_nuscenes()
    np.testing.assert_allclose(wlh, [r["size"] for r in rows])
    np.testing.assert_allclose(np.abs(np.sum(quat * np.array([r["rotation"] for r in rows]), axis=1)), 1.0, atol=1e-12)


def test_argoverse2_cuboids_contain_their_annotated_interior_points() -> None:
    log = REALDATA / "argoverse2/sensor/val/7fab2350-7eaf-3b7e-a39d-6937a4c1bede"
    sweep_ns = 315966265259836000
    lidar = feather.read_table(log / f"sensors/lidar/{sweep_ns}.feather")
    points_ego = np.stack([lidar.column(c).to_numpy().astype(np.float64) for c in "xyz"], axis=1)
    cuboids = feather.read_table(log / "annotations.feather").to_pydict()
    at = np.array(cuboids["timestamp_ns"]) == sweep_ns
    col = {k: np.asarray(v)[at] for k, v in cuboids.items()}
    boxes = Boxes3D.from_av2(np.stack([col["tx_m"], col["ty_m"], col["tz_m"]], 1),
                             np.stack([col["length_m"], col["width_m"], col["height_m"]], 1),
                             np.stack([col["qw"], col["qx"], col["qy"], col["qz"]], 1), "ego")
    counts = boxes.contains(points_ego).sum(axis=1)
    exact = counts == col["num_interior_pts"]
    # float16 coordinates put a few points within millimetres of a face; the rest must agree exactly.
    assert exact.mean() > 0.95, f"only {exact.mean():.3f} of {len(exact)} cuboids match num_interior_pts"
    assert np.abs(counts - col["num_interior_pts"]).max() <= 3


def test_waymo_heading_round_trip() -> None:
    center = np.array([[10.0, -2.0, 1.0], [3.0, 4.0, 0.8]])
    size = np.array([[4.5, 2.0, 1.6], [0.8, 0.7, 1.8]])
    heading = np.array([0.5, -2.9])
    boxes = Boxes3D.from_waymo(center, size, heading, "ego")
    back_center, back_size, back_heading = boxes.to_waymo()
    np.testing.assert_allclose(back_heading, heading, atol=1e-12)
    np.testing.assert_allclose(boxes.corners()[0, 0, :2],
                               center[0, :2] + [2.25 * np.cos(0.5) - 1.0 * np.sin(0.5), 2.25 * np.sin(0.5) + 1.0 * np.cos(0.5)])


def test_boxes_move_through_the_graph() -> None:
    graph = FrameGraph()
    world_T_ego = Transform.from_yaw(np.pi / 2, [10.0, 0.0, 0.0])
    graph.add_static("world", "ego", world_T_ego)
    boxes_ego = Boxes3D.from_yaw([[5.0, 0.0, 1.0]], [[4.0, 2.0, 1.5]], [0.0], "ego", ids=["a"], classes=["car"],
                                 velocity=[[3.0, 0.0, 0.0]])
    boxes_world = boxes_ego.to("world", graph)
    np.testing.assert_allclose(boxes_world.center, [[10.0, 5.0, 1.0]], atol=1e-12)
    np.testing.assert_allclose(boxes_world.yaw(), [np.pi / 2], atol=1e-12)
    np.testing.assert_allclose(boxes_world.velocity, [[0.0, 3.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(boxes_world.corners(), world_T_ego.apply(boxes_ego.corners()[0])[None], atol=1e-12)
    assert boxes_world.ids.tolist() == ["a"] and boxes_world.frame == "world"


def test_bev_corners_are_counter_clockwise_footprint() -> None:
    boxes = Boxes3D.from_yaw([[0.0, 0.0, 0.0]], [[4.0, 2.0, 1.0]], [0.0], "ego")
    np.testing.assert_allclose(boxes.bev_corners()[0], [[2, 1], [-2, 1], [-2, -1], [2, -1]])
    x, y = boxes.bev_corners()[0].T
    assert 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) == pytest.approx(8.0)


def test_invalid_boxes_raise() -> None:
    with pytest.raises(AvdataError, match="non-negative"):
        Boxes3D.from_yaw([[0, 0, 0]], [[-1, 1, 1]], [0.0], "ego")
    with pytest.raises(AvdataError, match="expected 1 ids"):
        Boxes3D.from_yaw([[0, 0, 0]], [[1, 1, 1]], [0.0], "ego", ids=["a", "b"])


def _random_boxes(rng: np.random.Generator, n: int, frame: str) -> Boxes3D:
    quat = rng.normal(size=(n, 4))
    return Boxes3D(center=rng.normal(scale=20, size=(n, 3)), size_lwh=rng.uniform(0.5, 5, (n, 3)),
                   quat_wxyz=quat / np.linalg.norm(quat, axis=1, keepdims=True), frame=frame,
                   ids=[str(i) for i in range(n)], velocity=rng.normal(size=(n, 3)))


def test_batched_transform_moves_each_box_by_its_own_transform() -> None:
    rng = np.random.default_rng(3)
    boxes = _random_boxes(rng, 7, "a")
    transforms = [Transform.from_quat_wxyz(rng.normal(size=4), rng.normal(scale=50, size=3)) for _ in range(6)]
    transforms.append(RH_T_CARLA @ transforms[0])  # one reflection among proper transforms
    batch = Transform.stack(transforms)
    moved = boxes.transform(batch, "b")
    assert moved.frame == "b" and moved.ids.tolist() == boxes.ids.tolist()
    for i, single in enumerate(transforms):
        expected = boxes[i].transform(single, "b")
        np.testing.assert_allclose(moved.center[i], expected.center[0], atol=1e-12)
        np.testing.assert_allclose(moved.quat_wxyz[i], expected.quat_wxyz[0], atol=1e-12)
        np.testing.assert_allclose(moved.velocity[i], expected.velocity[0], atol=1e-12)
        # the moved solid is the transformed solid (corners as sets: a reflection reorders them)
        corners = single.apply(boxes.corners()[i])
        distances = np.linalg.norm(corners[:, None, :] - moved.corners()[i][None, :, :], axis=2)
        assert distances.min(axis=1).max() < 1e-9
    assert np.all(np.linalg.det(moved.rotation_matrix()) > 0.0)


def test_batched_transform_keeps_roll_and_pitch() -> None:
    # A tilted box moved by a tilted transform: its full orientation is the product of the two.
    boxes = Boxes3D(center=[[1.0, 2.0, 3.0]], size_lwh=[[4.0, 2.0, 1.5]], frame="a",
                    quat_wxyz=Transform.from_euler("ZYX", np.array([0.3, 0.2, -0.1])).quat_wxyz())
    target_T_a = Transform.from_euler("ZYX", np.array([[-1.0, 0.05, 0.4]]), np.array([[5.0, 0.0, 0.0]]))
    moved = boxes.transform(target_T_a, "b")
    expected = target_T_a.rotation[0] @ boxes.rotation_matrix()[0]
    np.testing.assert_allclose(moved.rotation_matrix()[0], expected, atol=1e-12)
    assert abs(moved.rotation_matrix()[0, 2, 0]) > 0.1  # tilted: roll/pitch survive


def test_boxes_move_through_the_graph_at_per_box_times() -> None:
    graph = FrameGraph()
    times = np.array([0, 100, 200])
    graph.add_stamped("world", "ego", times, Transform.from_yaw(np.array([0.0, 0.5, 1.0]),
                                                                np.array([[0.0, 0, 0], [10, 0, 0], [20, 5, 0]])))
    boxes = _random_boxes(np.random.default_rng(5), 4, "world")
    box_times = np.array([0, 50, 200, 150])
    moved = boxes.to("ego", graph, box_times)
    for i, t in enumerate(box_times):
        expected = boxes[i].to("ego", graph, int(t))
        np.testing.assert_allclose(moved.center[i], expected.center[0], atol=1e-12)
        np.testing.assert_allclose(moved.quat_wxyz[i], expected.quat_wxyz[0], atol=1e-12)


def test_transform_batch_of_the_wrong_length_raises() -> None:
    boxes = _random_boxes(np.random.default_rng(6), 3, "a")
    with pytest.raises(AvdataError, match=r"expected one transform or 3 \(one per box\).*shape \(2,\)"):
        boxes.transform(Transform.identity((2,)), "b")


def test_box_quaternions_off_unit_beyond_tolerance_are_rejected() -> None:
    with pytest.warns(UserWarning, match="box quaternions.*normalised"):
        boxes = Boxes3D(center=[[0, 0, 0]], size_lwh=[[1, 1, 1]], quat_wxyz=[[1.001, 0, 0, 0]], frame="a")
    np.testing.assert_array_equal(boxes.quat_wxyz, [[1.0, 0, 0, 0]])
    with pytest.raises(AvdataError, match=r"box quaternions.*expected a unit quaternion .* got deviation 1"):
        Boxes3D(center=[[0, 0, 0]], size_lwh=[[1, 1, 1]], quat_wxyz=[[0.0, 0, 0, 0]], frame="a")
    with pytest.raises(AvdataError, match="box quaternions.*finite"):
        Boxes3D(center=[[0, 0, 0]], size_lwh=[[1, 1, 1]], quat_wxyz=[[np.nan, 0, 0, 0]], frame="a")
