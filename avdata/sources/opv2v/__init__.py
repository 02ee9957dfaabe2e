"""OPV2V / V2XSet / V2V4Real: frame files and PCD intensity (``files``), CARLA's poses and boxes (``carla``), classes."""

from avdata.sources.opv2v.carla import boxes_from_carla, boxes_to_carla, carla_pose_matrix, world_T_carla_pose
from avdata.sources.opv2v.classes import CLASS_MAP
from avdata.sources.opv2v.files import (
    UE_T_OPTICAL,
    AgentFrame,
    Camera,
    Vehicles,
    frame_files,
    intensity_from_rgb,
    png_size,
    read_agent_frame,
)

__all__ = [
    "CLASS_MAP",
    "UE_T_OPTICAL",
    "AgentFrame",
    "Camera",
    "Vehicles",
    "boxes_from_carla",
    "boxes_to_carla",
    "carla_pose_matrix",
    "frame_files",
    "intensity_from_rgb",
    "png_size",
    "read_agent_frame",
    "world_T_carla_pose",
]
