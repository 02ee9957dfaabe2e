"""The pybullet world: static town bodies, one body per object, camera rendering.

pybullet runs in DIRECT mode (no GUI, no server). It holds the scene's bodies and their poses and renders
camera images with segmentation masks (TinyRenderer, deterministic on the CPU). This module does not load
Open3D, so a camera render worker (:mod:`~avdata.generators.render_worker`) starts in a fraction of a
second. pybullet quaternions are (x, y, z, w); the reorder to avdata's (w, x, y, z) happens only here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avdata.frames import Transform
from avdata.generators._pybullet import load_pybullet
from avdata.generators.town import StaticScenery

pybullet = load_pybullet()

_COLORS = {"ground": (0.35, 0.35, 0.37), "sidewalk": (0.6, 0.6, 0.58), "building": (0.75, 0.68, 0.6),
           "wall": (0.55, 0.45, 0.4), "pole": (0.3, 0.3, 0.3), "crown": (0.2, 0.5, 0.2),
           "car": (0.15, 0.3, 0.8), "van": (0.8, 0.8, 0.85), "truck": (0.8, 0.3, 0.1), "bus": (0.9, 0.8, 0.1),
           "motorcycle": (0.6, 0.1, 0.6), "cyclist": (0.1, 0.7, 0.7), "pedestrian": (0.9, 0.2, 0.2)}


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraImage:
    """One rendered camera image.

    Attributes:
        rgb: (H, W, 3) uint8 colour image.
        object_id: (H, W) int32 object id per pixel, -1 for static scenery and sky.
    """

    rgb: np.ndarray
    object_id: np.ndarray


class BulletWorld:
    """The town and its objects as pybullet bodies.

    Bodies are created in a fixed order (static boxes, cylinders, spheres, then the objects), so two
    ``BulletWorld`` of the same arguments have the same body ids and render the same pixels.

    Args:
        scenery: the static town.
        object_ids: (N,) int object ids.
        object_classes: (N,) simulator classes of the objects.
        size_lwh: (N, 3) object box sizes.
    """

    def __init__(self, scenery: StaticScenery, object_ids: np.ndarray, object_classes: np.ndarray,
                 size_lwh: np.ndarray):
        self.client = pybullet.connect(pybullet.DIRECT)
        self._add_static_bodies(scenery)
        self._bodies = [self._add_box(size, _COLORS[cls], mass=1.0) for size, cls in
                        zip(np.asarray(size_lwh, dtype=np.float64), np.asarray(object_classes), strict=True)]
        max_uid = max([*self._bodies, 0]) + 1
        self._uid_to_object = np.full(max_uid + 1, -1, dtype=np.int32)
        self._uid_to_object[np.array(self._bodies, dtype=np.int64)] = np.asarray(object_ids, dtype=np.int64)

    def close(self) -> None:
        """Disconnects from pybullet."""
        pybullet.disconnect(physicsClientId=self.client)

    def _add_box(self, size: np.ndarray, color: tuple[float, float, float], mass: float = 0.0,
                 center: np.ndarray | None = None) -> int:
        half = (np.asarray(size) / 2).tolist()
        collision = pybullet.createCollisionShape(pybullet.GEOM_BOX, halfExtents=half, physicsClientId=self.client)
        visual = pybullet.createVisualShape(pybullet.GEOM_BOX, halfExtents=half, rgbaColor=[*color, 1.0],
                                            physicsClientId=self.client)
        position = [0.0, 0.0, -100.0] if center is None else np.asarray(center).tolist()
        return pybullet.createMultiBody(mass, collision, visual, basePosition=position, physicsClientId=self.client)

    def _add_static_bodies(self, scenery: StaticScenery) -> None:
        c = self.client
        for center, size, kind in zip(scenery.box_center, scenery.box_size, scenery.box_kind, strict=True):
            self._add_box(size, _COLORS[str(kind)], center=center)
        for center, radius, height in zip(scenery.cylinder_center, scenery.cylinder_radius, scenery.cylinder_height,
                                          strict=True):
            collision = pybullet.createCollisionShape(pybullet.GEOM_CYLINDER, radius=float(radius),
                                                      height=float(height), physicsClientId=c)
            visual = pybullet.createVisualShape(pybullet.GEOM_CYLINDER, radius=float(radius), length=float(height),
                                                rgbaColor=[*_COLORS["pole"], 1.0], physicsClientId=c)
            pybullet.createMultiBody(0.0, collision, visual, basePosition=center.tolist(), physicsClientId=c)
        for center, radius in zip(scenery.sphere_center, scenery.sphere_radius, strict=True):
            collision = pybullet.createCollisionShape(pybullet.GEOM_SPHERE, radius=float(radius), physicsClientId=c)
            visual = pybullet.createVisualShape(pybullet.GEOM_SPHERE, radius=float(radius),
                                                rgbaColor=[*_COLORS["crown"], 1.0], physicsClientId=c)
            pybullet.createMultiBody(0.0, collision, visual, basePosition=center.tolist(), physicsClientId=c)

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

    # ------------------------------------------------------------------ camera
    def render(self, world_T_camera: Transform, width: int, height: int, vertical_fov_deg: float,
               near_m: float, far_m: float, rows: tuple[int, int] | None = None) -> CameraImage:
        """Renders a camera whose frame is optical (x right, y down, z forward), or a strip of its rows.

        A strip is rendered through the same projection followed by a scale and shift of the clip-space y
        that maps the strip's rows onto the whole viewport (an off-axis frustum), so strips rendered apart
        (e.g. in parallel processes) and stacked give the whole image, up to rounding in the rasteriser:
        a few pixels where two surfaces meet or coincide may take the other surface's colour (7 of 115,200
        in the determinism test's 3 images, none in 4 of the benchmark's; the object-id masks were identical).

        Args:
            world_T_camera: pose of the optical camera frame in the world.
            width: image width in pixels.
            height: image height in pixels.
            vertical_fov_deg: vertical field of view.
            near_m: near clipping distance.
            far_m: far clipping distance.
            rows: the first and end row of a strip (None: the whole image).

        Returns:
            The image, or the strip's rows of it.
        """
        gl_T_optical = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenGL camera: x right, y up, z backwards
        view = gl_T_optical @ world_T_camera.inverse().as_matrix()
        projection = pybullet.computeProjectionMatrixFOV(vertical_fov_deg, width / height, near_m, far_m)
        first, end = (0, height) if rows is None else rows
        if (first, end) != (0, height):
            # Normalised y of the strip's top and bottom edges (row 0 is the top, y = +1).
            top, bottom = 1.0 - 2.0 * first / height, 1.0 - 2.0 * end / height
            scale, middle = 2.0 / (top - bottom), (top + bottom) / 2.0
            strip = np.eye(4)
            strip[1] = scale * np.eye(4)[1] - scale * middle * np.eye(4)[3]  # y' = s (y - m w) in clip space
            projection = (strip @ np.asarray(projection).reshape(4, 4).T).T.ravel().tolist()
        height = end - first
        _, _, rgba, _, seg = pybullet.getCameraImage(
            width, height, viewMatrix=view.T.ravel().tolist(), projectionMatrix=projection,
            renderer=pybullet.ER_TINY_RENDERER, physicsClientId=self.client,
        )
        rgba = np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)
        seg = np.asarray(seg, dtype=np.int64).reshape(height, width)
        lookup = np.concatenate([[-1], self._uid_to_object])  # index uid + 1: uid -1 is the sky
        object_id = lookup[np.clip(seg + 1, 0, len(lookup) - 1)]
        object_id = np.where(seg >= len(self._uid_to_object), -1, object_id)
        return CameraImage(rgb=np.ascontiguousarray(rgba[..., :3]), object_id=object_id.astype(np.int32))
