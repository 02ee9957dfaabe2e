"""OPV2V / V2V4Real object types and the unified taxonomy."""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

__all__ = ["CLASS_MAP"]

#: V2V4Real ``obj_type`` (lower case) -> unified class; OPV2V has cars only ("Car").
CLASS_MAP: Mapping[str, str] = MappingProxyType({
    "car": "car", "van": "car", "truck": "truck", "concretetruck": "truck", "bus": "bus",
    "pedestrian": "pedestrian", "bicyclerider": "cyclist", "scooterrider": "motorcycle", "scooter": "motorcycle",
})
