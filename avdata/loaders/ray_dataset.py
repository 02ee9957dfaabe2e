"""Frames of a unified dataset as a ``ray.data.Dataset``, for distributed training and preprocessing.

``ray_dataset(root, ...)`` takes :class:`~avdata.loaders.FrameDataset`'s options and gives the same
items as rows in Arrow types (:func:`as_row`), so Ray stores them in its Arrow blocks instead of pickling
them: every array is a tensor column (Ray's tensor extension type: (N, F) clouds and (N, 7) boxes of any
N, read back as numpy arrays), every other value a native Arrow column. Arrow has no column type for a
dict of arrays, so the item's dicts are flattened into one column per entry, named ``<key>.<name>``
(``points.ego/velodyne``, ``images.ego/cam2``, ``calibrations.ego/cam2.K``). A sensor a frame lacks (a rate-
limited agent, a frame whose scan is missing) has an empty array in that row ((0, F), same dtype) and
``None`` in its non-array columns (``sensor_timestamps_ns.<sensor>`` tells which sensors a frame had):
Arrow's tensor columns hold no nulls. The columns are filled within a scene (its read task); a scene that
never has a sensor another scene has gives a block without that column. Rows (``take``, ``iter_rows``) read
such blocks, but Ray cannot batch a tensor column across them (``iter_batches`` fails converting the nulls it
fills in): to batch across such scenes, name the sensors every scene has (``sensors=``).

It is built with one read task per scene file: the scenes are the blocks of a small source dataset, and
each task opens its scene once and yields that scene's rows in frame order. Workers read the scene files
from their paths, so every Ray node must see the dataset folder at the same path (a shared filesystem), or
the dataset is in an object store (``s3://bucket/prefix``, ``gs://...``): then each task reads its scene by
ranged requests, with the credentials and endpoint of its node's own environment (a task carries the URI,
never a credential).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from avdata.errors import AvdataError
from avdata.loaders.frame_dataset import FrameDataset
from avdata.storage import Location

if TYPE_CHECKING:
    import ray.data


def as_row(item: dict[str, Any]) -> dict[str, Any]:
    """A FrameDataset item as one row of Arrow-typed values: numpy arrays, scalars, strings and lists of them.

    Nested dicts become columns ``<key>.<name>`` (``calibrations.ego/cam2.K``); tuples (``point_fields``)
    become lists.
    """
    row: dict[str, Any] = {}

    def put(prefix: str, value: Any) -> None:
        if isinstance(value, dict):
            for name, inner in value.items():
                put(f"{prefix}.{name}", inner)
        elif isinstance(value, torch.Tensor):
            row[prefix] = value.numpy().copy()
        elif isinstance(value, tuple):
            row[prefix] = list(value)
        else:
            row[prefix] = value

    for key, value in item.items():
        put(key, value)
    return row


def fill_missing(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The rows with the union of their columns: an array a row lacks is empty ((0, ...), same dtype), else None."""
    columns: dict[str, Any] = {}
    for row in rows:
        for name, value in row.items():
            columns.setdefault(name, value)
    empty = {name: np.zeros((0, *value.shape[1:]), dtype=value.dtype) if isinstance(value, np.ndarray) else None
             for name, value in columns.items()}
    return [{name: row.get(name, empty[name]) for name in columns} for row in rows]


class _ReadScene:
    """The read task of one scene: every row of that scene, in frame order."""

    def __init__(self, frames: FrameDataset):
        self.frames = frames

    def __call__(self, row: dict[str, Any]) -> list[dict[str, Any]]:
        scene = str(row["scene"])
        return fill_missing([as_row(self.frames.item(scene, frame_index)) for frame_index in row["frame_indices"]])


def ray_dataset(root: str | Path | Location, **options: Any) -> ray.data.Dataset:
    """A Ray Dataset of the frame items of dataset ``root``, one read task per scene.

    Args:
        root: the unified dataset folder (on a filesystem every Ray node sees at this path), or its prefix in an
            object store (``s3://bucket/prefix``, ``gs://...``).
        **options: as for :class:`~avdata.loaders.FrameDataset` (sensors, frame, classes, agents, ...).

    Returns:
        A ``ray.data.Dataset`` whose rows are FrameDataset items as :func:`as_row` flattens them (in frame
        order within a scene; Ray Data may interleave scenes unless its ``preserve_order`` execution option
        is set).

    Raises:
        AvdataError: Ray is not installed, or an option is invalid (checked here, before any task runs).
    """
    try:
        import ray.data
    except ImportError as error:
        raise AvdataError("ray_dataset: expected Ray to be installed (pip install 'avdata[ray]'), got none") from error
    frames = FrameDataset(root, **options)
    per_scene: dict[str, list[int]] = {}
    for scene, frame_index in frames.keys():
        per_scene.setdefault(scene, []).append(frame_index)
    rows = [{"scene": scene, "frame_indices": indices} for scene, indices in per_scene.items()]
    source = ray.data.from_items(rows, override_num_blocks=max(1, len(rows)))
    return source.flat_map(_ReadScene(frames))
