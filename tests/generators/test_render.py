"""Ray-cast cameras against analytic scenes: which pixels show an object, what colour they are, what is culled."""

from __future__ import annotations

import cv2
import numpy as np

from avdata.frames import XFWD_T_OPTICAL, Transform
from avdata.generators.camera import CameraConfig
from avdata.generators.mesh import box_corners
from avdata.generators.raycast import AMBIENT, SKY_RGB, SUN_DIRECTION
from avdata.generators.render import _pixels_near_objects, encode_png, pixel_rays, render_camera
from avdata.generators.world import SURFACE_COLOR, SimWorld
from tests.generators.scenes import scenery

CAMERA = CameraConfig(width=320, height=160, horizontal_fov_deg=90.0, far_m=60.0)
WORLD_T_CAMERA = Transform.from_yaw(np.float64(0.1), translation=np.array([0.0, 0.0, 1.5])) @ XFWD_T_OPTICAL


def _render(centers, sizes, yaws, classes, static=(), camera=CAMERA, world_T_camera=WORLD_T_CAMERA):
    n = len(centers)
    world = SimWorld(scenery(list(static)), np.arange(n) + 3, np.asarray(classes), np.asarray(sizes, dtype=np.float64))
    try:
        world.set_object_poses(np.asarray(centers, dtype=np.float64), np.asarray(yaws, dtype=np.float64))
        center, rotation = world.object_poses()
        raycast = world.raycast_world()
        image = render_camera(raycast, world_T_camera, camera, box_corners(center, world.size_lwh, rotation))
        return image, raycast, center, rotation
    finally:
        world.close()


def _meets_box(rays: np.ndarray, center: np.ndarray, rotation: np.ndarray, half_size: np.ndarray) -> np.ndarray:
    """(R,) bool: rays (R, 6) that meet a box, by the slab test in float64 (independent of Embree)."""
    origin = (rays[:, :3].astype(np.float64) - center) @ rotation
    direction = rays[:, 3:].astype(np.float64) @ rotation
    with np.errstate(divide="ignore", invalid="ignore"):
        t_a = (-half_size - origin) / direction
        t_b = (half_size - origin) / direction
    t_enter = np.nanmax(np.minimum(t_a, t_b), axis=1)
    t_exit = np.nanmin(np.maximum(t_a, t_b), axis=1)
    return (t_enter <= t_exit) & (t_exit >= 0.0)


def test_pixel_rays_pass_through_the_pixel_centres():
    rays = pixel_rays(CAMERA, WORLD_T_CAMERA)
    assert rays.shape == (CAMERA.width * CAMERA.height, 6) and rays.dtype == np.float32
    np.testing.assert_allclose(rays[:, :3], np.broadcast_to(WORLD_T_CAMERA.translation, (len(rays), 3)), atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(rays[:, 3:], axis=1), 1.0, atol=1e-6)
    # Back in the optical frame, each direction projects onto its own pixel's centre.
    uv, in_front = CAMERA.project(WORLD_T_CAMERA.inverse().apply_vector(rays[:, 3:].astype(np.float64)))
    rows, cols = np.divmod(np.arange(len(rays)), CAMERA.width)
    assert in_front.all()
    np.testing.assert_allclose(uv, np.c_[cols + 0.5, rows + 0.5], atol=1e-3)


def test_an_object_covers_exactly_the_pixels_whose_rays_meet_its_box():
    centers, sizes, yaws = [[12.0, 1.5, 0.9]], [[4.2, 1.8, 1.8]], [0.5]
    image, _, center, rotation = _render(centers, sizes, yaws, ["car"])
    rays = pixel_rays(CAMERA, WORLD_T_CAMERA)
    half = np.asarray(sizes[0]) / 2
    surely_in = _meets_box(rays, center[0], rotation[0], half - 1e-3)
    maybe_in = _meets_box(rays, center[0], rotation[0], half + 1e-3)
    mask = image.object_id.ravel() == 3
    assert surely_in.sum() > 1000  # a real object, not a few pixels
    assert (mask[surely_in]).all() and not mask[~maybe_in].any()
    assert set(np.unique(image.object_id).tolist()) == {-1, 3}


def test_colours_are_the_flat_shade_of_the_surface_hit_and_sky_beyond_far():
    # A van ahead, its top seen from above; a car beyond the 60 m range; the ground below.
    centers, sizes, yaws = [[8.0, 0.0, 0.6], [80.0, 0.0, 0.75]], [[4.0, 2.0, 1.2], [4.0, 1.8, 1.5]], [0.0, 0.0]
    looking_down = Transform.from_euler("ZYX", np.array([0.0, 25.0, 0.0]), translation=np.array([0.0, 0.0, 4.0]),
                                        degrees=True) @ XFWD_T_OPTICAL
    image, _, _, _ = _render(centers, sizes, yaws, ["van", "car"], world_T_camera=looking_down)
    rgb = image.rgb.reshape(-1, 3)
    ids = image.object_id.ravel()
    assert not (ids == 4).any()  # beyond far_m
    rays = pixel_rays(CAMERA, looking_down).astype(np.float64)

    def shade(color, normal):
        light = AMBIENT + (1 - AMBIENT) * max(float(np.dot(normal, SUN_DIRECTION)), 0.0)
        return np.rint(np.asarray(color) * light * 255.0)

    # Which face each van pixel shows: the face its ray enters through (slab test), here top (+z) or rear (-x).
    van = ids == 3
    origin, direction = rays[van, :3] - [8.0, 0.0, 0.6], rays[van, 3:]
    t_top = (0.6 - origin[:, 2]) / direction[:, 2]
    t_rear = (-2.0 - origin[:, 0]) / direction[:, 0]
    top = t_top > t_rear
    assert top.sum() > 100 and (~top).sum() > 100
    np.testing.assert_array_equal(rgb[van][top], np.broadcast_to(shade(SURFACE_COLOR["van"], [0, 0, 1]), (top.sum(), 3)))
    np.testing.assert_array_equal(rgb[van][~top],
                                  np.broadcast_to(shade(SURFACE_COLOR["van"], [-1, 0, 0]), ((~top).sum(), 3)))
    # Ground pixels (rays down to z = 0 within range) are the ground's shade; rays that stay up are sky.
    t_ground = -rays[:, 2] / rays[:, 5]
    ground = (ids == -1) & (rays[:, 5] < 0) & (t_ground < CAMERA.far_m - 0.5)
    sky = (rays[:, 5] > 0) & (ids == -1)
    assert ground.sum() > 1000 and sky.sum() > 1000
    np.testing.assert_array_equal(rgb[ground], np.broadcast_to(shade(SURFACE_COLOR["ground"], [0, 0, 1]),
                                                               (ground.sum(), 3)))
    np.testing.assert_array_equal(rgb[sky], np.broadcast_to(SKY_RGB, (sky.sum(), 3)))


def test_an_object_behind_a_wall_has_no_pixels_and_the_wall_hides_it():
    centers, sizes, yaws = [[20.0, 0.0, 0.9], [9.0, -6.0, 0.9]], [[4.0, 1.8, 1.8], [4.0, 1.8, 1.8]], [0.0, 0.3]
    wall = ([12.0, 0.0, 3.0], [0.5, 12.0, 6.0])  # wide and tall enough to hide the first car entirely
    image, _, _, _ = _render(centers, sizes, yaws, ["car", "car"], static=[wall])
    assert not (image.object_id == 3).any()
    assert (image.object_id == 4).sum() > 500


def test_the_object_cull_changes_no_pixel():
    # Boxes ahead, behind, beside, one across the camera plane (the cull keeps every pixel) and, without it, a
    # union of rectangles: either way each pixel's answer equals casting every pixel's ray at the objects.
    centers = [[10.0, 1.0, 0.9], [-8.0, 0.0, 0.9], [3.0, 9.0, 0.9], [30.0, -6.0, 1.6], [0.5, -1.5, 1.0]]
    sizes = [[4.0, 1.8, 1.8], [4.0, 1.8, 1.8], [0.8, 0.7, 1.8], [10.0, 2.6, 3.2], [4.0, 1.8, 2.0]]
    yaws = [0.3, 0.0, 1.0, -0.4, 0.1]
    classes = ["car", "car", "pedestrian", "bus", "van"]
    rays = pixel_rays(CAMERA, WORLD_T_CAMERA)
    for n in (4, 5):
        image, raycast, center, rotation = _render(centers[:n], sizes[:n], yaws[:n], classes[:n])
        culled = _pixels_near_objects(CAMERA, WORLD_T_CAMERA.inverse(), box_corners(center, np.asarray(sizes[:n]),
                                                                                    rotation))
        assert culled.all() == (n == 5)
        rgba, object_id = raycast.shade(rays, CAMERA.far_m, np.ones(len(rays), dtype=bool))
        np.testing.assert_array_equal(image.object_id.ravel(), object_id)
        np.testing.assert_array_equal(image.rgb.reshape(-1, 3), rgba.view(np.uint8).reshape(-1, 4)[:, :3])
        assert {3, 6} <= set(object_id.tolist()) and 4 not in object_id  # ahead and the bus seen; behind not
        assert (n == 5) == (7 in object_id)


def test_the_png_holds_the_rendered_colours():
    image, _, _, _ = _render([[12.0, 1.5, 0.9]], [[4.2, 1.8, 1.8]], [0.5], ["car"])
    decoded = cv2.imdecode(np.frombuffer(encode_png(image.rgba), np.uint8), cv2.IMREAD_UNCHANGED)
    assert decoded.shape == (CAMERA.height, CAMERA.width, 3)  # no alpha channel
    np.testing.assert_array_equal(decoded[..., ::-1], image.rgb)  # OpenCV decodes to BGR
    assert len(np.unique(image.rgb.reshape(-1, 3), axis=0)) > 3  # sky, ground and the car's faces
