"""The pybullet world: static town bodies and one body per object, holding the objects' poses.

pybullet runs in DIRECT mode (no GUI, no server). The bodies are collision shapes only: every sensor,
cameras included, casts rays into the matching Open3D scenes (:mod:`~avdata.generators.world`), which are
read from these bodies' poses. pybullet quaternions are (x, y, z, w); the reorder to avdata's (w, x, y, z)
happens only here.
"""

from __future__ import annotations

import numpy as np

from avdata.frames import Transform
from avdata.generators._pybullet import load_pybullet
from avdata.generators.town import StaticScenery

pybullet = load_pybullet()


class BulletWorld:
    """The town and its objects as pybullet bodies.

    Bodies are created in a fixed order (static boxes, cylinders, spheres, then the objects).

    Args:
        scenery: the static town.
        size_lwh: (N, 3) object box sizes.
    """

    def __init__(self, scenery: StaticScenery, size_lwh: np.ndarray):
        self.client = pybullet.connect(pybullet.DIRECT)
        self._add_static_bodies(scenery)
        self._bodies = [self._add_box(size, mass=1.0) for size in np.asarray(size_lwh, dtype=np.float64)]

    def close(self) -> None:
        """Disconnects from pybullet."""
        pybullet.disconnect(physicsClientId=self.client)

    def _add_box(self, size: np.ndarray, mass: float = 0.0, center: np.ndarray | None = None) -> int:
        half = (np.asarray(size) / 2).tolist()
        collision = pybullet.createCollisionShape(pybullet.GEOM_BOX, halfExtents=half, physicsClientId=self.client)
        position = [0.0, 0.0, -100.0] if center is None else np.asarray(center).tolist()
        body: int = pybullet.createMultiBody(mass, collision, basePosition=position, physicsClientId=self.client)
        return body

    def _add_static_bodies(self, scenery: StaticScenery) -> None:
        c = self.client
        for center, size in zip(scenery.box_center, scenery.box_size, strict=True):
            self._add_box(size, center=center)
        for center, radius, height in zip(scenery.cylinder_center, scenery.cylinder_radius, scenery.cylinder_height,
                                          strict=True):
            collision = pybullet.createCollisionShape(pybullet.GEOM_CYLINDER, radius=float(radius),
                                                      height=float(height), physicsClientId=c)
            pybullet.createMultiBody(0.0, collision, basePosition=center.tolist(), physicsClientId=c)
        for center, radius in zip(scenery.sphere_center, scenery.sphere_radius, strict=True):
            collision = pybullet.createCollisionShape(pybullet.GEOM_SPHERE, radius=float(radius), physicsClientId=c)
            pybullet.createMultiBody(0.0, collision, basePosition=center.tolist(), physicsClientId=c)

    # ------------------------------------------------------------------ poses
    def set_object_poses(self, center_world: np.ndarray, yaw_rad: np.ndarray) -> None:
        """Moves every object body.

        Args:
            center_world: (N, 3) box centres in the world frame.
            yaw_rad: (N,) headings.
        """
        half = np.asarray(yaw_rad) / 2
        quat_xyzw = np.stack([np.zeros_like(half), np.zeros_like(half), np.sin(half), np.cos(half)], axis=-1)
        for body, position, quat in zip(self._bodies, center_world.tolist(), quat_xyzw.tolist(), strict=True):
            pybullet.resetBasePositionAndOrientation(body, position, quat, physicsClientId=self.client)

    def object_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """Reads every object's pose back from pybullet.

        Returns:
            (N, 3) centres and (N, 3, 3) rotations in the world frame.
        """
        states = [pybullet.getBasePositionAndOrientation(b, physicsClientId=self.client) for b in self._bodies]
        if not states:
            return np.zeros((0, 3)), np.zeros((0, 3, 3))
        center = np.array([s[0] for s in states])
        quat_xyzw = np.array([s[1] for s in states])
        return center, Transform.from_quat_wxyz(quat_xyzw[:, [3, 0, 1, 2]]).rotation
