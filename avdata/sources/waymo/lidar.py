"""Waymo range images -> points, with the formulas of Waymo's ``utils/range_image_utils.py``.

A range image has H rows (beams) and W columns (azimuth bins). Row ``i`` is the beam of inclination
``reversed(inclinations)[i]`` (row 0 is the highest beam); column ``j`` has the azimuth

    azimuth_j = ((W - j - 0.5) / W * 2 - 1) * pi - atan2(E[1, 0], E[0, 0])

in the lidar frame (E = vehicle_T_lidar, the extrinsic), so that column 0 looks backwards and the
columns sweep clockwise seen from above. A pixel of range r > 0 is the lidar-frame point

    (cos(az) cos(incl) r, sin(az) cos(incl) r, sin(incl) r),

and ``vehicle = E @ point``. The top lidar also has a per-pixel vehicle pose ``world_T_vehicle(pixel)``
(roll, pitch, yaw, x, y, z; the pose when that pixel was measured, a rolling sweep): its points are
``vehicle_T_world(frame) @ world_T_vehicle(pixel) @ E @ point``, i.e. in the vehicle frame at the
frame's time. Computed in float64 (Waymo's TensorFlow code runs in the input's dtype, float32 by default).
"""

from __future__ import annotations

import numpy as np

from avdata.errors import InputError


def beam_inclinations(height: int, min_rad: float, max_rad: float, values_rad: np.ndarray | None) -> np.ndarray:
    """Each range-image row's beam inclination, row 0 first (Waymo: ``compute_inclination`` then reversed).

    Args:
        height: H, rows of the range image.
        min_rad: the lowest beam's inclination (uniform beams).
        max_rad: the highest beam's inclination (uniform beams).
        values_rad: (H,) per-beam inclinations from lowest to highest, or None for uniform beams.

    Returns:
        (H,) radians, row 0 (top row, highest beam) first.
    """
    if values_rad is not None and len(values_rad):
        inclination = np.asarray(values_rad, dtype=np.float64)
        if inclination.shape != (height,):
            raise InputError(f"beam_inclination.values: expected {height} values (one per row), got {inclination.shape[0]}")
    else:
        inclination = (0.5 + np.arange(height, dtype=np.float64)) / height * (max_rad - min_rad) + min_rad
    return inclination[::-1]


def rotation_from_roll_pitch_yaw(roll_pitch_yaw: np.ndarray) -> np.ndarray:
    """``transform_utils.get_rotation_matrix``: R = Rz(yaw) @ Ry(pitch) @ Rx(roll) (3-2-1 Euler angles).

    Args:
        roll_pitch_yaw: (..., 3) radians.

    Returns:
        (..., 3, 3) rotation matrices.
    """
    roll, pitch, yaw = np.moveaxis(np.asarray(roll_pitch_yaw, dtype=np.float64), -1, 0)
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], axis=-1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], axis=-1),
            np.stack([-sp, cp * sr, cp * cr], axis=-1),
        ],
        axis=-2,
    )


def range_image_points_lidar(
    range_image: np.ndarray, vehicle_T_lidar: np.ndarray, inclinations_rad: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The points of one range image return in the lidar's own frame (no extrinsic, no per-pixel pose).

    Args:
        range_image: (H, W, C) channels range (m), intensity, elongation, ...; pixels of range <= 0 are empty.
        vehicle_T_lidar: (4, 4) the lidar's extrinsic (its yaw sets the azimuth of column 0).
        inclinations_rad: (H,) beam inclination of each row, row 0 first (:func:`beam_inclinations`).

    Returns:
        ((N, 3) float64 points in the lidar frame, (N, 2) int64 (row, column) of each point), in
        row-major pixel order (Waymo's ``tf.where`` order).
    """
    range_image = np.asarray(range_image)
    height, width = range_image.shape[:2]
    extrinsic = np.asarray(vehicle_T_lidar, dtype=np.float64).reshape(4, 4)
    if inclinations_rad.shape != (height,):
        raise InputError(f"expected {height} beam inclinations, got {inclinations_rad.shape}")
    rows, cols = np.nonzero(range_image[..., 0] > 0)
    distance = range_image[rows, cols, 0].astype(np.float64)
    az_correction = np.arctan2(extrinsic[1, 0], extrinsic[0, 0])
    ratios = (np.arange(width, 0, -1, dtype=np.float64) - 0.5) / width
    azimuth = (ratios * 2.0 - 1.0) * np.pi - az_correction
    # Trigonometry once per column and per row, then gathered per point.
    cos_incl = np.cos(inclinations_rad)[rows] * distance
    points = np.stack([np.cos(azimuth)[cols] * cos_incl, np.sin(azimuth)[cols] * cos_incl,
                       np.sin(inclinations_rad)[rows] * distance], axis=1)
    return points, np.stack([rows, cols], axis=1)


def range_image_points(
    range_image: np.ndarray,
    vehicle_T_lidar: np.ndarray,
    inclinations_rad: np.ndarray,
    pixel_pose: np.ndarray | None = None,
    world_T_vehicle: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The points of one range image return, in the vehicle frame at the frame time (Waymo's points).

    Args:
        range_image: (H, W, C) channels range (m), intensity, elongation, ...; pixels of range <= 0 are empty.
        vehicle_T_lidar: (4, 4) the lidar's extrinsic.
        inclinations_rad: (H,) beam inclination of each row, row 0 first (:func:`beam_inclinations`).
        pixel_pose: (H, W, 6) roll, pitch, yaw, x, y, z of ``world_T_vehicle`` per pixel (top lidar), or None.
        world_T_vehicle: (4, 4) the frame's vehicle pose; required with ``pixel_pose``.

    Returns:
        ((N, 3) float64 points in the vehicle frame, (N, 2) int64 (row, column) of each point), in
        row-major pixel order (Waymo's ``tf.where`` order).
    """
    extrinsic = np.asarray(vehicle_T_lidar, dtype=np.float64).reshape(4, 4)
    points_lidar, pixels = range_image_points_lidar(range_image, extrinsic, inclinations_rad)
    points = points_lidar @ extrinsic[:3, :3].T + extrinsic[:3, 3]
    if pixel_pose is not None:
        if world_T_vehicle is None:
            raise InputError("a per-pixel pose needs the frame's vehicle pose, got none")
        pose = np.asarray(pixel_pose, dtype=np.float64)[pixels[:, 0], pixels[:, 1]]
        rotation = rotation_from_roll_pitch_yaw(pose[:, :3])
        points_world = np.einsum("nij,nj->ni", rotation, points) + pose[:, 3:]
        # The full 4x4 inverse, as Waymo's code takes it (float32 poses are not exactly orthonormal).
        vehicle_T_world = np.linalg.inv(np.asarray(world_T_vehicle, dtype=np.float64).reshape(4, 4))
        points = points_world @ vehicle_T_world[:3, :3].T + vehicle_T_world[:3, 3]
    return points, pixels
