"""The nuScenes schema (nuScenes, Lyft Level 5, V2X-Sim): tables, sensor files and devkit formulas, each once.

Tables are stream-parsed without nuscenes-devkit (:class:`NuScenesTables`); timestamps become int64 ns
exactly, Lyft's float microseconds included (:func:`us_to_ns`); :func:`box_velocity` is the devkit's
formula; category names meet the unified taxonomy in :mod:`~avdata.sources.nuscenes.categories`. The
converter (nuScenes -> unified), the nuScenes exporter and nuScenes-style evaluation use these.
"""

from avdata.sources.nuscenes.categories import CATEGORY_OF_CLASS, CATEGORY_TO_CLASS, CLASS_MAP, unified_class
from avdata.sources.nuscenes.files import read_lidar_bin
from avdata.sources.nuscenes.formulas import MAX_VELOCITY_TIME_DIFF_S, box_velocity
from avdata.sources.nuscenes.jsonio import iter_json_array, iter_json_chunks, us_to_ns
from avdata.sources.nuscenes.tables import DANGLING, REQUIRED_TABLES, NuScenesTables, SampleDataRow

__all__ = [
    "CATEGORY_OF_CLASS",
    "CATEGORY_TO_CLASS",
    "CLASS_MAP",
    "DANGLING",
    "MAX_VELOCITY_TIME_DIFF_S",
    "REQUIRED_TABLES",
    "NuScenesTables",
    "SampleDataRow",
    "box_velocity",
    "iter_json_array",
    "iter_json_chunks",
    "read_lidar_bin",
    "unified_class",
    "us_to_ns",
]
