"""OPV2V / V2XSet / V2V4Real: frame files, PCD intensity and OpenCOOD's pose and box formulas (see ``files``)."""

from avdata.sources.opv2v.files import (
    UE_T_OPTICAL,
    AgentFrame,
    Camera,
    Vehicles,
    carla_pose_matrix,
    frame_files,
    intensity_from_rgb,
    png_size,
    read_agent_frame,
    world_T_carla_pose,
)

__all__ = [
    "UE_T_OPTICAL",
    "AgentFrame",
    "Camera",
    "Vehicles",
    "carla_pose_matrix",
    "frame_files",
    "intensity_from_rgb",
    "png_size",
    "read_agent_frame",
    "world_T_carla_pose",
]
