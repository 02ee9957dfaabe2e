"""``SequenceDataset``: windows of consecutive frames for tracking and prediction.

A window is ``past_frames`` observed frames followed by ``future_frames`` frames, consecutive
frame indices of one scene. Everything is expressed in the requested ``frame`` (default the ego)
at the time of the last observed frame, ``t_obs``: the observed frames' points and boxes (moved
through ``world``, so ego motion is compensated) and the trajectories.

An item is a dict:

=======================  ==========================================================================
``scene``                scene name; ``frame_indices`` (T,) and ``timestamps_ns`` (T,) int64, T = P + F
``frame``, ``timestamp_ns``  the reference frame name and ``t_obs``
``frames``               P FrameDataset items of the observed frames, all in ``frame`` at ``t_obs``
``object_ids``           the M objects kept by the label filters at the last observed frame
``object_labels``        (M,) int64 class indices
``past``                 (M, P, 4) float32 x, y, z, yaw of each object at each observed frame
                         (the last one is the present); ``past_valid`` (M, P) bool where labelled
``future``               (M, F, 4) float32 the same over the future frames; ``future_valid`` (M, F)
=======================  ==========================================================================
"""

from __future__ import annotations

import operator
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from avdata.errors import AvdataError
from avdata.frames import Boxes3D, Transform
from avdata.loaders.frame_dataset import FrameDataset
from avdata.loaders.options import FrameOptions


class SequenceDataset(Dataset[dict[str, Any]]):
    """Windows of ``past_frames + future_frames`` consecutive frames (see the module docstring).

    Args:
        root: the dataset folder.
        options: what each observed frame holds, as for :class:`FrameDataset` (None: the ego's
            point clouds and every class, in the ego frame); its label filter chooses the objects
            at the present frame.
        past_frames: P >= 1 observed frames, the last one being the present.
        future_frames: F >= 0 frames after the present.
        stride: frames between the starts of consecutive windows.
        sensors: shortcut for ``options.sensors`` (``[]`` for trajectories and labels only).
        frame: shortcut for ``options.frame``.
        classes: shortcut for ``options.labels.classes``.
        agents: shortcut for ``options.collaboration.agents``.
        with_velocity: shortcut for ``options.with_velocity``.
        with_quaternions: shortcut for ``options.with_quaternions``.
        scenes: restrict to these scene names.
        split: restrict to frames of this split.
        annotated_only: use only frames whose objects were labelled.
    """

    def __init__(
        self,
        root: str | Path,
        options: FrameOptions | None = None,
        *,
        past_frames: int,
        future_frames: int = 0,
        stride: int = 1,
        sensors: str | Sequence[str] | None = None,
        frame: str | None = None,
        classes: Sequence[str] | None = None,
        agents: str | Sequence[str] | None = None,
        with_velocity: bool | None = None,
        with_quaternions: bool | None = None,
        scenes: Sequence[str] | None = None,
        split: str | None = None,
        annotated_only: bool = True,
    ):
        counts = (past_frames, future_frames, stride)
        if (not all(isinstance(n, (int, np.integer)) and not isinstance(n, bool) for n in counts)
                or past_frames < 1 or future_frames < 0 or stride < 1):
            raise AvdataError(f"expected past_frames >= 1, future_frames >= 0, stride >= 1, got {past_frames}, "
                              f"{future_frames}, {stride}")
        self.past_frames = past_frames
        self.future_frames = future_frames
        self.frames = FrameDataset(root, options, sensors=sensors, frame=frame, classes=classes, agents=agents,
                                   with_velocity=with_velocity, with_quaternions=with_quaternions, scenes=scenes,
                                   split=split, annotated_only=annotated_only)
        keys = self.frames.keys()
        length = past_frames + future_frames
        key_scenes = np.array([k[0] for k in keys], dtype=str)
        indices = np.array([k[1] for k in keys], dtype=np.int64)
        consecutive = np.zeros(len(keys), dtype=bool)
        consecutive[1:] = (key_scenes[1:] == key_scenes[:-1]) & (indices[1:] == indices[:-1] + 1)
        # a window starting at i needs the next length-1 frames to be consecutive with it
        run = np.zeros(len(keys), dtype=np.int64)
        for i in range(len(keys) - 1, -1, -1):
            run[i] = 1 + run[i + 1] if i + 1 < len(keys) and consecutive[i + 1] else 1
        starts = np.flatnonzero(run >= length)
        # stride counts within each scene, from the scene's first window
        starts = np.array([s for s in starts if (indices[s] - indices[starts[key_scenes[starts] == key_scenes[s]][0]]) % stride
                           == 0], dtype=np.int64)
        self._windows = [(str(key_scenes[s]), int(indices[s])) for s in starts]

    def __len__(self) -> int:
        return len(self._windows)

    def __getitem__(self, index: int) -> dict[str, Any]:
        index = operator.index(index)  # 1.5 is a TypeError, as for a list, not window 1
        if not -len(self) <= index < len(self):
            raise IndexError(f"expected an index in [0, {len(self)}), got {index}")
        scene, first = self._windows[int(index) % len(self)]
        length = self.past_frames + self.future_frames
        frame_indices = list(range(first, first + length))
        present = frame_indices[self.past_frames - 1]
        frames = self.frames
        t_obs = frames.timestamp_ns(scene, present)
        reference = (frames.options.frame, t_obs)
        observed = frames.items([(scene, i) for i in frame_indices[: self.past_frames]], reference)
        current = observed[-1]
        ids = np.asarray(current["object_ids"], dtype=str)
        reader, transforms = frames.reader(scene), frames.transforms(scene)
        # Every labelled box of the window that is one of the present objects, each frame's boxes with
        # that frame's transform, moved in one batched call.
        parts, moves, columns, times = [], [], [], []
        for k, frame_index in enumerate(frame_indices):
            info, labels = reader.labels(frame_index)
            times.append(info.timestamp_ns)
            boxes = labels.boxes[np.isin(np.asarray(labels.boxes.ids), ids)]
            parts.append(boxes)
            moves.append(transforms.between(reference[0], t_obs, boxes.frame, info.timestamp_ns))
            columns.append(np.full(len(boxes), k, dtype=np.int64))
        counts = [len(b) for b in parts]
        per_box = np.repeat(np.arange(length), counts)
        batch = Transform(rotation=np.stack([m.rotation for m in moves])[per_box],
                          translation=np.stack([m.translation for m in moves])[per_box])
        # Each box moves from its own frame's labels frame by its own transform, so the boxes of the
        # window are joined as they are (their frame name is only a placeholder until moved).
        window = Boxes3D(center=np.concatenate([b.center for b in parts]),
                         size_lwh=np.concatenate([b.size_lwh for b in parts]),
                         quat_wxyz=np.concatenate([b.quat_wxyz for b in parts]), frame=parts[0].frame,
                         ids=np.concatenate([np.asarray(b.ids, dtype=str) for b in parts]))
        moved = window.transform(batch, reference[0])
        order = np.argsort(ids)
        rows = order[np.searchsorted(ids[order], np.asarray(moved.ids, dtype=str))] if len(moved) else per_box
        column = np.concatenate(columns)
        states = np.zeros((len(ids), length, 4), dtype=np.float32)
        valid = np.zeros((len(ids), length), dtype=bool)
        states[rows, column, :3] = moved.center
        states[rows, column, 3] = moved.yaw()
        valid[rows, column] = True
        return {
            "scene": scene,
            "frame": reference[0],
            "timestamp_ns": t_obs,
            "frame_indices": torch.tensor(frame_indices, dtype=torch.int64),
            "timestamps_ns": torch.tensor(times, dtype=torch.int64),
            "frames": observed,
            "object_ids": current["object_ids"],
            "object_labels": current["labels"],
            "past": torch.from_numpy(states[:, : self.past_frames].copy()),
            "past_valid": torch.from_numpy(valid[:, : self.past_frames].copy()),
            "future": torch.from_numpy(states[:, self.past_frames :].copy()),
            "future_valid": torch.from_numpy(valid[:, self.past_frames :].copy()),
        }
