"""Waymo range-image formulas (avdata.sources.waymo.lidar) as identities; Waymo's own values are in
tests/converters/test_waymo.py (points equal ``convert_range_image_to_point_cloud``)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from avdata.errors import InputError
from avdata.sources.waymo import beam_inclinations, range_image_points, range_image_points_lidar, rotation_from_roll_pitch_yaw


def test_rotation_is_zyx_euler() -> None:
    rpy = np.random.default_rng(0).uniform(-np.pi, np.pi, (100, 3))
    expected = Rotation.from_euler("ZYX", rpy[:, ::-1]).as_matrix()
    np.testing.assert_allclose(rotation_from_roll_pitch_yaw(rpy), expected, atol=1e-12)


def test_uniform_inclinations_are_pixel_centres_top_row_first() -> None:
    inclination = beam_inclinations(4, -0.4, 0.4, None)
    np.testing.assert_allclose(inclination, [0.3, 0.1, -0.1, -0.3], atol=1e-15)
    np.testing.assert_allclose(beam_inclinations(3, 0.0, 0.0, np.array([-0.2, 0.0, 0.1])), [0.1, 0.0, -0.2])
    with pytest.raises(InputError, match="expected 3 values"):
        beam_inclinations(3, 0.0, 0.0, np.array([0.1, 0.2]))


def test_columns_sweep_clockwise_from_behind() -> None:
    # Column 0 looks backwards (azimuth ~ +pi), the middle column forwards, column W/4 to the left (+y).
    width = 8
    image = np.zeros((1, width, 3), dtype=np.float32)
    image[0, :, 0] = 10.0
    points, pixels = range_image_points_lidar(image, np.eye(4), np.zeros(1))
    azimuth = np.arctan2(points[:, 1], points[:, 0])
    np.testing.assert_allclose(azimuth, (((width - np.arange(width) - 0.5) / width) * 2 - 1) * np.pi, atol=1e-12)
    assert np.all(np.diff(azimuth) < 0) and pixels[:, 1].tolist() == list(range(width))
    np.testing.assert_allclose(np.linalg.norm(points, axis=1), 10.0, atol=1e-12)


def test_extrinsic_yaw_keeps_columns_fixed_in_the_vehicle_frame() -> None:
    # A lidar turned by 90 degrees: Waymo's azimuth correction makes column j look the same way in the vehicle.
    image = np.zeros((2, 6, 3), dtype=np.float32)
    image[..., 0] = 5.0
    turned = np.eye(4)
    turned[:3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    turned[:3, 3] = [1.0, 0.0, 2.0]
    inclination = np.array([0.1, -0.1])
    straight, _ = range_image_points(image, np.eye(4), inclination)
    rotated, _ = range_image_points(image, turned, inclination)
    np.testing.assert_allclose(rotated - [1.0, 0.0, 2.0], straight, atol=1e-12)


def test_pixel_pose_equal_to_frame_pose_changes_nothing() -> None:
    image = np.random.default_rng(1).uniform(0, 50, (3, 10, 3)).astype(np.float32)
    image[0, :4, 0] = 0.0
    world_T_vehicle = np.eye(4)
    world_T_vehicle[:3, :3] = rotation_from_roll_pitch_yaw(np.array([0.01, -0.02, 1.3]))
    world_T_vehicle[:3, 3] = [1000.0, -2000.0, 30.0]
    pixel_pose = np.broadcast_to(np.array([0.01, -0.02, 1.3, 1000.0, -2000.0, 30.0]), (3, 10, 6))
    inclination = np.array([0.05, 0.0, -0.05])
    plain, pixels = range_image_points(image, np.eye(4), inclination)
    posed, _ = range_image_points(image, np.eye(4), inclination, pixel_pose, world_T_vehicle)
    assert len(plain) == 26 and pixels[0].tolist() == [0, 4]
    np.testing.assert_allclose(posed, plain, atol=1e-9)
