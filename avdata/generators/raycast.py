"""Ray casting through Open3D's Embree-backed ``RaycastingScene``, with an object id on every hit.

The scene is rebuilt per frame from the static town (object id -1) and the objects' boxes at their
current poses. Open3D cannot move geometry once added, and building the bounding-volume hierarchy of
a few ten thousand triangles takes milliseconds, so a rebuild per frame is the simple and fast way.
A hit's primitive id maps to an object id with one lookup into a per-triangle table.
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

    The static triangles and the objects' triangles go into one mesh (static first), so a hit's
    primitive id alone gives the object id and reflectivity.

    Args:
        static: the static town's triangles; ``static_reflectivity`` (T_s,) per triangle.
        objects: the objects' triangles; their ``shape_index`` indexes ``object_ids``.
        object_ids: (N,) int object ids.
        object_reflectivity: (N,) reflectivity per object.
    """

    def __init__(self, static: TriangleSoup, static_reflectivity: np.ndarray, objects: TriangleSoup,
                 object_ids: np.ndarray, object_reflectivity: np.ndarray):
        vertices = np.concatenate([static.vertices, objects.vertices]).astype(np.float32)
        triangles = np.concatenate([static.triangles, objects.triangles + np.uint32(len(static.vertices))])
        self._scene = o3d.t.geometry.RaycastingScene(nthreads=0)
        self._scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(triangles.astype(np.uint32)))
        # One extra entry at the end answers misses (primitive id INVALID, mapped to -1 below).
        self._triangle_object = np.concatenate([
            np.full(len(static.triangles), STATIC_ID, dtype=np.int32),
            np.asarray(object_ids, dtype=np.int32)[objects.shape_index],
            [STATIC_ID],
        ])
        self._triangle_reflectivity = np.concatenate([
            static_reflectivity.astype(np.float32),
            np.asarray(object_reflectivity, dtype=np.float32)[objects.shape_index],
            [0.0],
        ]).astype(np.float32)

    def cast(self, origins_world: np.ndarray, directions_world: np.ndarray) -> RayHits:
        """Casts rays and returns their first hits.

        Args:
            origins_world: (R, 3) or (3,) ray origins in the world frame.
            directions_world: (R, 3) unit directions in the world frame.
        """
        rays = np.empty((len(directions_world), 6), dtype=np.float32)
        rays[:, :3] = origins_world
        rays[:, 3:] = directions_world
        result = self._scene.cast_rays(o3d.core.Tensor.from_numpy(rays))
        t_hit = result["t_hit"].numpy()
        primitive = result["primitive_ids"].numpy().astype(np.int64)
        primitive[primitive >= len(self._triangle_object) - 1] = len(self._triangle_object) - 1
        normals = result["primitive_normals"].numpy()
        cos_incidence = -np.einsum("ij,ij->i", normals, rays[:, 3:])
        return RayHits(
            range_m=t_hit.astype(np.float64),
            object_id=self._triangle_object[primitive],
            reflectivity=self._triangle_reflectivity[primitive],
            cos_incidence=np.where(np.isfinite(t_hit), cos_incidence, np.float32(0.0)),
        )
