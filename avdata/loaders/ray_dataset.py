"""Frames of a unified dataset as a ``ray.data.Dataset``, for distributed training and preprocessing.

``ray_dataset(root, ...)`` takes :class:`~avdata.loaders.FrameDataset`'s options and gives the same
items (the same keys and values), with numpy arrays instead of torch tensors. It is built with one read
task per scene file: the scenes are the blocks of a small source dataset, and each task opens its
scene once and yields that scene's items in frame order. Workers read the scene files from their paths,
so every Ray node must see the dataset folder at the same path (a shared filesystem).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from avdata.errors import AvdataError
from avdata.loaders.frame_dataset import FrameDataset

if TYPE_CHECKING:
    import ray.data


def as_numpy(value: Any) -> Any:
    """``value`` with every tensor (in dicts, lists and tuples) turned into a numpy array of its own."""
    if isinstance(value, torch.Tensor):
        return value.numpy().copy()
    if isinstance(value, dict):
        return {key: as_numpy(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return type(value)(as_numpy(item) for item in value)
    return value


class _ReadScene:
    """The read task of one scene: every item of that scene, in frame order."""

    def __init__(self, frames: FrameDataset):
        self.frames = frames

    def __call__(self, row: dict[str, Any]) -> list[dict[str, Any]]:
        scene = str(row["scene"])
        return [as_numpy(self.frames.item(scene, frame_index)) for frame_index in row["frame_indices"]]


def ray_dataset(root: str | Path, **options: Any) -> ray.data.Dataset:
    """A Ray Dataset of the frame items of dataset ``root``, one read task per scene.

    Args:
        root: the unified dataset folder (on a filesystem every Ray node sees at this path).
        **options: as for :class:`~avdata.loaders.FrameDataset` (sensors, frame, classes, agents, ...).

    Returns:
        A ``ray.data.Dataset`` whose rows are FrameDataset items with numpy arrays (in frame order within
        a scene; Ray Data may interleave scenes unless its ``preserve_order`` execution option is set).

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
