"""The simulated world: pybullet bodies (poses) and the matching ray-casting geometry.

The pybullet part lives in :mod:`~avdata.generators.bodies`; this module adds the Open3D ray-casting
scenes, the static town's built once and the objects' rebuilt per frame from the pybullet bodies' poses,
which every sensor casts into (LiDARs and cameras alike).
"""

from __future__ import annotations

import numpy as np

from avdata.generators.bodies import BulletWorld
from avdata.generators.mesh import TriangleSoup, box_mesh, cylinder_mesh, sphere_mesh
from avdata.generators.raycast import RaycastWorld, StaticGeometry
from avdata.generators.town import StaticScenery

STATIC_REFLECTIVITY = {"ground": 0.15, "sidewalk": 0.25, "building": 0.35, "wall": 0.3, "pole": 0.4, "crown": 0.2}
"""Diffuse reflectivity of static surfaces (asphalt is dark, concrete brighter, foliage dark)."""

OBJECT_REFLECTIVITY = {"car": 0.6, "van": 0.6, "truck": 0.55, "bus": 0.55, "motorcycle": 0.5, "cyclist": 0.4,
                       "pedestrian": 0.35}
"""Diffuse reflectivity of objects by simulator class (painted metal brighter than clothing)."""

SURFACE_COLOR = {"ground": (0.35, 0.35, 0.37), "sidewalk": (0.6, 0.6, 0.58), "building": (0.75, 0.68, 0.6),
                 "wall": (0.55, 0.45, 0.4), "pole": (0.3, 0.3, 0.3), "crown": (0.2, 0.5, 0.2),
                 "car": (0.15, 0.3, 0.8), "van": (0.8, 0.8, 0.85), "truck": (0.8, 0.3, 0.1), "bus": (0.9, 0.8, 0.1),
                 "motorcycle": (0.6, 0.1, 0.6), "cyclist": (0.1, 0.7, 0.7), "pedestrian": (0.9, 0.2, 0.2)}
"""RGB in [0, 1] of static surfaces by kind and of objects by simulator class, as cameras see them."""


def static_triangles(scenery: StaticScenery) -> tuple[TriangleSoup, np.ndarray, np.ndarray]:
    """The static town's triangles, (T,) float32 reflectivity and (T, 3) float32 colour per triangle."""
    n_box = len(scenery.box_center)
    boxes = box_mesh(scenery.box_center, scenery.box_size, np.broadcast_to(np.eye(3), (n_box, 3, 3)))
    cylinders = cylinder_mesh(scenery.cylinder_center, scenery.cylinder_radius, scenery.cylinder_height)
    spheres = sphere_mesh(scenery.sphere_center, scenery.sphere_radius)
    soup = TriangleSoup.concatenate([boxes, cylinders, spheres], [0, n_box, n_box + len(scenery.cylinder_center)])
    shape_kind = np.concatenate([np.asarray(scenery.box_kind, dtype=str),
                                 np.full(len(scenery.cylinder_center), "pole"),
                                 np.full(len(scenery.sphere_center), "crown")])
    shape_reflectivity = np.array([STATIC_REFLECTIVITY[str(k)] for k in shape_kind], dtype=np.float64)
    shape_color = np.array([SURFACE_COLOR[str(k)] for k in shape_kind], dtype=np.float64).reshape(-1, 3)
    return (soup, shape_reflectivity[soup.shape_index].astype(np.float32),
            shape_color[soup.shape_index].astype(np.float32))


class SimWorld:
    """The town and its objects in pybullet, and the matching ray-casting geometry.

    The static town's ray-casting scene (``static_geometry``) is built once; the objects' per frame.

    Args:
        scenery: the static town.
        object_ids: (N,) int object ids.
        object_classes: (N,) simulator classes of the objects.
        size_lwh: (N, 3) object box sizes; objects are modelled as their boxes, so labels, rendering
            and ray casting agree exactly.
    """

    def __init__(self, scenery: StaticScenery, object_ids: np.ndarray, object_classes: np.ndarray,
                 size_lwh: np.ndarray):
        self.object_ids = np.asarray(object_ids, dtype=np.int64)
        self.object_classes = np.asarray(object_classes)
        self.size_lwh = np.asarray(size_lwh, dtype=np.float64)
        self.bodies = BulletWorld(scenery, self.size_lwh)
        self.static_geometry = StaticGeometry(*static_triangles(scenery))
        self._object_reflectivity = np.array([OBJECT_REFLECTIVITY[c] for c in self.object_classes], dtype=np.float32)
        self._object_color = np.array([SURFACE_COLOR[c] for c in self.object_classes], dtype=np.float32).reshape(-1, 3)
        self._poses: tuple[np.ndarray, np.ndarray] | None = None

    def close(self) -> None:
        """Disconnects from pybullet."""
        self.bodies.close()

    def set_object_poses(self, center_world: np.ndarray, yaw_rad: np.ndarray) -> None:
        """Moves every object body (see :meth:`BulletWorld.set_object_poses`)."""
        self.bodies.set_object_poses(center_world, yaw_rad)
        self._poses = None

    def object_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) centres and (N, 3, 3) rotations of the objects, read back from pybullet (read-only).

        Read once per :meth:`set_object_poses` (a frame asks twice: its ray-casting scene and its labels).
        """
        if self._poses is None:
            center, rotation = self.bodies.object_poses()
            center.flags.writeable = rotation.flags.writeable = False
            self._poses = center, rotation
        return self._poses

    def raycast_world(self) -> RaycastWorld:
        """The ray-casting scene of the current poses, read from the pybullet bodies."""
        center, rotation = self.object_poses()
        objects = box_mesh(center, self.size_lwh, rotation)
        return RaycastWorld(self.static_geometry, objects, self.object_ids, self._object_reflectivity,
                            self._object_color)
