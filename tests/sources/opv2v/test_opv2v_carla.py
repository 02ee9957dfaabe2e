"""CARLA's left-handed boxes and poses (avdata.sources.opv2v.carla), worked by hand and against the mirror."""

from __future__ import annotations

import numpy as np
import pytest

from avdata.frames import RH_T_CARLA, carla_rotation_matrix
from avdata.sources.opv2v import boxes_from_carla, boxes_to_carla, carla_pose_matrix, world_T_carla_pose


def test_carla_box_worked_by_hand() -> None:
    # A CARLA car at (10, 5, 0.5) with yaw +30 deg (left-handed: turning from +x towards +y, i.e. to
    # the right), extent (2.0, 0.9, 0.75). In right-handed axes (y left) it stands at (10, -5, 0.5)
    # heading -30 deg, size 4.0 x 1.8 x 1.5.
    boxes = boxes_from_carla([[10.0, 5.0, 0.5]], [[2.0, 0.9, 0.75]], [[0.0, 0.0, 30.0]], "world",
                             velocity=[[np.cos(np.radians(30)), np.sin(np.radians(30)), 0.0]])
    np.testing.assert_allclose(boxes.center, [[10.0, -5.0, 0.5]])
    np.testing.assert_allclose(boxes.size_lwh, [[4.0, 1.8, 1.5]])
    np.testing.assert_allclose(np.degrees(boxes.yaw()), [-30.0], atol=1e-12)
    np.testing.assert_allclose(boxes.quat_wxyz, [[np.cos(np.radians(-15)), 0, 0, np.sin(np.radians(-15))]], atol=1e-12)
    np.testing.assert_allclose(boxes.velocity, [[np.cos(np.radians(30)), -np.sin(np.radians(30)), 0.0]], atol=1e-12)
    # Its front-left corner (+l/2, +w/2 with y left) is the CARLA front-right corner mirrored.
    front_left = boxes.corners()[0, 3]
    yaw = np.radians(-30.0)
    expected = [10 + 2 * np.cos(yaw) - 0.9 * np.sin(yaw), -5 + 2 * np.sin(yaw) + 0.9 * np.cos(yaw), -0.25]
    np.testing.assert_allclose(front_left, expected)


def test_carla_tilted_box_mirrors_the_solid_and_keeps_a_proper_frame() -> None:
    rotation_deg = np.array([[5.0, 10.0, 30.0]])
    boxes = boxes_from_carla([[1.0, 2.0, 3.0]], [[2.0, 1.0, 0.5]], rotation_deg, "world")
    roll, pitch, yaw = np.radians(rotation_deg[0])
    forward_lh = np.array([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)])
    np.testing.assert_allclose(boxes.rotation_matrix()[0, :, 0], forward_lh * [1, -1, 1], atol=1e-12)
    assert np.linalg.det(boxes.rotation_matrix()[0]) == pytest.approx(1.0)
    corners_lh = (carla_rotation_matrix(rotation_deg)[0] @ (np.array(
        [[sx * 2.0, sy * 1.0, sz * 0.5] for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)]).T)).T + [1.0, 2.0, 3.0]
    mirrored = RH_T_CARLA.apply(corners_lh)
    ours = boxes.corners()[0]
    distances = np.linalg.norm(mirrored[:, None, :] - ours[None, :, :], axis=2)
    assert distances.min(axis=1).max() < 1e-12
    location, extent, back_deg = boxes_to_carla(boxes)
    np.testing.assert_allclose(location, [[1.0, 2.0, 3.0]], atol=1e-12)
    np.testing.assert_allclose(extent, [[2.0, 1.0, 0.5]], atol=1e-12)
    np.testing.assert_allclose(back_deg, rotation_deg, atol=1e-9)


def test_carla_pose_is_the_mirrored_x_to_world() -> None:
    # OpenCOOD's pose order is [x, y, z, roll, yaw, pitch]; yaw +90 deg turns CARLA's x onto its y (right).
    pose = np.array([1.0, 2.0, 3.0, 0.0, 90.0, 0.0])
    np.testing.assert_allclose(carla_pose_matrix(pose)[:3, :3] @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)
    world_T_x = world_T_carla_pose(pose)
    # In right-handed axes the same pose stands at (1, -2, 3) and looks along -y (a right turn).
    np.testing.assert_allclose(world_T_x.apply(np.zeros((1, 3))), [[1.0, -2.0, 3.0]], atol=1e-12)
    np.testing.assert_allclose(world_T_x.apply(np.array([[1.0, 0.0, 0.0]])), [[1.0, -3.0, 3.0]], atol=1e-12)
    assert np.linalg.det(world_T_x.as_matrix()[:3, :3]) == pytest.approx(1.0)
