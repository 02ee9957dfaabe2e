"""One home per source dataset format.

Each sub-package (``kitti``, ``nuscenes``, ``argoverse2``, ``waymo``, ``opv2v``, ``dair_v2x`` …) holds
that format's file readers and writers, its conventions and its devkit formulas, each exactly once.
Converters (source -> unified), exporters (unified -> source) and eval (source-format results) import
from here; nothing here imports converters, exporters, loaders or eval. Format-independent readers
shared by several sources (PCD) live beside the sub-packages.
"""
