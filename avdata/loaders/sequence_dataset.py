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

from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from avdata.errors import AvdataError
from avdata.loaders.frame_dataset import FrameDataset


class SequenceDataset(Dataset):
    """Windows of ``past_frames + future_frames`` consecutive frames (see the module docstring).

    Args:
        root: the dataset folder.
        past_frames: P >= 1 observed frames, the last one being the present.
        future_frames: F >= 0 frames after the present.
        stride: frames between the starts of consecutive windows.
        **options: any :class:`FrameDataset` keyword (sensors, frame, classes, filters, agents ...);
            the filters choose the objects at the present frame.
    """

    def __init__(self, root: str | Path, *, past_frames: int, future_frames: int = 0, stride: int = 1,
                 **options: Any):
        if past_frames < 1 or future_frames < 0 or stride < 1:
            raise AvdataError(f"expected past_frames >= 1, future_frames >= 0, stride >= 1, got {past_frames}, "
                              f"{future_frames}, {stride}")
        self.past_frames = past_frames
        self.future_frames = future_frames
        self.frames = FrameDataset(root, **options)
        keys = self.frames.keys()
        length = past_frames + future_frames
        scenes = np.array([k[0] for k in keys], dtype=str)
        indices = np.array([k[1] for k in keys], dtype=np.int64)
        consecutive = np.zeros(len(keys), dtype=bool)
        consecutive[1:] = (scenes[1:] == scenes[:-1]) & (indices[1:] == indices[:-1] + 1)
        # a window starting at i needs the next length-1 frames to be consecutive with it
        run = np.zeros(len(keys), dtype=np.int64)
        for i in range(len(keys) - 1, -1, -1):
            run[i] = 1 + run[i + 1] if i + 1 < len(keys) and consecutive[i + 1] else 1
        starts = np.flatnonzero(run >= length)
        # stride counts within each scene, from the scene's first window
        starts = np.array([s for s in starts if (indices[s] - indices[starts[scenes[starts] == scenes[s]][0]]) % stride
                           == 0], dtype=np.int64)
        self._windows = [(str(scenes[s]), int(indices[s])) for s in starts]

    def __len__(self) -> int:
        return len(self._windows)

    def __getitem__(self, index: int) -> dict[str, Any]:
        if not -len(self) <= index < len(self):
            raise IndexError(f"expected an index in [0, {len(self)}), got {index}")
        scene, first = self._windows[int(index) % len(self)]
        length = self.past_frames + self.future_frames
        frame_indices = list(range(first, first + length))
        present = frame_indices[self.past_frames - 1]
        frames = self.frames
        t_obs = int(frames._time_ns[frames._position(scene, present)])
        reference = (frames.options.frame, t_obs)
        observed = [frames.item(scene, i, reference) for i in frame_indices[: self.past_frames]]
        current = observed[-1]
        ids = current["object_ids"]
        states = np.zeros((len(ids), length, 4), dtype=np.float32)
        valid = np.zeros((len(ids), length), dtype=bool)
        reader, transforms = frames._open(scene)
        row = {object_id: m for m, object_id in enumerate(ids)}
        times = []
        for k, frame_index in enumerate(frame_indices):
            info, labels = reader.labels(frame_index)
            times.append(info.timestamp_ns)
            boxes = labels.boxes
            mine = np.isin(np.asarray(boxes.ids), ids)
            boxes = boxes[mine]
            moved = boxes.transform(transforms.between(reference[0], t_obs, boxes.frame, info.timestamp_ns),
                                    reference[0])
            rows = np.array([row[object_id] for object_id in np.asarray(moved.ids).tolist()], dtype=np.int64)
            states[rows, k, :3] = moved.center
            states[rows, k, 3] = moved.yaw()
            valid[rows, k] = True
        return {
            "scene": scene,
            "frame": reference[0],
            "timestamp_ns": t_obs,
            "frame_indices": torch.tensor(frame_indices, dtype=torch.int64),
            "timestamps_ns": torch.tensor(times, dtype=torch.int64),
            "frames": observed,
            "object_ids": ids,
            "object_labels": current["labels"],
            "past": torch.from_numpy(states[:, : self.past_frames].copy()),
            "past_valid": torch.from_numpy(valid[:, : self.past_frames].copy()),
            "future": torch.from_numpy(states[:, self.past_frames :].copy()),
            "future_valid": torch.from_numpy(valid[:, self.past_frames :].copy()),
        }
