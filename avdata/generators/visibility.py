"""Per-sensor visibility labels, from the sensor's own viewpoint.

For every object, a k x k grid of samples (cell centres) covers each face of its box that faces the
sensor. A ray is cast from the sensor to every sample; the sample is visible when the ray's first hit
is the object itself and the sample lies in the sensor's field of view and range. Each sample stands
for its cell's area projected towards the sensor (face area x cos(view angle) / k^2), so the visible
fraction is the fraction of the object's apparent (sensor-facing) surface the sensor sees.

Occlusion level from the visible fraction ``f`` (thresholds in :data:`OCCLUSION_THRESHOLDS`):
0 fully visible (f >= 0.8), 1 partly (0.4 <= f < 0.8), 2 largely (0.05 <= f < 0.4),
3 fully occluded or out of view (f < 0.05).

Cameras add truncation (fraction of the apparent surface outside the image or behind the camera),
the 2D box of the visible part (extent of the projected corners of visible cells, clipped to the image;
exact for an unoccluded box, since the silhouette of a box is the union of its facing faces), and the
visible pixel fraction (the object's pixels in the segmentation mask over the area of its projected
silhouette inside the image, i.e. silhouette area x (1 - truncation); NaN for an object that crosses
the camera plane, whose silhouette is unbounded).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from avdata import portable_math
from avdata.frames import Transform
from avdata.generators.camera import CameraConfig
from avdata.generators.lidar import LidarConfig
from avdata.generators.raycast import RaycastWorld

OCCLUSION_THRESHOLDS = (0.8, 0.4, 0.05)
"""Visible-fraction lower bounds of occlusion levels 0, 1 and 2; below the last is level 3."""

# Faces of the unit box: outward normal axis and sign, and the two in-face axes.
_FACE_AXIS = np.array([0, 0, 1, 1, 2, 2])
_FACE_SIGN = np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0])
_FACE_U = np.array([1, 1, 0, 0, 0, 0])
_FACE_V = np.array([2, 2, 2, 2, 1, 1])


@dataclass(frozen=True, slots=True, kw_only=True)
class BoxSurface:
    """Samples on all six faces of N boxes, computed once per frame and shared by every sensor.

    Attributes:
        points_world: (N, 6, k*k, 3) sample points (cell centres).
        face_corners_world: (N, 6, 4, 3) corners of each face.
        face_center_world: (N, 6, 3) face centres.
        normal_world: (N, 6, 3) outward face normals.
        area_per_sample: (N, 6) face area / k^2.
        center_world: (N, 3) box centres.
        radius_m: (N,) radius of a sphere around each box (half its diagonal, plus 1 cm).
        size_lwh: (N, 3) box sizes.
        rotation_world: (N, 3, 3) box-to-world rotations.
        grid: samples per face side (k).
    """

    points_world: np.ndarray
    face_corners_world: np.ndarray
    face_center_world: np.ndarray
    normal_world: np.ndarray
    area_per_sample: np.ndarray
    center_world: np.ndarray
    radius_m: np.ndarray
    size_lwh: np.ndarray
    rotation_world: np.ndarray
    grid: int

    def cell_corners_world(self, cells: np.ndarray) -> np.ndarray:
        """(K, 4, 3) corners of the K cells where the (N, 6, k*k) bool ``cells`` is True, in its C order.

        Computed for the cells asked for only (the visible ones: a small share of all).
        """
        box, face, cell = np.nonzero(cells)
        _, corners, _ = _unit_face_grid(self.grid)
        scaled = corners[face, cell] * self.size_lwh[box][:, None, :]
        corners_world: np.ndarray = (np.matmul(scaled, np.swapaxes(self.rotation_world[box], 1, 2))
                                     + self.center_world[box][:, None, :])
        return corners_world

    def facing_weight(self, origin_world: np.ndarray) -> np.ndarray:
        """(N, 6) projected area per sample of each face seen from ``origin_world``; 0 if turned away."""
        to_sensor = origin_world - self.face_center_world
        distance = np.linalg.norm(to_sensor, axis=-1)
        cos_view = np.einsum("nfi,nfi->nf", self.normal_world, to_sensor) / np.maximum(distance, 1e-9)
        return np.where(cos_view > 1e-6, self.area_per_sample * cos_view, 0.0)


def occlusion_level(visible_fraction: np.ndarray) -> np.ndarray:
    """(N,) int32 occlusion levels 0..3 from visible fractions (NaN gives 3)."""
    f = np.nan_to_num(np.asarray(visible_fraction, dtype=np.float64), nan=0.0)
    t0, t1, t2 = OCCLUSION_THRESHOLDS
    return np.select([f >= t0, f >= t1, f >= t2], [0, 1, 2], default=3).astype(np.int32)


@functools.lru_cache(maxsize=4)
def _unit_face_grid(grid: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cell centres (6, k*k, 3), cell corners (6, k*k, 4, 3) and face corners (6, 4, 3) of the unit box.

    Computed once per grid size (read-only).
    """
    cell = (np.arange(grid) + 0.5) / grid - 0.5
    edges = np.arange(grid + 1) / grid - 0.5
    grid_u, grid_v = np.meshgrid(np.arange(grid), np.arange(grid), indexing="ij")
    iu, iv = grid_u.ravel(), grid_v.ravel()
    local = np.zeros((6, grid * grid, 3))
    corners = np.zeros((6, grid * grid, 4, 3))
    face_corners = np.zeros((6, 4, 3))
    for f in range(6):  # six faces: a fixed, tiny loop
        local[f, :, _FACE_AXIS[f]] = 0.5 * _FACE_SIGN[f]
        local[f, :, _FACE_U[f]] = cell[iu]
        local[f, :, _FACE_V[f]] = cell[iv]
        for c, (du, dv) in enumerate(((0, 0), (1, 0), (1, 1), (0, 1))):
            corners[f, :, c, _FACE_AXIS[f]] = 0.5 * _FACE_SIGN[f]
            corners[f, :, c, _FACE_U[f]] = edges[iu + du]
            corners[f, :, c, _FACE_V[f]] = edges[iv + dv]
            face_corners[f, c, _FACE_AXIS[f]] = 0.5 * _FACE_SIGN[f]
            face_corners[f, c, _FACE_U[f]] = -0.5 + du
            face_corners[f, c, _FACE_V[f]] = -0.5 + dv
    for array in (local, corners, face_corners):
        array.flags.writeable = False
    return local, corners, face_corners


def box_surface(center: np.ndarray, size_lwh: np.ndarray, rotation: np.ndarray, grid: int = 8) -> BoxSurface:
    """Samples the six faces of every box.

    Args:
        center: (N, 3) box centres in the world frame.
        size_lwh: (N, 3) box sizes.
        rotation: (N, 3, 3) box-to-world rotations.
        grid: samples per face side.
    """
    n = len(center)
    local, _, face_corners = _unit_face_grid(grid)
    rotation_t = np.swapaxes(rotation, 1, 2)

    def to_world(points: np.ndarray) -> np.ndarray:
        scaled = points.reshape(1, -1, 3) * size_lwh[:, None, :]
        world: np.ndarray = (np.matmul(scaled, rotation_t) + center[:, None, :]).reshape((n,) + points.shape)
        return world

    normals_local = np.zeros((6, 3))
    normals_local[np.arange(6), _FACE_AXIS] = _FACE_SIGN
    normals = np.matmul(normals_local[None], rotation_t)  # (N, 6, 3)
    face_center = center[:, None, :] + normals * (size_lwh[:, _FACE_AXIS] / 2)[..., None]
    area = size_lwh[:, _FACE_U] * size_lwh[:, _FACE_V] / (grid * grid)
    return BoxSurface(points_world=to_world(local), face_corners_world=to_world(face_corners),
                      face_center_world=face_center, normal_world=normals, area_per_sample=area, center_world=center,
                      radius_m=0.5 * np.linalg.norm(size_lwh, axis=-1) + 0.01, size_lwh=size_lwh,
                      rotation_world=rotation, grid=grid)


@dataclass(frozen=True, slots=True, kw_only=True)
class FieldOfView:
    """A sensor's field of view and range, as two tests in the sensor frame.

    Attributes:
        points: maps (M, 3) points to (M,) bool, True inside.
        spheres: maps (N, 3) sphere centres and (N,) radii to (N,) bool, False only for a sphere with no
            point inside (a conservative cull: objects wholly outside skip their samples).
    """

    points: Callable[[np.ndarray], np.ndarray]
    spheres: Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True, slots=True, kw_only=True)
class SampleVisibility:
    """Visibility of every surface sample of N objects from one sensor.

    Attributes:
        surface: the samples.
        weight: (N, 6) projected area per sample of each face; 0 for faces turned away.
        visible: (N, 6, k*k) first hit is the object and the sample is in view (facing faces only).
        in_fov: (N,) any facing sample in the field of view and range.
        visible_fraction: (N,) weighted fraction of visible facing samples.
    """

    surface: BoxSurface
    weight: np.ndarray
    visible: np.ndarray
    in_fov: np.ndarray
    visible_fraction: np.ndarray


def sample_visibility(world: RaycastWorld, world_T_sensor: Transform, object_ids: np.ndarray, surface: BoxSurface,
                      in_view: FieldOfView) -> SampleVisibility:
    """Casts rays from a sensor to the facing surface samples of every object.

    Args:
        world: this frame's ray-casting scene.
        world_T_sensor: the sensor's pose.
        object_ids: (N,) object ids.
        surface: the objects' surface samples (see :func:`box_surface`).
        in_view: the sensor's field of view and range.
    """
    origin = world_T_sensor.translation
    sensor_T_world = world_T_sensor.inverse()
    weight = surface.facing_weight(origin)
    n = len(weight)
    facing = np.broadcast_to((weight > 0)[..., None], surface.points_world.shape[:-1])
    # Samples of objects wholly outside the field of view are out of view without testing each one.
    facing_in_reach = facing & in_view.spheres(sensor_T_world.apply(surface.center_world), surface.radius_m)[:, None, None]
    targets = surface.points_world[facing_in_reach]
    view = in_view.points(sensor_T_world.apply(targets))
    # Only samples in view can be visible: cast rays to those alone.
    offsets = targets[view] - origin
    distance = np.linalg.norm(offsets, axis=-1)
    owner = np.broadcast_to(np.asarray(object_ids)[:, None, None], facing.shape)[facing_in_reach][view]
    seen = view.copy()
    seen[view] = world.sees(origin, offsets / np.maximum(distance, 1e-9)[:, None], owner, distance + 0.05)
    visible = np.zeros(facing.shape, dtype=bool)
    visible[facing_in_reach] = seen
    viewed = np.zeros(facing.shape, dtype=bool)
    viewed[facing_in_reach] = view
    sample_weight = np.broadcast_to(weight[..., None], facing.shape)
    total = sample_weight.reshape(n, -1).sum(axis=1)
    fraction = (sample_weight * visible).reshape(n, -1).sum(axis=1) / np.maximum(total, 1e-12)
    return SampleVisibility(surface=surface, weight=weight, visible=visible,
                            in_fov=np.asarray(viewed.reshape(n, -1).any(axis=1)), visible_fraction=fraction)


_CULL_MARGIN_RAD = 1e-4
"""Angular margin of the sphere culls, far above the float error of their trigonometry."""


def lidar_in_view(config: LidarConfig) -> FieldOfView:
    """The field-of-view test of a LiDAR: azimuth, elevation between the outer beams, range.

    A sphere of angular radius ``a`` around its centre's direction spans elevations within ``a`` of the
    centre's and azimuths within ``asin(sin(a) / cos(elevation))`` (any, if it reaches a pole); it is
    culled when those ranges or its distance miss the field of view and range.
    """
    elevation = config.elevations_rad
    half_fov = np.deg2rad(config.horizontal_fov_deg) / 2
    # The points' test without inverse trigonometry (many points per frame): azimuth and elevation are monotone in
    # the cosine of the angle to the x axis and in z / r, so their bounds are compared as cos(half_fov) and
    # sin(elevation); numpy's sin and cos give the same bits on every CPU (docs/determinism.md).
    cos_half_fov = np.cos(half_fov) if half_fov < np.pi else -np.inf
    sin_low, sin_high = np.sin(elevation.min()), np.sin(elevation.max())

    def points(points_sensor: np.ndarray) -> np.ndarray:
        x, y, z = points_sensor[:, 0], points_sensor[:, 1], points_sensor[:, 2]
        r = np.linalg.norm(points_sensor, axis=-1)
        sin_el = z / np.maximum(r, 1e-9)
        inside: np.ndarray = ((x >= cos_half_fov * np.sqrt(x * x + y * y)) & (sin_el >= sin_low) & (sin_el <= sin_high)
                              & (r >= config.min_range_m) & (r <= config.max_range_m))
        return inside

    def spheres(center_sensor: np.ndarray, radius_m: np.ndarray) -> np.ndarray:
        distance = np.linalg.norm(center_sensor, axis=-1)
        inside = distance <= radius_m
        half_angle = portable_math.arcsin(np.clip(radius_m / np.maximum(distance, 1e-9), 0.0, 1.0)) + _CULL_MARGIN_RAD
        el = portable_math.arcsin(np.clip(center_sensor[:, 2] / np.maximum(distance, 1e-9), -1.0, 1.0))
        azimuth = portable_math.arctan2(center_sensor[:, 1], center_sensor[:, 0])
        sin_ratio = np.sin(np.minimum(half_angle, np.pi / 2)) / np.maximum(np.cos(el), 1e-9)
        half_width = np.where((half_angle < np.pi / 2) & (sin_ratio < 1.0), portable_math.arcsin(np.minimum(sin_ratio, 1.0)),
                              np.pi) + _CULL_MARGIN_RAD
        reached: np.ndarray = inside | (
            (distance - radius_m <= config.max_range_m) & (distance + radius_m >= config.min_range_m)
            & (el - half_angle <= elevation.max()) & (el + half_angle >= elevation.min())
            & (np.abs(azimuth) <= half_fov + half_width))
        return reached

    return FieldOfView(points=points, spheres=spheres)


def camera_in_view(config: CameraConfig) -> FieldOfView:
    """The field-of-view test of a camera: in front, inside the image, within ``far_m``.

    Inside the image means on the inner side of the four planes through the optical centre and the image
    edges; a sphere is culled when it lies wholly behind the near plane, beyond ``far_m`` or on the outer
    side of one edge plane.
    """
    f = config.focal_px
    # Inward unit normals of the planes through the centre and the image's left, right, top and bottom edges.
    edge_normal = np.array([[f, 0.0, config.width / 2], [-f, 0.0, config.width / 2],
                            [0.0, f, config.height / 2], [0.0, -f, config.height / 2]])
    edge_normal /= np.linalg.norm(edge_normal, axis=1, keepdims=True)

    def points(points_camera: np.ndarray) -> np.ndarray:
        uv, in_front = config.project(points_camera)
        inside: np.ndarray = (in_front & (uv[:, 0] >= 0) & (uv[:, 0] <= config.width) & (uv[:, 1] >= 0)
                              & (uv[:, 1] <= config.height) & (np.linalg.norm(points_camera, axis=-1) <= config.far_m))
        return inside

    def spheres(center_camera: np.ndarray, radius_m: np.ndarray) -> np.ndarray:
        margin_m = 1e-6 * (1.0 + np.linalg.norm(center_camera, axis=-1))
        reach = radius_m + margin_m
        edge_distance = center_camera[:, 0:1] * edge_normal[:, 0] + center_camera[:, 2:3] * edge_normal[:, 2] \
            + center_camera[:, 1:2] * edge_normal[:, 1]
        reached: np.ndarray = ((center_camera[:, 2] + reach > config.near_m)
                               & (np.linalg.norm(center_camera, axis=-1) - reach <= config.far_m)
                               & (edge_distance >= -reach[:, None]).all(axis=1))
        return reached

    return FieldOfView(points=points, spheres=spheres)


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraVisibility:
    """Camera-only labels of N objects.

    Attributes:
        truncation: (N,) fraction of the apparent surface outside the image or behind the camera.
        box2d_xyxy: (N, 4) 2D box of the visible part, NaN when nothing is visible.
        visible_pixel_fraction: (N,) mask pixels over the silhouette area inside the image.
    """

    truncation: np.ndarray
    box2d_xyxy: np.ndarray
    visible_pixel_fraction: np.ndarray


def camera_labels(config: CameraConfig, camera_T_world: Transform, vis: SampleVisibility, object_ids: np.ndarray,
                  mask_object_id: np.ndarray) -> CameraVisibility:
    """Truncation, visible 2D box and visible pixel fraction of every object for one camera.

    Args:
        config: the camera.
        camera_T_world: world to optical camera frame.
        vis: the sample visibility computed for this camera.
        object_ids: (N,) object ids, non-negative.
        mask_object_id: (H, W) object id per pixel (-1 none).
    """
    samples = vis.surface
    n = len(object_ids)
    weight = vis.weight
    facing = weight > 0
    # Truncation: weighted share of the facing samples that are not inside the image.
    pts_cam = camera_T_world.apply(samples.points_world)
    uv, in_front = config.project(pts_cam)
    inside = in_front & (uv[..., 0] >= 0) & (uv[..., 0] <= config.width) & (uv[..., 1] >= 0) & (
        uv[..., 1] <= config.height)
    w = np.broadcast_to(weight[..., None], inside.shape)
    total = w.reshape(n, -1).sum(axis=1)
    truncation = 1.0 - (w * inside).reshape(n, -1).sum(axis=1) / np.maximum(total, 1e-12)
    # 2D box of the visible cells' projected corners (only visible cells are projected: a small share).
    owner = np.nonzero(vis.visible)[0]
    corner_uv, corner_front = config.project(camera_T_world.apply(samples.cell_corners_world(vis.visible)))
    usable = corner_front.all(axis=-1)
    owner, corner_uv = owner[usable], corner_uv[usable]
    lo = np.full((n, 2), np.inf)
    hi = np.full((n, 2), -np.inf)
    np.minimum.at(lo, owner, corner_uv.min(axis=1))
    np.maximum.at(hi, owner, corner_uv.max(axis=1))
    any_visible = np.bincount(owner, minlength=n) > 0
    box = np.where(any_visible[:, None], np.concatenate([lo, hi], axis=1), np.nan)
    box[:, [0, 2]] = np.clip(box[:, [0, 2]], 0, config.width)
    box[:, [1, 3]] = np.clip(box[:, [1, 3]], 0, config.height)
    # Silhouette area: sum of projected facing-face areas (shoelace), valid with every corner in front.
    face_cam = camera_T_world.apply(samples.face_corners_world)
    face_uv, face_front = config.project(face_cam)
    x, y = face_uv[..., 0], face_uv[..., 1]
    face_area = 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y, axis=-1))
    silhouette = np.where(facing, face_area, 0.0).sum(axis=1)
    crosses = ~np.where(facing[..., None], face_front, True).all(axis=(1, 2))
    ids = mask_object_id.ravel()
    ids = ids[ids >= 0]  # object pixels only: a small share of the image
    id_index = {int(k): i for i, k in enumerate(object_ids)}
    lookup = np.full(max([*id_index, 0]) + 1, -1, dtype=np.int64)
    lookup[np.array(list(id_index), dtype=np.int64)] = np.arange(n)
    counts = np.bincount(lookup[ids] + 1, minlength=n + 1)[1:]
    inside_area = silhouette * (1.0 - truncation)
    with np.errstate(all="ignore"):
        vpf = np.where(crosses | (inside_area <= 0), np.nan, np.clip(counts / inside_area, 0.0, 1.0))
    return CameraVisibility(truncation=truncation, box2d_xyxy=box, visible_pixel_fraction=vpf)
