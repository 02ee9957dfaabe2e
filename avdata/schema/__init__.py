"""The unified on-disk format: label records, MCAP scene writer/reader, Parquet index, dataset."""

from avdata.schema.dataset import DatasetReader, DatasetWriter, build_index, scene_path
from avdata.schema.records import UNIFIED_CLASSES, FrameInfo, ObjectLabels, VisibilityLabels
from avdata.schema.scene_reader import SceneReader, decode_points, scene_metadata
from avdata.schema.scene_writer import SceneWriter
from avdata.schema.topics import FORMAT_VERSION

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
