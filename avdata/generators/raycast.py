"""Ray casting through Open3D's Embree-backed ``RaycastingScene``, with an object id on every hit.

The scene is rebuilt per frame from two triangle soups: the static town (object id -1) and the
objects' boxes at their current poses. Open3D cannot move geometry once added, and building the
bounding-volume hierarchy of a few ten thousand triangles takes milliseconds, so a rebuild per frame
is the simple and fast way. A hit's (geometry id, primitive id) maps to an object id with one lookup
into a per-triangle table.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avdata.generators._open3d import o3d
from avdata.generators.mesh import TriangleSoup

STATIC_ID = -1
"""Object id of everything that is not an object (ground, buildings, trees, poles)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class RayHits:
    """First hits of a batch of rays.

    Attributes:
        range_m: (R,) distance along the (unit) ray, inf for a miss.
        object_id: (R,) object id hit, -1 for static scenery or a miss.
        reflectivity: (R,) reflectivity of the surface hit (0 for a miss).
        cos_incidence: (R,) cosine between the ray and the hit triangle's normal (0 for a miss).
    """

    range_m: np.ndarray
    object_id: np.ndarray
    reflectivity: np.ndarray
    cos_incidence: np.ndarray


class RaycastWorld:
    """One frame's geometry, ready for casting.

    Args:
        static: the static town's triangles; ``static_reflectivity`` (T_s,) per triangle.
        objects: the objects' triangles; their ``shape_index`` indexes ``object_ids``.
        object_ids: (N,) int object ids.
        object_reflectivity: (N,) reflectivity per object.
    """

    def __init__(self, static: TriangleSoup, static_reflectivity: np.ndarray, objects: TriangleSoup,
                 object_ids: np.ndarray, object_reflectivity: np.ndarray):
        self._scene = o3d.t.geometry.RaycastingScene(nthreads=0)
        self._static_geometry = self._scene.add_triangles(
            o3d.core.Tensor(static.vertices), o3d.core.Tensor(static.triangles)
        )
        self._static_reflectivity = static_reflectivity.astype(np.float32)
        if len(objects.triangles):
            self._scene.add_triangles(o3d.core.Tensor(objects.vertices), o3d.core.Tensor(objects.triangles))
        self._triangle_object = np.asarray(object_ids, dtype=np.int32)[objects.shape_index]
        self._triangle_reflectivity = np.asarray(object_reflectivity, dtype=np.float32)[objects.shape_index]

    def cast(self, origins_world: np.ndarray, directions_world: np.ndarray) -> RayHits:
        """Casts rays and returns their first hits.

        Args:
            origins_world: (R, 3) or (3,) ray origins in the world frame.
            directions_world: (R, 3) unit directions in the world frame.
        """
        directions_world = np.asarray(directions_world, dtype=np.float32)
        origins = np.broadcast_to(np.asarray(origins_world, dtype=np.float32), directions_world.shape)
        rays = o3d.core.Tensor(np.ascontiguousarray(np.concatenate([origins, directions_world], axis=1)))
        result = self._scene.cast_rays(rays)
        t_hit = result["t_hit"].numpy()
        geometry = result["geometry_ids"].numpy()
        primitive = result["primitive_ids"].numpy().astype(np.int64)
        normals = result["primitive_normals"].numpy()
        hit = np.isfinite(t_hit)
        is_object = hit & (geometry != self._static_geometry)
        safe_object = np.where(is_object, primitive, 0)
        safe_static = np.where(hit & ~is_object, primitive, 0)
        object_id = np.where(is_object, self._triangle_object[safe_object] if len(self._triangle_object) else 0,
                             STATIC_ID)
        reflectivity = np.where(
            is_object,
            self._triangle_reflectivity[safe_object] if len(self._triangle_reflectivity) else 0.0,
            np.where(hit, self._static_reflectivity[safe_static], 0.0),
        )
        cos_incidence = np.where(hit, -np.einsum("ij,ij->i", normals, directions_world), 0.0)
        return RayHits(
            range_m=t_hit.astype(np.float64),
            object_id=object_id.astype(np.int32),
            reflectivity=reflectivity.astype(np.float32),
            cos_incidence=cos_incidence.astype(np.float32),
        )
