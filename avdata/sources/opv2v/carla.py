"""CARLA's left-handed poses and boxes (OPV2V, V2XSet) as right-handed transforms and :class:`Boxes3D`.

CARLA/Unreal axes are x forward, y right, z up, rotations in degrees. Everything here goes through the one
explicit reflection :data:`avdata.frames.RH_T_CARLA` (y -> -y), so the results are proper, right-handed
transforms and boxes: same sizes, mirrored positions and headings (a CARLA yaw of +30 degrees becomes -30).
"""

from __future__ import annotations

import numpy as np

from avdata.frames import RH_T_CARLA, Boxes3D, Transform, carla_rotation_matrix

__all__ = ["boxes_from_carla", "boxes_to_carla", "carla_pose_matrix", "world_T_carla_pose"]


def carla_pose_matrix(pose: np.ndarray) -> np.ndarray:
    """OpenCOOD's ``x_to_world``: (..., 6) [x, y, z, roll, yaw, pitch] degrees -> (..., 4, 4), left-handed."""
    pose = np.asarray(pose, dtype=np.float64)
    matrix = np.zeros(pose.shape[:-1] + (4, 4))
    matrix[..., :3, :3] = carla_rotation_matrix(pose[..., [3, 5, 4]])  # (roll, pitch, yaw)
    matrix[..., :3, 3] = pose[..., :3]
    matrix[..., 3, 3] = 1.0
    return matrix


def world_T_carla_pose(pose: np.ndarray) -> Transform:
    """A CARLA pose [x, y, z, roll, yaw, pitch] as a right-handed ``world_T_x``.

    ``rh_T_lh_world @ x_to_world(pose) @ lh_T_rh_x``: both the map and the posed frame are reflected
    (y -> -y), so the result is proper and maps the reflected (right-handed) coordinates.
    """
    return RH_T_CARLA @ Transform.from_matrix(carla_pose_matrix(pose)) @ RH_T_CARLA.inverse()


def boxes_from_carla(
    location: np.ndarray,
    extent_half: np.ndarray,
    rotation_deg: np.ndarray,
    frame: str,
    center_offset: np.ndarray | None = None,
    **extra: np.ndarray | None,
) -> Boxes3D:
    """From CARLA/OPV2V boxes in a left-handed world, into the right-handed ``frame``.

    The numbers are coordinates in CARLA's left-handed axes (x forward, y right, z up, degrees).
    They are read as a box in that frame and moved through the explicit reflection
    :data:`~avdata.frames.RH_T_CARLA`, so the result is a right-handed box: same size, mirrored position
    and heading.

    Args:
        location: (N, 3) actor location in the left-handed world.
        extent_half: (N, 3) half-extents along the actor's x, y, z.
        rotation_deg: (N, 3) roll, pitch, yaw in degrees (carla.Rotation; OPV2V stores
            ``angle`` as [roll, yaw, pitch]: reorder before calling).
        frame: the right-handed frame the result is expressed in.
        center_offset: (N, 3) bounding-box centre relative to the actor origin, in the actor's
            left-handed axes (carla ``bounding_box.location``, OPV2V ``center``), or None.
        **extra: ``ids``, ``classes``, ``velocity`` (in CARLA's axes) as in :class:`~avdata.frames.Boxes3D`.
    """
    location = np.asarray(location, dtype=np.float64).reshape(-1, 3)
    rotation_lh = carla_rotation_matrix(np.asarray(rotation_deg, dtype=np.float64).reshape(-1, 3))
    center_lh = location
    if center_offset is not None:
        offset = np.asarray(center_offset, dtype=np.float64).reshape(-1, 3)
        center_lh = location + np.einsum("nij,nj->ni", rotation_lh, offset)
    size_lwh = 2.0 * np.asarray(extent_half, dtype=np.float64).reshape(-1, 3)
    boxes_lh = Boxes3D.from_rotation(center_lh, size_lwh, rotation_lh, "carla_world", **extra)
    return boxes_lh.transform(RH_T_CARLA, frame)


def boxes_to_carla(boxes: Boxes3D) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(location (N, 3), extent_half (N, 3), rotation_deg (N, 3) roll-pitch-yaw) in CARLA's axes."""
    boxes_lh = boxes.transform(RH_T_CARLA.inverse(), "carla_world")
    rotation = boxes_lh.rotation_matrix()
    pitch = np.degrees(np.arcsin(np.clip(rotation[:, 2, 0], -1.0, 1.0)))
    yaw = np.degrees(np.arctan2(rotation[:, 1, 0], rotation[:, 0, 0]))
    roll = np.degrees(np.arctan2(-rotation[:, 2, 1], rotation[:, 2, 2]))
    return boxes_lh.center, boxes.size_lwh / 2.0, np.stack([roll, pitch, yaw], axis=1)
