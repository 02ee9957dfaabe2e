"""KITTI converters: 3D object, tracking and raw, each in its published folder layout.

docs/conventions.md rows of KITTI:

- KITTI object: labels in rectified camera 0 (x right, y down, z forward); box origin bottom centre;
  size h, w, l; ``rotation_y`` about camera Y. rect = R0_rect·Tr_velo_to_cam; P2/P3 carry a baseline
  in their 4th column (t_x = P[0,3]/P[0,0]); occluded 0–3, truncated 0–1.
- KITTI tracking: as KITTI object, per frame, with ``track_id``. Calib key names differ (``R_rect``,
  ``Tr_velo_cam``, ``Tr_imu_velo``); truncation is an integer 0/1/2.
- KITTI raw: IMU/GPS (oxts) poses, tracklets in the velodyne frame (bottom centre, h, w, l, yaw).
  oxts yaw 0 = east, counter-clockwise; Mercator scale from the first frame's latitude.

Frame tree written by all three (``ego`` is the body frame; what it is differs, see each module):
``world -> ego -> ego/velodyne, ego/cam0_unrectified, ego/cam0..cam3`` (rectified, optical), and
``ego/imu`` for KITTI object. Boxes are stored in ``world``; camera-2 truncation, occlusion, alpha and
2D box are camera-2 visibility labels, DontCare regions its ignore regions.
"""

from avdata.converters.kitti.object import KittiObjectConverter
from avdata.converters.kitti.raw import KittiRawConverter
from avdata.converters.kitti.tracking import KittiTrackingConverter

__all__ = ["KittiObjectConverter", "KittiRawConverter", "KittiTrackingConverter"]
