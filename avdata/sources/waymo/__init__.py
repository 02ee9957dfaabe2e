"""Waymo Open Dataset v2 (Parquet components): component files, range images, box and camera conventions.

Read with pyarrow only (no TensorFlow): :mod:`.components` locates and reads ``<component>/<context>.parquet``
files, :mod:`.lidar` turns range images into points with Waymo's formulas.
"""

from avdata.sources.waymo.components import (
    BOX_TYPES,
    CAMERA_NAMES,
    CLASS_MAP,
    COMPONENTS,
    LASER_NAMES,
    ComponentFile,
    find_component_files,
    read_component,
)
from avdata.sources.waymo.lidar import (
    beam_inclinations,
    range_image_points,
    range_image_points_lidar,
    rotation_from_roll_pitch_yaw,
)

__all__ = [
    "BOX_TYPES",
    "CAMERA_NAMES",
    "CLASS_MAP",
    "COMPONENTS",
    "LASER_NAMES",
    "ComponentFile",
    "beam_inclinations",
    "find_component_files",
    "range_image_points",
    "range_image_points_lidar",
    "read_component",
    "rotation_from_roll_pitch_yaw",
]
