"""Visibility labels against analytic scenes: hidden, half hidden, out of view, camera boxes."""

from __future__ import annotations

import numpy as np
import pytest

from avdata.frames import XFWD_T_OPTICAL, Transform
from avdata.generators.camera import CameraConfig
from avdata.generators.lidar import LidarConfig
from avdata.generators.mesh import box_corners
from avdata.generators.render import render_camera
from avdata.generators.visibility import (
    box_surface,
    camera_in_view,
    camera_labels,
    lidar_in_view,
    occlusion_level,
    sample_visibility,
)
from avdata.generators.world import SimWorld
from tests.generators.scenes import scenery

ORIGIN = Transform.from_yaw(np.float64(0.0), translation=np.array([0.0, 0.0, 1.0]))


def _visibility(centers, sizes, yaws=None, sensor=ORIGIN, lidar=None, static=()):
    n = len(centers)
    ids = np.arange(n) + 10
    classes = np.full(n, "car")
    world = SimWorld(scenery(list(static)), ids, classes, np.asarray(sizes, dtype=np.float64))
    try:
        world.set_object_poses(np.asarray(centers, dtype=np.float64), np.zeros(n) if yaws is None else np.asarray(yaws))
        center, rotation = world.object_poses()
        lidar = lidar or LidarConfig(model="hdl64e", horizontal_fov_deg=180.0, max_range_m=50.0)
        return sample_visibility(world.raycast_world(), sensor, ids, box_surface(center, world.size_lwh, rotation),
                                 lidar_in_view(lidar))
    finally:
        world.close()


def test_box_hidden_behind_a_larger_box_is_fully_occluded():
    # Small box at 12 m straight ahead, a 4 m cube at 6 m between it and the sensor (both at sensor height).
    vis = _visibility([[12.0, 0.0, 1.0], [6.0, 0.0, 1.0]], [[1.0, 1.0, 1.0], [4.0, 4.0, 4.0]])
    assert vis.in_fov.tolist() == [True, True]
    assert vis.visible_fraction[0] == 0.0
    assert occlusion_level(vis.visible_fraction)[0] == 3
    assert vis.visible_fraction[1] > 0.1


def test_half_hidden_box_has_visible_fraction_one_half():
    # Target face 2 m wide at x = 11.5 seen head-on; a static wall in front covers exactly its y < 0 half,
    # from the ground to well above (the sensor at the same height sees only the target's front face).
    sensor = Transform.from_yaw(np.float64(0.0), translation=np.array([0.0, 0.0, 1.0]))
    wall = ([6.0, -5.0, 2.0], [0.2, 10.0, 4.0])  # spans y in [-10, 0]
    # The wall's shadow edge is the plane through the sensor and the wall edge y = 0: the plane y = 0.
    vis = _visibility([[12.0, 0.0, 1.0]], [[1.0, 2.0, 0.2]], sensor=sensor, static=[wall])
    assert vis.visible_fraction[0] == pytest.approx(0.5, abs=0.02)
    assert occlusion_level(vis.visible_fraction).tolist() == [1]


def test_objects_behind_the_sensor_or_beyond_range_are_not_in_the_field_of_view():
    lidar = LidarConfig(model="hdl64e", horizontal_fov_deg=180.0, max_range_m=30.0)
    vis = _visibility([[10.0, 0.0, 1.0], [-10.0, 0.0, 1.0], [45.0, 0.0, 1.0], [0.0, 12.0, 1.0]],
                      [[2.0, 2.0, 2.0]] * 4, lidar=lidar)
    # Ahead: in view; behind a 180 deg sensor: not; 45 m with a 30 m range: not; to the side: the
    # half facing forward of the 180 deg fan.
    assert vis.in_fov.tolist() == [True, False, False, True]
    assert vis.visible_fraction[1] == 0.0 and vis.visible_fraction[2] == 0.0
    assert occlusion_level(vis.visible_fraction)[1:3].tolist() == [3, 3]
    assert 0.3 < vis.visible_fraction[3] < 0.7


def test_projected_2d_boxes_agree_with_the_segmentation_mask():
    camera = CameraConfig(width=640, height=360, horizontal_fov_deg=90.0)
    world_T_camera = Transform.from_yaw(np.float64(0.2), translation=np.array([0.0, 0.0, 1.6])) @ XFWD_T_OPTICAL
    centers = np.array([[10.0, 1.0, 0.75], [14.0, 5.0, 0.9], [25.0, -4.0, 1.6], [16.0, 2.5, 0.75]])
    sizes = np.array([[4.0, 1.8, 1.5], [0.8, 0.7, 1.8], [10.0, 2.6, 3.2], [4.0, 1.8, 1.5]])
    yaws = np.array([0.4, 0.0, -0.3, 1.2])
    ids = np.array([3, 4, 5, 6])
    world = SimWorld(scenery([]), ids, np.array(["car", "pedestrian", "truck", "car"]), sizes)
    try:
        world.set_object_poses(centers, yaws)
        center, rotation = world.object_poses()
        raycast = world.raycast_world()
        image = render_camera(raycast, world_T_camera, camera, box_corners(center, sizes, rotation))
        vis = sample_visibility(raycast, world_T_camera, ids, box_surface(center, sizes, rotation),
                                camera_in_view(camera))
        labels = camera_labels(camera, world_T_camera.inverse(), vis, ids, image.object_id)
    finally:
        world.close()
    checked = 0
    for k, object_id in enumerate(ids):
        rows, cols = np.nonzero(image.object_id == object_id)
        assert len(rows) > 50
        mask_box = np.array([cols.min(), rows.min(), cols.max() + 1, rows.max() + 1], dtype=np.float64)
        if labels.truncation[k] == 0.0 and occlusion_level(vis.visible_fraction)[k] == 0:
            np.testing.assert_allclose(labels.box2d_xyxy[k], mask_box, atol=2.0)
            assert labels.visible_pixel_fraction[k] == pytest.approx(1.0, abs=0.05)
            checked += 1
        else:
            # Partly hidden: the visible part's box lies within the full box and covers the mask.
            assert np.all(labels.box2d_xyxy[k, :2] <= mask_box[:2] + 2.0)
            assert np.all(labels.box2d_xyxy[k, 2:] >= mask_box[2:] - 2.0)
    assert checked >= 2


def test_camera_field_of_view_excludes_objects_behind_beyond_far_and_outside_the_image():
    camera = CameraConfig(width=400, height=200, horizontal_fov_deg=60.0, far_m=40.0)
    world_T_camera = Transform.from_yaw(np.float64(0.0), translation=np.array([0.0, 0.0, 1.5])) @ XFWD_T_OPTICAL
    centers = np.array([[10.0, 0.0, 0.75], [-10.0, 0.0, 0.75], [60.0, 0.0, 0.75], [3.0, 10.0, 0.75],
                        [10.0, 6.0, 0.75]])
    sizes = np.tile([[2.0, 2.0, 1.5]], (5, 1))
    ids = np.arange(5) + 1
    world = SimWorld(scenery([]), ids, np.full(5, "car"), sizes)
    try:
        world.set_object_poses(centers, np.zeros(5))
        center, rotation = world.object_poses()
        raycast = world.raycast_world()
        image = render_camera(raycast, world_T_camera, camera, box_corners(center, sizes, rotation))
        vis = sample_visibility(raycast, world_T_camera, ids, box_surface(center, sizes, rotation),
                                camera_in_view(camera))
        labels = camera_labels(camera, world_T_camera.inverse(), vis, ids, image.object_id)
    finally:
        world.close()
    # Ahead: in view; behind; beyond far; far to the side (outside the 60 deg image); at the image edge.
    assert vis.in_fov.tolist() == [True, False, False, False, True]
    assert labels.truncation[0] == 0.0 and 0.0 < labels.truncation[4] < 1.0
    assert np.isnan(labels.box2d_xyxy[1]).all() and np.isnan(labels.box2d_xyxy[3]).all()
    # The truncated box (left of the image: +y is left) is clipped at the border, where the mask ends too.
    cols = np.nonzero((image.object_id == 5).any(axis=0))[0]
    assert cols.min() == 0 and labels.box2d_xyxy[4, 0] == 0.0
    assert labels.box2d_xyxy[4, 2] == pytest.approx(cols.max() + 1, abs=2.0)


@pytest.mark.parametrize(("view", "up"), [
    (lidar_in_view(LidarConfig(model="hdl64e", azimuth_steps=64, horizontal_fov_deg=180.0, max_range_m=40.0)), 2),
    (lidar_in_view(LidarConfig(model="vlp16", azimuth_steps=64, min_range_m=3.0, max_range_m=25.0)), 2),
    (camera_in_view(CameraConfig(width=400, height=150, horizontal_fov_deg=70.0, far_m=30.0)), 1),
], ids=["lidar-180deg", "lidar-360deg-min-range", "camera"])
def test_sphere_cull_keeps_every_sphere_with_a_point_in_view_and_culls_most_others(view, up):
    rng = np.random.default_rng(3)
    n = 3000
    center = rng.uniform(-45.0, 45.0, (n, 3))
    center[:, up] *= 0.3  # flatter along the vertical axis (z up for a LiDAR, y down for a camera)
    radius = rng.uniform(0.2, 4.0, n)
    # Points on and in each sphere, many near its surface, where the field of view's edges cut it.
    direction = rng.normal(size=(n, 200, 3))
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    points = center[:, None, :] + direction * (radius[:, None] * rng.uniform(0.6, 1.0, (n, 200)))[..., None]
    seen = view.points(points.reshape(-1, 3)).reshape(n, 200).any(axis=1)
    kept = view.spheres(center, radius)
    assert seen.sum() > 100
    assert not (seen & ~kept).any()
    assert (~kept).sum() > 0.3 * n
