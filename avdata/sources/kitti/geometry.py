"""KITTI calibration and oxts packets as transforms of the unified frame tree.

Formulas (KITTI devkit, readme of the object and raw development kits):

- ``x_rect0 = R0_rect · Tr_velo_to_cam · x_velo``: rectified camera 0 from velodyne, through the
  unrectified camera 0 (``Tr_velo_to_cam`` maps into it, ``R0_rect`` rotates it into the rectified one).
- ``P_i = K_i · [I | t_i]`` projects points of rectified camera 0 into image i, so the 4th column is
  camera i's offset from rectified camera 0: ``t_i = K_i^-1 · P_i[:, 3]`` with ``K_i = P_i[:, :3]``,
  i.e. ``cam_i_T_cam0 = (I, t_i)``. It becomes a real translation of frame ``cam_i``; ``K_i`` is then
  applied to points already in camera i, so the offset is not counted twice.
- oxts: Mercator with scale ``s = cos(lat_0)`` of the first packet, ``x = s·r·lon``,
  ``y = s·r·ln(tan(pi/4 + lat/2))``, ``z = alt`` (r = 6378137 m); rotation ``Rz(yaw)·Ry(pitch)·Rx(roll)``
  (yaw 0 = east, counter-clockwise); ``world`` is the first pose (``world_T_ego[0] = I``).

KITTI prints its matrices with 7 digits, so their rotations are orthonormal only to ~1e-7; each is
replaced by its nearest rotation (SVD) before it is stored as a quaternion. That moves projected
points by at most ~0.002 px.
"""

from __future__ import annotations

import numpy as np

from avdata.frames import Boxes3D, Transform
from avdata.frames.rotations import orthonormalize
from avdata.sources.kitti.calib import KittiCalib

EARTH_RADIUS_M = 6378137.0
#: Frame names below the agent (``ego/<name>``).
VELODYNE = "velodyne"
CAM0_UNRECTIFIED = "cam0_unrectified"
IMU = "imu"


def camera_frame(index: int) -> str:
    """The name of rectified camera ``index`` below the agent: ``cam0`` .. ``cam3``."""
    return f"cam{index}"


def rigid(matrix_3x4: np.ndarray) -> Transform:
    """A KITTI (3, 4) [R | t] as a transform with R replaced by its nearest rotation.

    The matrix was checked by the one rotation rule when its calibration file was read
    (:func:`avdata.sources.kitti.calib.read_calib`): not checked a second time here.
    """
    transform = Transform.from_matrix(matrix_3x4)
    return Transform(rotation=orthonormalize(transform.rotation), translation=transform.translation)


def intrinsics(calib: KittiCalib, index: int) -> np.ndarray:
    """(3, 3) K of rectified camera ``index``: the left 3x3 block of ``P_index``."""
    K: np.ndarray = calib.P[index][:, :3].copy()
    return K


def camera_offset(calib: KittiCalib, index: int) -> np.ndarray:
    """(3,) t_i = K_i^-1 P_i[:, 3]: camera ``index``'s position relative to rectified camera 0, in its axes."""
    return np.linalg.solve(intrinsics(calib, index), calib.P[index][:, 3])


#: :func:`velo_T_sensors` by the calibration's matrices (bytes): object samples share calibrations.
_POSES_BY_CALIB: dict[bytes, dict[str, Transform]] = {}
_POSES_CACHE_SIZE = 256


def calibration_key(calib: KittiCalib) -> bytes:
    """The calibration's matrices as bytes: equal keys, equal calibrations (a cache key)."""
    matrices = (calib.P, calib.R0_rect, calib.velo_to_cam, calib.imu_to_velo)
    return b"|".join(b"-" if matrix is None else matrix.tobytes() for matrix in matrices)


def velo_T_sensors(calib: KittiCalib) -> dict[str, Transform]:
    """Every sensor frame's pose in the velodyne frame.

    Returns:
        ``{"cam0_unrectified": velo_T_cam0u, "cam0".."cam3": velo_T_cam_i, "imu": velo_T_imu}``
        (``imu`` only when the calibration has ``Tr_imu_to_velo``). Rotations are orthonormal.
    """
    key = calibration_key(calib)
    poses = _POSES_BY_CALIB.get(key)
    if poses is None:
        if len(_POSES_BY_CALIB) >= _POSES_CACHE_SIZE:
            _POSES_BY_CALIB.clear()
        poses = _POSES_BY_CALIB[key] = _velo_T_sensors(calib)
    return dict(poses)


def _velo_T_sensors(calib: KittiCalib) -> dict[str, Transform]:
    cam0u_T_velo = rigid(calib.velo_to_cam)
    cam0_T_cam0u = Transform(rotation=orthonormalize(calib.R0_rect), translation=np.zeros(3))  # checked when read
    velo_T_cam0u = cam0u_T_velo.inverse()
    velo_T_cam0 = velo_T_cam0u @ cam0_T_cam0u.inverse()
    poses = {CAM0_UNRECTIFIED: velo_T_cam0u}
    for i in range(4):
        cam0_T_cami = Transform(rotation=np.eye(3), translation=-camera_offset(calib, i))
        poses[camera_frame(i)] = velo_T_cam0 @ cam0_T_cami
    if calib.imu_to_velo is not None:
        poses[IMU] = rigid(calib.imu_to_velo)
    return poses


#: Devkit corner k (``compute_box_3d``) is corner DEVKIT_CORNERS[k] of :meth:`Boxes3D.corners`.
DEVKIT_CORNERS = (3, 2, 6, 7, 0, 1, 5, 4)


def compute_box_3d(dimensions_hwl: np.ndarray, location_bottom: np.ndarray, rotation_y: np.ndarray) -> np.ndarray:
    """(N, 8, 3) corners of KITTI label boxes in the rectified camera, in the devkit's ``compute_box_3d`` order.

    The devkit's formula: ``roty(ry) @ [x; y; z] + location`` with x = ±l/2, y = 0 (bottom) or -h (top),
    z = ±w/2, corners 0-3 on the bottom. The geometry is :meth:`Boxes3D.from_kitti_camera` (the one
    place that reads KITTI's box convention); this only reorders its corners.

    Args:
        dimensions_hwl: (N, 3) height, width, length in metres.
        location_bottom: (N, 3) bottom centre in the rectified camera.
        rotation_y: (N,) rotation about the camera y axis, radians.
    """
    boxes = Boxes3D.from_kitti_camera(dimensions_hwl, location_bottom, rotation_y, "camera")
    return boxes.corners()[:, list(DEVKIT_CORNERS)]


def oxts_poses(oxts: np.ndarray) -> Transform:
    """``world_T_ego`` (T,) of the IMU/GPS body frame from oxts packets, ``world`` = the first pose.

    Args:
        oxts: (T, >=6) packets: lat (deg), lon (deg), alt (m), roll, pitch, yaw (rad).
    """
    lat, lon, alt = oxts[:, 0], oxts[:, 1], oxts[:, 2]
    scale = np.cos(np.radians(lat[0]))
    translation = np.stack([
        scale * EARTH_RADIUS_M * np.radians(lon),
        scale * EARTH_RADIUS_M * np.log(np.tan(np.radians(90.0 + lat) / 2.0)),
        alt,
    ], axis=1)
    # Extrinsic x-y-z = intrinsic Z-Y-X: R = Rz(yaw) Ry(pitch) Rx(roll), as the devkit composes it.
    mercator_T_ego = Transform.from_euler("xyz", oxts[:, 3:6], translation).orthonormalize()
    return mercator_T_ego[0].inverse() @ mercator_T_ego


def extrapolate_pose(world_T_ego: Transform, packet: np.ndarray, dt_s: float) -> Transform:
    """The pose ``dt_s`` seconds after (or before, if negative) an oxts packet's, at constant body velocity.

    Args:
        world_T_ego: the pose at the packet's time.
        packet: (30,) the oxts packet: vf, vl, vu (m/s) at indices 8-10 and wf, wl, wu (rad/s) at 20-22,
            all in the body axes (x forward, y left, z up).
        dt_s: seconds to move by.
    """
    ego_T_moved = Transform.from_euler("xyz", packet[20:23] * dt_s, packet[8:11] * dt_s)
    return world_T_ego @ ego_T_moved
