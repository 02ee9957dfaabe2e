"""Argoverse 2 sensor dataset: its file readers, conventions and the ROI raster of its maps (once).

``files`` reads the log folder (feather tables, sweeps, image names), ``conventions`` holds the
categories, sensors and timing constants, ``roi`` builds the region-of-interest raster av2's
detection evaluation filters with. The converter (``avdata.converters.argoverse2``) and the av2
detection protocol (``avdata.eval.detection.av2``) import from here.
"""

from avdata.sources.argoverse2.conventions import (
    ANNOTATION_CATEGORIES,
    CLASS_MAP,
    COMPETITION_CATEGORIES,
    LIDARS,
    MAX_LIDAR_CAM_TIMESTAMP_DIFF_NS,
    RING_CAMERAS,
    STEREO_CAMERAS,
    unified_class,
)
from avdata.sources.argoverse2.files import (
    Intrinsics,
    Rows,
    city_name,
    read_annotations,
    read_columns,
    read_intrinsics,
    read_poses,
    read_sensor_poses,
    read_sweep,
    read_table,
    timestamp_files,
)
from avdata.sources.argoverse2.roi import RoiRaster, log_roi, roi_raster

__all__ = [
    "ANNOTATION_CATEGORIES",
    "CLASS_MAP",
    "COMPETITION_CATEGORIES",
    "Intrinsics",
    "LIDARS",
    "MAX_LIDAR_CAM_TIMESTAMP_DIFF_NS",
    "RING_CAMERAS",
    "RoiRaster",
    "Rows",
    "STEREO_CAMERAS",
    "city_name",
    "log_roi",
    "read_annotations",
    "read_columns",
    "read_intrinsics",
    "read_poses",
    "read_sensor_poses",
    "read_sweep",
    "read_table",
    "roi_raster",
    "timestamp_files",
    "unified_class",
]
