"""Argoverse 2 sensor-dataset conventions: categories, sensors, frame names, timing (av2-api 0.3.6).

Frames as AV2 defines them (av2-api ``geometry/se3.py``: ``a_SE3_b`` maps points from b to a, the
same reading as avdata's ``a_T_b``):

- ``city``: the city's map frame (e.g. PIT), z up; ``city_SE3_egovehicle`` gives the ego pose in it.
- ``egovehicle``: x forward, y left, z up, origin at the rear axle centre on the ground.
- cameras: already optical (x right, y down, z forward); ``egovehicle_SE3_sensor`` is their pose.
- lidars: ``up_lidar`` and ``down_lidar`` poses in ``egovehicle_SE3_sensor``; sweeps are stored in the
  *egovehicle* frame at the sweep timestamp, motion-compensated, the two lidars stacked
  (``laser_number`` 0-63 names the beam across both, as stored).
- cuboids: centre ``tx_m ty_m tz_m``, ``length_m width_m height_m`` along the box x, y, z, rotation
  ``qw qx qy qz`` (scalar first), all in the egovehicle frame at the sweep (annotation) time.
"""

from __future__ import annotations

#: Every annotation category of the sensor dataset (av2 ``AnnotationCategories``), verbatim.
ANNOTATION_CATEGORIES: tuple[str, ...] = (
    "ANIMAL",
    "ARTICULATED_BUS",
    "BICYCLE",
    "BICYCLIST",
    "BOLLARD",
    "BOX_TRUCK",
    "BUS",
    "CONSTRUCTION_BARREL",
    "CONSTRUCTION_CONE",
    "DOG",
    "LARGE_VEHICLE",
    "MESSAGE_BOARD_TRAILER",
    "MOBILE_PEDESTRIAN_CROSSING_SIGN",
    "MOTORCYCLE",
    "MOTORCYCLIST",
    "OFFICIAL_SIGNALER",
    "PEDESTRIAN",
    "RAILED_VEHICLE",
    "REGULAR_VEHICLE",
    "SCHOOL_BUS",
    "SIGN",
    "STOP_SIGN",
    "STROLLER",
    "TRAFFIC_LIGHT_TRAILER",
    "TRUCK",
    "TRUCK_CAB",
    "VEHICULAR_TRAILER",
    "WHEELCHAIR",
    "WHEELED_DEVICE",
    "WHEELED_RIDER",
)

#: The 26 categories of the sensor detection competition (av2 ``SensorCompetitionCategories``), in
#: av2's order: the rows of its detection summary.
COMPETITION_CATEGORIES: tuple[str, ...] = (
    "ARTICULATED_BUS",
    "BICYCLE",
    "BICYCLIST",
    "BOLLARD",
    "BOX_TRUCK",
    "BUS",
    "CONSTRUCTION_BARREL",
    "CONSTRUCTION_CONE",
    "DOG",
    "LARGE_VEHICLE",
    "MESSAGE_BOARD_TRAILER",
    "MOBILE_PEDESTRIAN_CROSSING_SIGN",
    "MOTORCYCLE",
    "MOTORCYCLIST",
    "PEDESTRIAN",
    "REGULAR_VEHICLE",
    "SCHOOL_BUS",
    "SIGN",
    "STOP_SIGN",
    "STROLLER",
    "TRUCK",
    "TRUCK_CAB",
    "VEHICULAR_TRAILER",
    "WHEELCHAIR",
    "WHEELED_DEVICE",
    "WHEELED_RIDER",
)

#: AV2 category -> unified class (docs/conventions.md). Riders are the person-on-vehicle classes
#: (``cyclist``); objects without a unified class (signs, strollers, wheelchairs) are ``other``.
CLASS_MAP: dict[str, str] = {
    "ANIMAL": "animal",
    "ARTICULATED_BUS": "bus",
    "BICYCLE": "bicycle",
    "BICYCLIST": "cyclist",
    "BOLLARD": "barrier",
    "BOX_TRUCK": "truck",
    "BUS": "bus",
    "CONSTRUCTION_BARREL": "traffic_cone",
    "CONSTRUCTION_CONE": "traffic_cone",
    "DOG": "animal",
    "LARGE_VEHICLE": "truck",
    "MESSAGE_BOARD_TRAILER": "trailer",
    "MOBILE_PEDESTRIAN_CROSSING_SIGN": "other",
    "MOTORCYCLE": "motorcycle",
    "MOTORCYCLIST": "cyclist",
    "OFFICIAL_SIGNALER": "pedestrian",
    "PEDESTRIAN": "pedestrian",
    "RAILED_VEHICLE": "other",
    "REGULAR_VEHICLE": "car",
    "SCHOOL_BUS": "bus",
    "SIGN": "other",
    "STOP_SIGN": "other",
    "STROLLER": "other",
    "TRAFFIC_LIGHT_TRAILER": "trailer",
    "TRUCK": "truck",
    "TRUCK_CAB": "truck",
    "VEHICULAR_TRAILER": "trailer",
    "WHEELCHAIR": "other",
    "WHEELED_DEVICE": "other",
    "WHEELED_RIDER": "cyclist",
}

#: The seven ring cameras and two stereo cameras (av2 ``RingCameras``, ``StereoCameras``).
RING_CAMERAS: tuple[str, ...] = (
    "ring_rear_left",
    "ring_side_left",
    "ring_front_left",
    "ring_front_center",
    "ring_front_right",
    "ring_side_right",
    "ring_rear_right",
)
STEREO_CAMERAS: tuple[str, ...] = ("stereo_front_left", "stereo_front_right")

#: The two lidars of ``egovehicle_SE3_sensor``; their points arrive stacked in one sweep.
LIDARS: tuple[str, ...] = ("up_lidar", "down_lidar")

#: A camera image belongs to a sweep when it is the nearest one within half a camera period
#: (av2 ``SynchronizationDB.MAX_LIDAR_RING_CAM_TIMESTAMP_DIFF``: 1/20 s / 2 = 25 ms).
MAX_LIDAR_CAM_TIMESTAMP_DIFF_NS = 25_000_000


def unified_class(category: str) -> str:
    """The unified class of an AV2 category (``other`` for a category AV2 does not define)."""
    return CLASS_MAP.get(category, "other")
