"""Rigid transforms, the frame graph, axis conventions and frame-aware boxes (no I/O)."""

from avdata.frames.boxes import Boxes3D
from avdata.frames.conventions import RH_T_CARLA, XFWD_T_OPTICAL, carla_rotation_matrix
from avdata.frames.graph import FrameGraph, StampedEdge
from avdata.frames.rotations import RepairWarning, normalize_quat_checked, orthonormalize_checked
from avdata.frames.transform import Transform

__all__ = [
    "Boxes3D",
    "FrameGraph",
    "RH_T_CARLA",
    "RepairWarning",
    "StampedEdge",
    "Transform",
    "XFWD_T_OPTICAL",
    "carla_rotation_matrix",
    "normalize_quat_checked",
    "orthonormalize_checked",
]
