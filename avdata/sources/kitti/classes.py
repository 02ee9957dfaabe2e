"""KITTI class names and the unified taxonomy, both ways."""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

import numpy as np

__all__ = ["CLASS_MAP", "KITTI_CLASSES", "KITTI_CLASS_OF_UNIFIED", "unified_classes"]

#: KITTI class -> unified class. Van goes with car (as nuScenes and most detectors merge them) and
#: Person_sitting with pedestrian; the KITTI string stays beside it as ``source_class``, so a
#: KITTI-style evaluation can still treat Van and Person_sitting as KITTI's "neighbouring" classes.
#: ``Person`` is the raw tracklets' name for a pedestrian.
CLASS_MAP: Mapping[str, str] = MappingProxyType({
    "Car": "car",
    "Van": "car",
    "Truck": "truck",
    "Pedestrian": "pedestrian",
    "Person_sitting": "pedestrian",
    "Person": "pedestrian",
    "Cyclist": "cyclist",
    "Tram": "other",
    "Misc": "other",
})

#: The KITTI object benchmark's classes (label_2 ``type``, DontCare aside): written verbatim when exporting a
#: KITTI source.
KITTI_CLASSES = frozenset({"Car", "Van", "Truck", "Pedestrian", "Person_sitting", "Cyclist", "Tram", "Misc"})

#: Unified class -> the KITTI class an exporter writes for it; other unified classes are capitalised.
KITTI_CLASS_OF_UNIFIED: Mapping[str, str] = MappingProxyType(
    {"car": "Car", "truck": "Truck", "pedestrian": "Pedestrian", "cyclist": "Cyclist"})


def unified_classes(kitti_classes: np.ndarray) -> np.ndarray:
    """(N,) unified classes of (N,) KITTI classes; unknown ones become ``other``."""
    return np.array([CLASS_MAP.get(c, "other") for c in kitti_classes.tolist()], dtype=str)
