"""Ray casting through Open3D's Embree-backed ``RaycastingScene``, with an object id on every hit.

The static town (object id -1) and the objects live in two scenes. Open3D cannot move geometry once
added, so the objects' scene is rebuilt per frame from their boxes at the current poses, while the
static scene (tens of thousands of triangles, the costly bounding-volume hierarchy) is built once per
scene; a fixed sensor's static hits can even be kept for the whole scene. A ray's first hit is the
nearer of its static and its object hit (the static one on an exact tie). Rays that cannot reach any
object (see :meth:`~avdata.generators.lidar.LidarConfig.rays_near`) skip the objects' scene. A hit's
primitive id maps to an object id and reflectivity with one lookup into a per-triangle table.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from avdata.generators._open3d import o3d
from avdata.generators.mesh import TriangleSoup

STATIC_ID = -1
"""Object id of everything that is not an object (ground, buildings, trees, poles)."""

SKY_RGB = (158, 191, 224)
"""RGB of a camera pixel whose ray hits nothing within the camera's range."""

AMBIENT = 0.4
"""Share of a surface's colour lit whatever its orientation; the rest scales with the cosine to the sun."""

SUN_DIRECTION = np.array([0.36, 0.48, 0.8])
"""Unit vector towards the sun in the world frame (high, from one side, so a box's faces differ)."""


def _rgba_word(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) uint8 RGB as (...,) uint32 whose bytes in memory are R, G, B, 255 (one gather per pixel)."""
    rgba = np.concatenate([rgb, np.full(rgb.shape[:-1] + (1,), 255, dtype=np.uint8)], axis=-1)
    return np.ascontiguousarray(rgba).view(np.uint32)[..., 0]


def shaded_rgb(vertices: np.ndarray, triangles: np.ndarray, color: np.ndarray) -> np.ndarray:
    """(T, 3) uint8 RGB of flat-shaded triangles: colour x (AMBIENT + (1 - AMBIENT) max(0, cos to the sun)).

    A triangle's shade depends only on its outward normal (counter-clockwise seen from outside), not on the
    viewer, so it is computed once per triangle instead of once per pixel.

    Args:
        vertices: (V, 3) float32 vertices.
        triangles: (T, 3) vertex indices.
        color: (T, 3) RGB in [0, 1].
    """
    corner = vertices[triangles].astype(np.float64)
    normal = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    cos_sun = normal @ SUN_DIRECTION / np.maximum(np.linalg.norm(normal, axis=1), 1e-12)
    light = AMBIENT + (1.0 - AMBIENT) * np.maximum(cos_sun, 0.0)
    shaded: np.ndarray = np.rint(np.asarray(color, dtype=np.float64) * light[:, None] * 255.0).astype(np.uint8)
    return shaded


@dataclass(frozen=True, slots=True, kw_only=True)
class RayHits:
    """First hits of a batch of rays.

    Attributes:
        range_m: (R,) float32 distance along the (unit) ray, inf for a miss.
        object_id: (R,) object id hit, -1 for static scenery or a miss.
        reflectivity: (R,) reflectivity of the surface hit (0 for a miss).
        cos_incidence: (R,) cosine between the ray and the hit triangle's normal (0 for a miss).
    """

    range_m: np.ndarray
    object_id: np.ndarray
    reflectivity: np.ndarray
    cos_incidence: np.ndarray


@dataclass(frozen=True, slots=True, kw_only=True)
class StaticHits:
    """First hits of a batch of rays in the static scene alone (reusable while rays and town stay put).

    Attributes:
        t_hit: (R,) float32 distance along the ray, inf for a miss.
        reflectivity: (R,) float32 reflectivity of the triangle hit (0 for a miss).
        cos_incidence: (R,) float32 cosine between the ray and the hit triangle's normal (0 for a miss).
    """

    t_hit: np.ndarray
    reflectivity: np.ndarray
    cos_incidence: np.ndarray


def _scene(vertices: np.ndarray, triangles: np.ndarray) -> Any:
    scene = o3d.t.geometry.RaycastingScene(nthreads=0)
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(triangles, dtype=np.uint32)))
    # Open3D builds (commits) a scene's hierarchy on its first query, without a lock: done here with one ray,
    # before threads (a camera's and the LiDARs') cast into the scene. Its casts hold the GIL today, so two cannot
    # overlap, but nothing in its API promises that.
    scene.cast_rays(o3d.core.Tensor(np.array([[0.0, 0.0, 0.0, 0.0, 0.0, 1.0]], dtype=np.float32)))
    return scene


def _cast(scene: Any, rays: np.ndarray, n_triangles: int
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(R,) t_hit, (R,) primitive index (``n_triangles`` for a miss) and (R, 3) normals of (R, 6) float32 rays."""
    # Every core per cast: Open3D holds the GIL while it casts, so the casts of a frame's two sensor threads
    # (``write_frame``) never overlap; only Embree's own threads spread one cast over the cores. Each ray is
    # intersected on its own, so the threads add no work per ray and change no hit.
    result = scene.cast_rays(o3d.core.Tensor.from_numpy(rays), nthreads=0)
    primitive = result["primitive_ids"].numpy().astype(np.int64)
    np.minimum(primitive, n_triangles, out=primitive)  # a miss is INVALID_ID (2^32 - 1)
    return result["t_hit"].numpy(), primitive, result["primitive_normals"].numpy()


_XYZ = np.dtype((np.void, 12))
"""Three float32 as one 12-byte item: rows of (R, 3) arrays copied in one loop over R instead of R loops over 3."""


def ray_array(origins_world: np.ndarray, directions_world: np.ndarray) -> np.ndarray:
    """(R, 6) float32 rays, each its origin and direction, as Open3D casts them.

    Args:
        origins_world: (R, 3) or (3,) ray origins in the world frame.
        directions_world: (R, 3) directions in the world frame.
    """
    rays = np.empty((len(directions_world), 6), dtype=np.float32)
    row = rays.view(_XYZ)  # (R, 2): origin, direction; the same float32 values as assigning to rays[:, :3] / [:, 3:]
    origins = np.ascontiguousarray(origins_world, dtype=np.float32)
    row[:, 0] = origins.view(_XYZ)[0] if origins.ndim == 1 else origins.view(_XYZ)[:, 0]
    row[:, 1] = np.ascontiguousarray(directions_world, dtype=np.float32).view(_XYZ)[:, 0]
    return rays


def rotated_rays(origin_world: np.ndarray, rotation: np.ndarray, directions_columns: np.ndarray) -> np.ndarray:
    """(R, 6) float32 rays from one origin along directions rotated into the world frame.

    The same bits as ``ray_array(origin, Transform.apply_vector(directions))`` for float32 directions (float32
    products summed in the same order), computed on whole columns (a third of the CPU of (R, 3) rows).

    Args:
        origin_world: (3,) ray origin in the world frame.
        rotation: (3, 3) world-from-sensor rotation.
        directions_columns: (3, R) float32 directions in the sensor frame, one contiguous row per axis.
    """
    r = rotation.astype(np.float32)
    x, y, z = directions_columns
    rays = np.empty((len(x), 6), dtype=np.float32)
    rays.view(_XYZ)[:, 0] = np.asarray(origin_world, dtype=np.float32).view(_XYZ)[0]
    for axis in range(3):
        rays[:, 3 + axis] = x * r[axis, 0] + y * r[axis, 1] + z * r[axis, 2]
    return rays


def _cos_incidence(normal: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """(R,) float32 cosine between (R, 3) float32 unit ray directions and the (R, 3) normals they hit."""
    cosine: np.ndarray = -np.einsum("ij,ij->i", normal, directions)
    return cosine


class StaticGeometry:
    """The static town's triangles in a ray-casting scene, built once per scene.

    Args:
        static: the triangles.
        reflectivity: (T,) reflectivity per triangle.
        color: (T, 3) RGB in [0, 1] per triangle (what a camera sees).
    """

    def __init__(self, static: TriangleSoup, reflectivity: np.ndarray, color: np.ndarray):
        self._scene = _scene(static.vertices, static.triangles)
        # One extra entry at the end answers misses.
        self._reflectivity = np.concatenate([np.asarray(reflectivity, dtype=np.float32), [np.float32(0.0)]])
        self._rgba = _rgba_word(np.concatenate([shaded_rgb(static.vertices, static.triangles, color),
                                                np.array([SKY_RGB], dtype=np.uint8)]))

    def distance_m(self, point_world: np.ndarray) -> float:
        """Distance from a (3,) point to the nearest static surface (one closest-point query)."""
        query = o3d.core.Tensor(np.asarray(point_world, dtype=np.float32).reshape(1, 3))
        return float(self._scene.compute_distance(query).numpy()[0])

    def cast(self, rays: np.ndarray) -> StaticHits:
        """Casts rays into the static scene alone.

        Args:
            rays: (R, 6) float32 origins and unit directions in the world frame (:func:`ray_array`).
        """
        t_hit, primitive, normal = _cast(self._scene, rays, len(self._reflectivity) - 1)
        cos_incidence = np.where(np.isfinite(t_hit), _cos_incidence(normal, rays[:, 3:]), np.float32(0.0))
        return StaticHits(t_hit=t_hit, reflectivity=self._reflectivity[primitive], cos_incidence=cos_incidence)


class RaycastWorld:
    """One frame's geometry, ready for casting: the static scene and the objects' boxes.

    Args:
        static: the static town's scene.
        objects: the objects' triangles; their ``shape_index`` indexes ``object_ids``.
        object_ids: (N,) int object ids.
        object_reflectivity: (N,) reflectivity per object.
        object_color: (N, 3) RGB in [0, 1] per object.
    """

    def __init__(self, static: StaticGeometry, objects: TriangleSoup, object_ids: np.ndarray,
                 object_reflectivity: np.ndarray, object_color: np.ndarray):
        self.static = static
        self._objects = _scene(objects.vertices, objects.triangles) if len(objects.triangles) else None
        # One extra entry at the end answers misses.
        self._triangle_object = np.concatenate([np.asarray(object_ids, dtype=np.int32)[objects.shape_index],
                                                [STATIC_ID]]).astype(np.int32)
        self._triangle_reflectivity = np.concatenate([
            np.asarray(object_reflectivity, dtype=np.float32)[objects.shape_index], [0.0]]).astype(np.float32)
        self._triangle_rgba = _rgba_word(shaded_rgb(objects.vertices, objects.triangles,
                                                    np.asarray(object_color, dtype=np.float64)[objects.shape_index]))

    def cast(self, rays: np.ndarray, *, static_hits: StaticHits | None = None,
             may_hit_objects: np.ndarray | None = None, skip: np.ndarray | None = None) -> RayHits:
        """Casts rays and returns their first hits.

        Args:
            rays: (R, 6) float32 origins and unit directions in the world frame (:func:`ray_array`).
            static_hits: these rays' hits in the static scene, if already known.
            may_hit_objects: (R,) bool, False for rays known to miss every object (None: all may hit).
            skip: (R,) bool, rays whose first hit the caller knows without casting (answered as misses; with
                ``static_hits`` None and ``may_hit_objects`` False for them).
        """
        if static_hits is None and skip is not None:
            cast = np.flatnonzero(~skip)
            static_hits = self.static.cast(rays[cast])
            t_hit = np.full(len(rays), np.inf, dtype=np.float32)
            reflectivity = np.zeros(len(rays), dtype=np.float32)
            cos_incidence = np.zeros(len(rays), dtype=np.float32)
            t_hit[cast], reflectivity[cast] = static_hits.t_hit, static_hits.reflectivity
            cos_incidence[cast] = static_hits.cos_incidence
        elif static_hits is None:
            static_hits = self.static.cast(rays)
            t_hit, reflectivity, cos_incidence = static_hits.t_hit, static_hits.reflectivity, static_hits.cos_incidence
        else:  # kept for the whole scene: updated on copies
            t_hit = static_hits.t_hit.copy()
            reflectivity = static_hits.reflectivity.copy()
            cos_incidence = static_hits.cos_incidence.copy()
        object_id = np.full(len(t_hit), STATIC_ID, dtype=np.int32)
        if self._objects is not None:
            index = np.arange(len(t_hit)) if may_hit_objects is None else np.flatnonzero(may_hit_objects)
            near_rays = rays[index]
            t_object, primitive, normal_object = _cast(self._objects, near_rays, len(self._triangle_object) - 1)
            nearer = t_object < t_hit[index]
            index, primitive = index[nearer], primitive[nearer]
            t_hit[index] = t_object[nearer]
            cos_incidence[index] = _cos_incidence(normal_object[nearer], near_rays[nearer, 3:])
            object_id[index] = self._triangle_object[primitive]
            reflectivity[index] = self._triangle_reflectivity[primitive]
        return RayHits(range_m=t_hit, object_id=object_id, reflectivity=reflectivity, cos_incidence=cos_incidence)

    def sees(self, origin_world: np.ndarray, directions_world: np.ndarray, object_id: np.ndarray,
             max_range_m: np.ndarray) -> np.ndarray:
        """Whether each ray's first hit is a given object, at most so far away.

        The same answer as comparing :meth:`cast`'s ``object_id`` and ``range_m``, but the costly static
        scene is cast only by the rays whose first object hit already qualifies: those are seen unless
        scenery is nearer (scenery wins a tie, as in :meth:`cast`).

        Args:
            origin_world: (3,) ray origin in the world frame.
            directions_world: (R, 3) unit directions in the world frame.
            object_id: (R,) the object each ray looks for (non-negative).
            max_range_m: (R,) the farthest that hit may be.

        Returns:
            (R,) bool.
        """
        seen = np.zeros(len(directions_world), dtype=bool)
        if self._objects is None:
            return seen
        rays = ray_array(origin_world, directions_world)
        t_object, primitive, _ = _cast(self._objects, rays, len(self._triangle_object) - 1)
        candidate = np.flatnonzero((self._triangle_object[primitive] == object_id) & (t_object <= max_range_m))
        t_static, _, _ = _cast(self.static._scene, rays[candidate], len(self.static._reflectivity) - 1)
        seen[candidate] = t_object[candidate] < t_static
        return seen

    def shade(self, rays: np.ndarray, max_range_m: float, may_hit_objects: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """What a camera sees along each ray: the colour and object id of its first hit.

        The same first hit as :meth:`cast` (the nearer of the static and the object hit, scenery on a tie); a
        hit farther than ``max_range_m`` is sky. A surface shows its triangle's flat shade (:func:`shaded_rgb`).

        Args:
            rays: (R, 6) float32 origin and unit direction of each ray in the world frame.
            max_range_m: the farthest hit the camera sees.
            may_hit_objects: (R,) bool, False for rays known to miss every object.

        Returns:
            (R,) uint32 colour whose bytes are R, G, B, 255, and (R,) int32 object id (-1 for scenery and sky).
        """
        t_hit, primitive, _ = _cast(self.static._scene, rays, len(self.static._reflectivity) - 1)
        rgba = self.static._rgba[primitive]
        object_id = np.full(len(t_hit), STATIC_ID, dtype=np.int32)
        if self._objects is not None:
            index = np.flatnonzero(may_hit_objects)
            t_object, primitive, _ = _cast(self._objects, rays[index], len(self._triangle_object) - 1)
            nearer = t_object < t_hit[index]
            index, primitive = index[nearer], primitive[nearer]
            t_hit[index] = t_object[nearer]
            rgba[index] = self._triangle_rgba[primitive]
            object_id[index] = self._triangle_object[primitive]
        sky = ~(t_hit <= np.float32(max_range_m))  # a miss is inf
        rgba[sky] = self.static._rgba[-1]
        object_id[sky] = STATIC_ID
        return rgba, object_id
