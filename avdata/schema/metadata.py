"""Scene metadata that avdata itself writes: its reserved keys, the conventions in force, the primary agent."""

from __future__ import annotations

from typing import Any

#: Scene metadata keys that avdata writes itself.
RESERVED_METADATA = frozenset({"name", "format_version", "writer", "conventions", "agents", "sensors"})

#: The conventions in force, written into every scene's metadata (docs/conventions.md).
CONVENTIONS = {
    "handedness": "right",
    "body_frame": "x forward, y left, z up (REP-103)",
    "camera_frame": "optical: x right, y down, z forward",
    "box": "centre; size (length along box x, width along y, height along z); quaternion (w, x, y, z) of box in frame",
    "yaw": "about z from the reference x axis, counter-clockwise",
    "transform": "FrameTransform gives the child's pose in the parent: p_parent = R p_child + t",
    "time": "int64 nanoseconds",
    "units": "metres, radians, m/s, m/s^2, rad/s",
}


def ego_frame_of(metadata: dict[str, Any]) -> str | None:
    """The primary agent's body frame of a scene's metadata: ``ego`` if present, else the first vehicle, else None."""
    agents = metadata.get("agents", {})
    if "ego" in agents:
        return "ego"
    vehicles = [name for name, spec in agents.items() if spec.get("kind") == "vehicle"]
    return vehicles[0] if vehicles else None
