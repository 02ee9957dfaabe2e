"""The frame index of a FrameDataset: which frames it serves, in item order, and what each needs from the index.

Built once from ``index/frames.parquet`` (and ``index/visibility.parquet`` when labels are filtered by
visibility or agents collaborate), as flat arrays: a DataLoader worker receives them pickled once.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from avdata.errors import AvdataError
from avdata.loaders.options import LabelFilter, as_patterns
from avdata.storage import Location


class VisibilityIndex:
    """Per (scene, frame_index, sensor) visibility rows, as flat arrays and group slices."""

    def __init__(self, table: pa.Table):
        table = table.select(["scene", "frame_index", "sensor", "object_id", "in_fov", "n_points",
                                            "occlusion"])
        table = table.sort_by([("scene", "ascending"), ("frame_index", "ascending"), ("sensor", "ascending")])
        scene = table.column("scene").to_numpy(zero_copy_only=False).astype(str)
        frame_index = table.column("frame_index").to_numpy()
        sensor = table.column("sensor").to_numpy(zero_copy_only=False).astype(str)
        self.object_id = table.column("object_id").to_numpy(zero_copy_only=False).astype(str)
        self.in_fov = table.column("in_fov").to_numpy(zero_copy_only=False).astype(bool)
        self.n_points = table.column("n_points").to_numpy().astype(np.int64)
        self.occlusion = table.column("occlusion").to_numpy().astype(np.int64)
        n = len(scene)
        change = np.ones(n, dtype=bool)
        if n:
            change[1:] = (scene[1:] != scene[:-1]) | (frame_index[1:] != frame_index[:-1]) | (sensor[1:] != sensor[:-1])
        starts = np.flatnonzero(change)
        stops = np.append(starts[1:], n) if n else np.zeros(0, dtype=np.int64)
        self.groups: dict[tuple[str, int, str], tuple[int, int]] = {
            (str(scene[a]), int(frame_index[a]), str(sensor[a])): (int(a), int(b)) for a, b in zip(starts, stops, strict=True)
        }
        self._sensors: dict[tuple[str, int], list[str]] = {}
        for group_scene, group_frame, group_sensor in self.groups:
            self._sensors.setdefault((group_scene, group_frame), []).append(group_sensor)

    def sensors_of(self, scene: str, frame_index: int) -> list[str]:
        """Sensors with visibility labels in a frame, sorted."""
        return self._sensors.get((scene, frame_index), [])

    def passes(
        self, scene: str, frame_index: int, sensor: str, object_ids: np.ndarray, labels: LabelFilter
    ) -> np.ndarray:
        """(N,) whether ``sensor`` saw each object under the filter's thresholds (no row: not seen)."""
        span = self.groups.get((scene, frame_index, sensor))
        if span is None or not len(object_ids):
            return np.zeros(len(object_ids), dtype=bool)
        rows = slice(*span)
        ok = self.in_fov[rows].copy()
        if labels.min_points is not None:
            ok &= self.n_points[rows] >= labels.min_points
        if labels.max_occlusion is not None:
            ok &= self.occlusion[rows] <= labels.max_occlusion
        seen = self.object_id[rows][ok]
        return np.isin(object_ids, seen)


@dataclass(frozen=True, slots=True, kw_only=True)
class SceneFrames:
    """Every frame of one scene, kept by the dataset's filters or not (a delayed transmission may come from any).

    Attributes:
        times_ns: (F,) int64 frame times, sorted.
        frame_indices: (F,) int64 frame indices.
        sensor_times: per frame, sensor -> message time in ns.
    """

    times_ns: np.ndarray
    frame_indices: np.ndarray
    sensor_times: list[dict[str, int]]


class FrameIndex:
    """The frames of a dataset that a FrameDataset serves, in item order (scene, then frame index).

    Args:
        root: the dataset folder (named in errors).
        frames: the dataset's ``index/frames.parquet`` table.
        known_scenes: the dataset's scene names.
        scenes: restrict to these scene names.
        split: restrict to frames of this split.
        annotated_only: skip frames whose objects were not labelled.

    Attributes:
        scene, frame_index, time_ns, ego_frame: (N,) per item: its key, reference time and ego frame.
        prev_time_ns: (N,) the time of the scene's previous frame (kept or not), -1 for a first frame.
        sensor_times: per item, sensor -> message time in ns.
        scene_frames: scene -> :class:`SceneFrames`.
        scene_times: scene -> (T,) sorted unique frame and sensor times (stamped lookups are batched over them).

    Raises:
        AvdataError: ``scenes`` names a scene, or ``split`` a split, the dataset does not have.
    """

    def __init__(self, root: Path | Location, frames: pa.Table, known_scenes: Sequence[str], *, scenes: Sequence[str] | None,
                 split: str | None, annotated_only: bool):
        self.root = root
        scene = np.asarray(frames.column("scene").to_pylist(), dtype=str)
        frame_index = frames.column("frame_index").to_numpy().astype(np.int64)
        time_ns = frames.column("timestamp_ns").to_numpy().astype(np.int64)
        order = np.lexsort((frame_index, scene))
        scene, frame_index, time_ns = scene[order], frame_index[order], time_ns[order]
        sensor_times = [dict(frames.column("sensor_timestamps_ns")[int(i)].as_py()) for i in order]
        ego_frame = np.asarray([e or "" for e in frames.column("ego_frame").to_pylist()], dtype=str)[order]
        annotated = frames.column("annotated").to_numpy(zero_copy_only=False).astype(bool)[order]
        frame_split = np.asarray(frames.column("split").to_pylist(), dtype=str)[order]
        first = np.ones(len(scene), dtype=bool)
        first[1:] = scene[1:] != scene[:-1]
        prev_time = np.where(first, -1, np.roll(time_ns, 1))
        keep = np.ones(len(scene), dtype=bool)
        if annotated_only:
            keep &= annotated
        if split is not None:
            if split not in set(frame_split.tolist()):
                raise AvdataError(f"{root}: expected a split of the dataset {sorted(set(frame_split.tolist()))}, "
                                  f"got split={split!r}")
            keep &= frame_split == split
        scenes = as_patterns(scenes, "scenes")  # one name is one scene, not its characters
        if scenes is not None:
            missing = sorted(set(scenes) - set(known_scenes))
            if missing:
                raise AvdataError(f"{root}: expected scenes of the dataset, got unknown {missing}")
            keep &= np.isin(scene, list(scenes))
        self.scene = scene[keep]
        self.frame_index = frame_index[keep]
        self.time_ns = time_ns[keep]
        self.prev_time_ns = prev_time[keep]
        self.ego_frame = ego_frame[keep]
        self.sensor_times = [times for times, k in zip(sensor_times, keep, strict=True) if k]
        self._positions = {key: i for i, key in enumerate(self.keys())}
        self.scene_times: dict[str, np.ndarray] = {}
        self.scene_frames: dict[str, SceneFrames] = {}
        for name in np.unique(scene):
            rows = np.flatnonzero(scene == name)
            self.scene_frames[str(name)] = SceneFrames(times_ns=time_ns[rows], frame_indices=frame_index[rows],
                                                       sensor_times=[sensor_times[r] for r in rows])
            times = [time_ns[rows]] + [np.fromiter(sensor_times[r].values(), dtype=np.int64) for r in rows]
            self.scene_times[str(name)] = np.unique(np.concatenate(times))

    def __len__(self) -> int:
        return len(self.scene)

    def keys(self) -> list[tuple[str, int]]:
        """(scene, frame_index) of every item, in item order."""
        return list(zip(self.scene.tolist(), self.frame_index.tolist(), strict=True))

    def position(self, scene: str, frame_index: int) -> int:
        """The item position of a frame."""
        position = self._positions.get((scene, int(frame_index)))
        if position is None:
            raise AvdataError(f"{self.root}: expected a frame of this dataset, got scene {scene!r} frame {frame_index}")
        return position
