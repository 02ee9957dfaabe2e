"""The nuScenes category tables (avdata.sources.nuscenes.categories) against the real v1.0-mini categories."""

from __future__ import annotations

import json

from avdata.sources.nuscenes import CATEGORY_OF_CLASS, CATEGORY_TO_CLASS, unified_class
from tests.realdata import REALDATA

MINI_CATEGORIES = REALDATA / "nuscenes" / "v1.0-mini" / "category.json"
#: The devkit's ``category_to_detection_name`` (nuscenes/eval/detection/utils.py), written out by hand.
DEVKIT_DETECTION_NAME = {
    "movable_object.barrier": "barrier",
    "vehicle.bicycle": "bicycle",
    "vehicle.bus.bendy": "bus",
    "vehicle.bus.rigid": "bus",
    "vehicle.car": "car",
    "vehicle.construction": "construction_vehicle",
    "vehicle.motorcycle": "motorcycle",
    "human.pedestrian.adult": "pedestrian",
    "human.pedestrian.child": "pedestrian",
    "human.pedestrian.construction_worker": "pedestrian",
    "human.pedestrian.police_officer": "pedestrian",
    "movable_object.trafficcone": "traffic_cone",
    "vehicle.trailer": "trailer",
    "vehicle.truck": "truck",
}


def test_class_map() -> None:
    cases = {
        "vehicle.bus.bendy": "bus",
        "human.pedestrian.police_officer": "pedestrian",
        "vehicle.construction": "construction_vehicle",
        "movable_object.trafficcone": "traffic_cone",
        "static_object.bicycle_rack": "other",
        "vehicle.emergency.police": "other",
        "emergency_vehicle": "other",
        "other_vehicle": "other",
        "animal": "animal",
        "car": "car",
    }
    assert {name: unified_class(name) for name in cases} == cases


def test_detection_classes_are_the_devkits() -> None:
    assert dict(CATEGORY_TO_CLASS) == DEVKIT_DETECTION_NAME


def test_every_real_category_has_a_class_and_every_class_a_real_category() -> None:
    real = {row["name"] for row in json.loads(MINI_CATEGORIES.read_text())}
    assert set(CATEGORY_TO_CLASS) <= real
    assert set(CATEGORY_OF_CLASS.values()) <= real
    assert {unified_class(name) for name in real} == {
        "animal", "barrier", "bicycle", "bus", "car", "construction_vehicle", "motorcycle", "other", "pedestrian",
        "traffic_cone", "trailer", "truck"}


def test_exported_category_converts_back_to_its_class_where_the_taxonomies_agree() -> None:
    lossy = {"cyclist": "bicycle"}  # nuScenes has no rider class: a cyclist is written as its bicycle
    assert {c: unified_class(name) for c, name in CATEGORY_OF_CLASS.items()} == {c: lossy.get(c, c) for c in CATEGORY_OF_CLASS}
