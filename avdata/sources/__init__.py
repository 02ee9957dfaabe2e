"""One home per source dataset format.

Each sub-package (``kitti``, ``nuscenes``, ``argoverse2``, ``waymo``, ``opv2v``, ``dair_v2x`` …) holds
that format's file readers and writers, its conventions and its devkit formulas, each exactly once.
Converters (source -> unified), exporters (unified -> source) and eval (source-format results) import
from here; nothing here imports converters, exporters, loaders or eval. Format-independent readers
shared by several sources (PCD) live beside the sub-packages. The checks of point values read from files
without a checksum are public here, for converters that build clouds themselves (Waymo's range images).
"""

from avdata.sources._checks import coordinates_problem, point_values_problem

__all__ = ["coordinates_problem", "point_values_problem"]
