"""KITTI's file formats (object, tracking, raw), their conventions and devkit formulas, each once.

Readers return columns (numpy arrays) or raise :class:`avdata.errors.InputError` naming the file, the
line and the value; label readers report unreadable lines one by one so that callers lose only those.
Class names meet the unified taxonomy in :mod:`~avdata.sources.kitti.classes`.
Converters (KITTI -> unified), the KITTI exporter and KITTI-style evaluation all use these.
"""

from avdata.sources.kitti.calib import CALIB_KEYS, KittiCalib, format_calib, read_calib, read_raw_calib
from avdata.sources.kitti.classes import CLASS_MAP, KITTI_CLASS_OF_UNIFIED, KITTI_CLASSES, unified_classes
from avdata.sources.kitti.geometry import (
    DEVKIT_CORNERS,
    camera_frame,
    camera_offset,
    compute_box_3d,
    extrapolate_pose,
    intrinsics,
    oxts_poses,
    rigid,
    velo_T_sensors,
)
from avdata.sources.kitti.labels import DONT_CARE, KittiLabels, LabelProblem, read_labels
from avdata.sources.kitti.oxts import read_oxts_file, read_oxts_lines, read_timestamps
from avdata.sources.kitti.sensors import VELODYNE_DTYPE, png_size, read_velodyne, velodyne_problem
from avdata.sources.kitti.tracklets import Tracklets, read_tracklets

__all__ = [
    "CALIB_KEYS",
    "CLASS_MAP",
    "DEVKIT_CORNERS",
    "DONT_CARE",
    "KITTI_CLASSES",
    "KITTI_CLASS_OF_UNIFIED",
    "VELODYNE_DTYPE",
    "KittiCalib",
    "KittiLabels",
    "LabelProblem",
    "Tracklets",
    "camera_frame",
    "camera_offset",
    "compute_box_3d",
    "extrapolate_pose",
    "format_calib",
    "intrinsics",
    "oxts_poses",
    "png_size",
    "read_calib",
    "read_labels",
    "read_oxts_file",
    "read_oxts_lines",
    "read_raw_calib",
    "read_timestamps",
    "read_tracklets",
    "read_velodyne",
    "unified_classes",
    "rigid",
    "velo_T_sensors",
    "velodyne_problem",
]
