"""nuScenes-schema category names and the unified taxonomy, each mapping once.

Three readers of the same names want three different things:

* a converter keeps every annotation: :func:`unified_class` maps any nuScenes or Lyft category (by the
  longest dotted prefix listed in :data:`CLASS_MAP`) and calls the rest ``other``;
* nuScenes-style evaluation keeps only the devkit's detection categories (``category_to_detection_name``):
  :data:`CATEGORY_TO_CLASS`, those categories through the same :data:`CLASS_MAP`;
* an exporter writes a unified class back as one nuScenes leaf category: :data:`CATEGORY_OF_CLASS`.
  It is lossy where the taxonomies differ (``cyclist`` is written as ``vehicle.bicycle``, ``other`` as
  ``movable_object.debris``).
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

__all__ = ["ATTRIBUTES", "CATEGORY_OF_CLASS", "CATEGORY_TO_CLASS", "CLASS_MAP", "DETECTION_CATEGORIES", "DETECTION_NAMES",
           "unified_class"]

#: nuScenes and Lyft category name -> unified class. nuScenes names are matched by the longest
#: dotted prefix (``vehicle.bus.rigid`` -> ``vehicle.bus``); Lyft's flat names are listed verbatim.
CLASS_MAP: Mapping[str, str] = MappingProxyType({
    "vehicle.car": "car",
    "vehicle.truck": "truck",
    "vehicle.bus": "bus",
    "vehicle.trailer": "trailer",
    "vehicle.construction": "construction_vehicle",
    "vehicle.motorcycle": "motorcycle",
    "vehicle.bicycle": "bicycle",
    "human.pedestrian": "pedestrian",
    "movable_object.trafficcone": "traffic_cone",
    "movable_object.barrier": "barrier",
    "animal": "animal",
    # Lyft Level 5
    "car": "car",
    "truck": "truck",
    "bus": "bus",
    "pedestrian": "pedestrian",
    "bicycle": "bicycle",
    "motorcycle": "motorcycle",
    "emergency_vehicle": "other",
    "other_vehicle": "other",
})


def unified_class(category: str) -> str:
    """The unified class of a nuScenes or Lyft category name (``other`` when unmapped)."""
    name = category
    while name:
        if name in CLASS_MAP:
            return CLASS_MAP[name]
        name = name.rpartition(".")[0]
    return "other"


#: The categories the nuScenes detection and tracking benchmarks evaluate (the devkit's
#: ``category_to_detection_name``); wheelchairs, strollers, personal mobility, animals, emergency
#: vehicles and static objects are not among them.
DETECTION_CATEGORIES = (
    "movable_object.barrier",
    "vehicle.bicycle",
    "vehicle.bus.bendy",
    "vehicle.bus.rigid",
    "vehicle.car",
    "vehicle.construction",
    "vehicle.motorcycle",
    "human.pedestrian.adult",
    "human.pedestrian.child",
    "human.pedestrian.construction_worker",
    "human.pedestrian.police_officer",
    "movable_object.trafficcone",
    "vehicle.trailer",
    "vehicle.truck",
)
#: The 10 classes of the nuScenes detection and tracking challenges, in the devkit's order (each is also a unified
#: class name): the ``detection_name`` of a submission.
DETECTION_NAMES = ("car", "truck", "bus", "trailer", "construction_vehicle", "pedestrian", "motorcycle", "bicycle",
                   "traffic_cone", "barrier")
#: The 8 nuScenes attributes, in the order an exporter writes its ``attribute`` table.
ATTRIBUTES = ("vehicle.moving", "vehicle.stopped", "vehicle.parked", "cycle.with_rider", "cycle.without_rider",
              "pedestrian.sitting_lying_down", "pedestrian.standing", "pedestrian.moving")
#: Benchmark category -> its detection class (a unified class); other categories are not evaluated.
CATEGORY_TO_CLASS: Mapping[str, str] = MappingProxyType({name: unified_class(name) for name in DETECTION_CATEGORIES})

#: Unified class -> the nuScenes leaf category an exporter writes for it.
CATEGORY_OF_CLASS: Mapping[str, str] = MappingProxyType({
    "car": "vehicle.car", "truck": "vehicle.truck", "bus": "vehicle.bus.rigid", "trailer": "vehicle.trailer",
    "construction_vehicle": "vehicle.construction", "pedestrian": "human.pedestrian.adult",
    "cyclist": "vehicle.bicycle", "motorcycle": "vehicle.motorcycle", "bicycle": "vehicle.bicycle",
    "traffic_cone": "movable_object.trafficcone", "barrier": "movable_object.barrier", "animal": "animal",
    "other": "movable_object.debris",
})
