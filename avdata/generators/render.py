"""Camera images by ray casting: one ray per pixel into the same scenes the LiDARs cast into.

Each pixel's ray leaves the optical centre through the pixel's centre ((u + 0.5, v + 0.5), see
:mod:`~avdata.generators.camera`); as with a real camera nothing is clipped near it, and a first hit farther
than ``far_m`` from the camera is sky, the same range the camera's visibility labels use. The colour is the
hit triangle's flat shade under a fixed sun (:func:`~avdata.generators.raycast.shaded_rgb`), and every pixel
carries the object id of its first hit, so the segmentation mask is exact by construction: a pixel shows an
object exactly when its ray's first hit is that object, the same test as the LiDAR's ``object_id`` and the
visibility labels' samples.

Rays whose pixel lies outside every object's projected bounding rectangle skip the objects' scene.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from avdata.errors import AvdataError
from avdata.frames import Transform
from avdata.generators.camera import CameraConfig
from avdata.generators.raycast import RaycastWorld


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraImage:
    """One rendered camera image.

    Attributes:
        rgba: (H, W, 4) uint8 colour image, alpha 255 (the bytes the renderer gathers, one word per pixel).
        object_id: (H, W) int32 object id per pixel, -1 for static scenery and sky.
    """

    rgba: np.ndarray
    object_id: np.ndarray

    @property
    def rgb(self) -> np.ndarray:
        """(H, W, 3) uint8 view of the colour channels."""
        return self.rgba[..., :3]


@functools.lru_cache(maxsize=8)
def _pixel_grid(config: CameraConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(W,) x / z of the pixel columns' centres, (H,) y / z of the rows' and (H, W) float32 1 / |(x, y, 1)|.

    Computed once per camera model (read-only).
    """
    f = config.focal_px
    x = (np.arange(config.width, dtype=np.float64) + 0.5 - config.width / 2) / f
    y = (np.arange(config.height, dtype=np.float64) + 0.5 - config.height / 2) / f
    inverse_length = (1.0 / np.sqrt(x[None, :] ** 2 + y[:, None] ** 2 + 1.0)).astype(np.float32)
    for array in (x, y, inverse_length):
        array.flags.writeable = False
    return x, y, inverse_length


def pixel_rays(config: CameraConfig, world_T_camera: Transform) -> np.ndarray:
    """(H * W, 6) float32 rays through the pixel centres, row-major: the optical centre and unit direction.

    A pixel's direction is ``R (x_u, y_v, 1)`` normalised: a column term plus a row term, so the rotation
    costs (H + W) products, and each world axis is one (H, W) broadcast sum and scaling (whole image rows
    per inner loop; an (H, W, 3) layout would loop over 3 values at a time). OpenCV's ``merge`` interleaves the
    six planes (a fifth of the CPU of six strided numpy copies; the same bytes).
    """
    x, y, inverse_length = _pixel_grid(config)
    rotation = world_T_camera.rotation
    shape = (config.height, config.width)
    planes = [np.full(shape, world_T_camera.translation[axis], dtype=np.float32) for axis in range(3)]
    for axis in range(3):  # the three world axes
        column = (x * rotation[axis, 0]).astype(np.float32)  # (W,)
        row = (y * rotation[axis, 1] + rotation[axis, 2]).astype(np.float32)  # (H,)
        plane = np.add(row[:, None], column[None, :])
        np.multiply(plane, inverse_length, out=plane)
        planes.append(plane)
    rays: np.ndarray = cv2.merge(planes).reshape(-1, 6)
    return rays


def _pixels_near_objects(config: CameraConfig, camera_T_world: Transform, corners_world: np.ndarray) -> np.ndarray:
    """(H * W,) bool, False only for pixels whose ray misses every box (a conservative cull).

    A box wholly in front of the camera projects inside the rectangle of its projected corners (it is convex),
    widened by a pixel against float32 vertices; a box wholly behind it is out of sight; one that crosses the
    camera plane may cover any pixel.

    Args:
        config: the camera.
        camera_T_world: world to optical camera frame.
        corners_world: (N, 8, 3) box corners.
    """
    width, height = config.width, config.height
    corners_camera = camera_T_world.apply(corners_world.reshape(-1, 3)).reshape(-1, 8, 3)
    in_front = corners_camera[..., 2] > 0.0  # every pixel's ray has z > 0 beyond the optical centre
    if (in_front.any(axis=1) & ~in_front.all(axis=1)).any():
        return np.ones(width * height, dtype=bool)
    ahead = corners_camera[in_front.all(axis=1)]
    uv = ahead[..., :2] / ahead[..., 2:] * config.focal_px + [width / 2, height / 2]
    lo = np.floor(uv.min(axis=1)) - 1
    hi = np.ceil(uv.max(axis=1)) + 1
    u0, v0 = np.clip(lo[:, 0], 0, width).astype(np.int64), np.clip(lo[:, 1], 0, height).astype(np.int64)
    u1, v1 = np.clip(hi[:, 0], 0, width).astype(np.int64), np.clip(hi[:, 1], 0, height).astype(np.int64)
    # Each rectangle adds 1 inside itself: +1 / -1 at its corners, then running sums over rows and columns.
    # Counts up to the number of boxes: int16 (half the memory the running sums stream through) unless there
    # could be more than it holds.
    count = np.int16 if len(u0) < np.iinfo(np.int16).max else np.int32
    marks = np.zeros((height + 1, width + 1), dtype=count)
    np.add.at(marks, (v0, u0), 1)
    np.add.at(marks, (v0, u1), -1)
    np.add.at(marks, (v1, u0), -1)
    np.add.at(marks, (v1, u1), 1)
    np.cumsum(marks, axis=1, dtype=count, out=marks)
    np.cumsum(marks, axis=0, dtype=count, out=marks)
    return (marks[:height, :width] > 0).reshape(-1)


def render_camera(raycast: RaycastWorld, world_T_camera: Transform, config: CameraConfig,
                  object_corners_world: np.ndarray) -> CameraImage:
    """Renders a camera by casting one ray per pixel (:func:`pixel_rays`).

    Args:
        raycast: this frame's geometry.
        world_T_camera: pose of the optical camera frame in the world.
        config: the camera.
        object_corners_world: (N, 8, 3) corners of the objects' boxes (to skip the objects for other pixels).

    Returns:
        The image and its object-id mask.
    """
    may_hit = _pixels_near_objects(config, world_T_camera.inverse(), object_corners_world)
    rgba, object_id = raycast.shade(pixel_rays(config, world_T_camera), config.far_m, may_hit)
    shape = (config.height, config.width)
    return CameraImage(rgba=rgba.view(np.uint8).reshape(*shape, 4), object_id=object_id.reshape(shape))


def encode_png(rgba: np.ndarray) -> bytes:
    """PNG bytes (RGB, no alpha) of an (H, W, 4) uint8 RGBA image (OpenCV, which releases the GIL while it encodes).

    OpenCV's default settings: a simulated frame is written at every step, so encoding time counts more than
    file size; the settings that write smaller files (``IMWRITE_PNG_COMPRESSION`` 1, the RLE strategy) spend
    more CPU per frame (figures in docs/performance.md). The colour conversion reads the contiguous RGBA words
    (from an (H, W, 3) view of them, OpenCV would copy the image first, ten times the CPU).
    """
    ok, png = cv2.imencode(".png", cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGR))
    if not ok:
        raise AvdataError(f"expected OpenCV to PNG-encode a {rgba.shape[1]}x{rgba.shape[0]} image, got a failure")
    return png.tobytes()
