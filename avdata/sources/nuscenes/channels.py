"""nuScenes channel names for unified sensor frames, as nuScenes-based tools expect them.

nuScenes names each sensor by a channel (``LIDAR_TOP``, ``CAM_FRONT``, ...), and the tools built on it look
channels up by those names: the devkit's renderers and ``nuscenes.eval`` take the ego pose of the sample's
``LIDAR_TOP`` key frame, mmdetection3d's ``create_data.py nuscenes`` reads ``sample["data"]["LIDAR_TOP"]`` and the
six ``CAM_*`` channels of every sample, OpenPCDet's ``nuscenes_dataset`` the same ``LIDAR_TOP``. An export must
therefore name the ego's sensors that have a nuScenes equivalent by that equivalent, whatever the source called
them. :data:`EGO_CHANNELS` holds the equivalents of the sensor names avdata's converters and generator write
(the part after ``<agent>/``):

=======================  ======================================================================================
channel                  ego sensors
=======================  ======================================================================================
``LIDAR_TOP``            ``lidar_top`` (nuScenes, Waymo's TOP lidar, generated), ``velodyne`` (KITTI),
                         ``lidar`` (Argoverse 2's two stacked roof lidars as one, DAIR-V2X vehicle, OPV2V)
``CAM_FRONT``            ``cam_front`` (nuScenes, Waymo, generated), ``cam2`` (KITTI left colour camera),
                         ``ring_front_center`` (Argoverse 2)
``CAM_FRONT_LEFT``       ``cam_front_left``, ``ring_front_left``
``CAM_FRONT_RIGHT``      ``cam_front_right``, ``ring_front_right``
``CAM_BACK``             ``cam_back``
``CAM_BACK_LEFT``        ``cam_back_left``, ``ring_rear_left``
``CAM_BACK_RIGHT``       ``cam_back_right``, ``ring_rear_right``
=======================  ======================================================================================

Any other sensor keeps its own name, upper-case: an ego sensor without an equivalent by its name (KITTI's
``cam3`` -> ``CAM3``, Waymo's ``cam_side_left`` -> ``CAM_SIDE_LEFT``), another agent's with the agent in front
(``infra_03/lidar`` -> ``INFRA_03_LIDAR``), since nuScenes has no channel for sensors off the ego vehicle.
``overrides`` (sensor frame -> channel) replace any of these for one export.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping

from avdata.errors import AvdataError

#: The channels of the nuScenes sensor rig.
NUSCENES_CHANNELS = ("LIDAR_TOP", "CAM_FRONT", "CAM_FRONT_LEFT", "CAM_FRONT_RIGHT", "CAM_BACK", "CAM_BACK_LEFT",
                     "CAM_BACK_RIGHT", "RADAR_FRONT", "RADAR_FRONT_LEFT", "RADAR_FRONT_RIGHT", "RADAR_BACK_LEFT",
                     "RADAR_BACK_RIGHT")

#: Ego sensor name (without the agent) -> its nuScenes channel (module docstring: which source writes which).
EGO_CHANNELS: Mapping[str, str] = {
    "lidar_top": "LIDAR_TOP", "velodyne": "LIDAR_TOP", "lidar": "LIDAR_TOP",
    "cam_front": "CAM_FRONT", "cam2": "CAM_FRONT", "ring_front_center": "CAM_FRONT",
    "cam_front_left": "CAM_FRONT_LEFT", "ring_front_left": "CAM_FRONT_LEFT",
    "cam_front_right": "CAM_FRONT_RIGHT", "ring_front_right": "CAM_FRONT_RIGHT",
    "cam_back": "CAM_BACK",
    "cam_back_left": "CAM_BACK_LEFT", "ring_rear_left": "CAM_BACK_LEFT",
    "cam_back_right": "CAM_BACK_RIGHT", "ring_rear_right": "CAM_BACK_RIGHT",
}

#: A channel becomes a folder name (``samples/<CHANNEL>/``) and a file name part.
_CHANNEL_NAME = re.compile(r"[A-Z0-9_]+")


def own_channel(sensor: str, ego: str) -> str:
    """The channel a sensor frame gets by its own name: ``ego/cam3`` -> ``CAM3``, ``infra_03/lidar`` -> ``INFRA_03_LIDAR``."""
    agent, name = sensor.split("/", 1)
    return (name if agent == ego else f"{agent}_{name}").upper().replace("/", "_")


def check_overrides(overrides: Mapping[str, str]) -> dict[str, str]:
    """``overrides`` (sensor frame -> channel) checked: sensor frames ``<agent>/<name>``, channels of A-Z, 0-9, _.

    Raises:
        AvdataError: a sensor frame or a channel name is malformed.
    """
    checked = {}
    for sensor, channel in overrides.items():
        if not isinstance(sensor, str) or "/" not in sensor.strip("/"):
            raise AvdataError(f"channel mapping: expected a sensor frame such as 'ego/cam3', got {sensor!r}")
        if not isinstance(channel, str) or not _CHANNEL_NAME.fullmatch(channel):
            raise AvdataError(f"channel mapping for {sensor}: expected a channel of A-Z, 0-9 and _ such as "
                              f"'CAM_FRONT_RIGHT', got {channel!r}")
        checked[sensor] = channel
    return checked


def channel_map(sensors: Iterable[str], ego: str, overrides: Mapping[str, str] | None = None) -> dict[str, str]:
    """Sensor frame -> nuScenes channel for the sensors of one scene.

    Args:
        sensors: the scene's sensor frames (``ego/velodyne``, ``infra_00/lidar``).
        ego: the scene's ego agent.
        overrides: sensor frame -> channel, applied before :data:`EGO_CHANNELS` (checked with
            :func:`check_overrides`).

    Raises:
        AvdataError: two sensors of the scene would get the same channel (name one of them in ``overrides``).
    """
    overrides = check_overrides(overrides or {})
    channels: dict[str, str] = {}
    for sensor in sorted(sensors):
        agent, name = sensor.split("/", 1)
        if sensor in overrides:
            channels[sensor] = overrides[sensor]
        elif agent == ego and name in EGO_CHANNELS:
            channels[sensor] = EGO_CHANNELS[name]
        else:
            channels[sensor] = own_channel(sensor, ego)
    by_channel: dict[str, list[str]] = {}
    for sensor, channel in channels.items():
        by_channel.setdefault(channel, []).append(sensor)
    shared = {channel: names for channel, names in by_channel.items() if len(names) > 1}
    if shared:
        channel, names = next(iter(shared.items()))
        raise AvdataError(f"channel {channel}: expected one sensor per channel, got {names} (map one of them to "
                          f"another channel, e.g. --channel {names[-1]}=<CHANNEL>)")
    return channels
