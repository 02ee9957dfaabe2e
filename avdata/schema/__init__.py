"""The unified on-disk format: label records, MCAP scene writer/reader, Parquet index, dataset.

The names below load their module on first use (PEP 562), so a command that only reads a manifest and
scene summaries (``avdata info``) does not import the Parquet stack that the dataset writer and index need.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from avdata.schema.dataset import DatasetReader, DatasetWriter, build_index
    from avdata.schema.manifest import scene_path
    from avdata.schema.records import UNIFIED_CLASSES, FrameInfo, ObjectLabels, VisibilityLabels
    from avdata.schema.scene_reader import SceneReader, decode_points, scene_metadata
    from avdata.schema.scene_writer import SceneWriter
    from avdata.schema.topics import FORMAT_VERSION

#: Public name -> the module that defines it.
_HOMES = {
    "DatasetReader": "avdata.schema.dataset",
    "DatasetWriter": "avdata.schema.dataset",
    "build_index": "avdata.schema.dataset",
    "scene_path": "avdata.schema.manifest",
    "UNIFIED_CLASSES": "avdata.schema.records",
    "FrameInfo": "avdata.schema.records",
    "ObjectLabels": "avdata.schema.records",
    "VisibilityLabels": "avdata.schema.records",
    "SceneReader": "avdata.schema.scene_reader",
    "decode_points": "avdata.schema.scene_reader",
    "scene_metadata": "avdata.schema.scene_reader",
    "SceneWriter": "avdata.schema.scene_writer",
    "FORMAT_VERSION": "avdata.schema.topics",
}

__all__ = [
    "FORMAT_VERSION",
    "UNIFIED_CLASSES",
    "DatasetReader",
    "DatasetWriter",
    "FrameInfo",
    "ObjectLabels",
    "SceneReader",
    "SceneWriter",
    "VisibilityLabels",
    "build_index",
    "decode_points",
    "scene_metadata",
    "scene_path",
]


def __getattr__(name: str) -> Any:
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(home), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
