"""``FrameDataset``: one item per (scene, frame) of a unified dataset, single-agent or collaborative.

``FrameDataset(root)`` gives the ego's point clouds (its lidars and radars) and its labelled boxes in
the ego frame, every class kept. Anything else is chosen with a :class:`FrameOptions` (sensors,
frame, :class:`LabelFilter`, :class:`Collaboration`, velocities, quaternions); ``sensors``,
``frame``, ``classes``, ``agents``, ``with_velocity`` and ``with_quaternions`` are also keyword
shortcuts, each replacing that one field.

Everything in an item is expressed in one requested frame of the scene's tree (``frame``: "world",
"ego", "ego/lidar_top", "infra_03/lidar", ...) at the frame's time ``timestamp_ns`` (the time of
its labels). A sensor message taken at another time is moved through ``world``:
``frame(t_ref)_T_sensor(t_sensor) = frame_T_world(t_ref) @ world_T_sensor(t_sensor)``, so ego motion
between the two times is compensated.

An item is a dict:

==========================  =====================================================================
``scene``, ``frame_index``  the key; ``timestamp_ns`` the reference time; ``frame`` the frame name
``points``                  sensor -> (N, F) float32 tensor; x, y, z in ``frame``, other fields as stored
``point_fields``            sensor -> tuple of the F field names
``images``                  camera -> (C, H, W) uint8 tensor, RGB (decoded with OpenCV, BGR converted)
``calibrations``            camera -> dict of K (3, 3), D (k,), R (3, 3), P (3, 4) float64 tensors,
                            ``width``, ``height``, ``distortion_model``
``projections``             camera -> (3, 4) float64 ``P[:, :3] @ [R | 0] @ camera_T_frame``: homogeneous
                            points in ``frame`` to pixels of the (rectified) image (see below)
``sensor_timestamps_ns``    sensor -> int, the time of the message used
``boxes``                   (N, 7) float32 x, y, z, length, width, height, yaw in ``frame``, or
                            (N, 9) with vx, vy appended (``with_velocity``; NaN when not labelled)
``boxes_quat_wxyz``         (N, 4) float64 full box orientations in ``frame`` (``with_quaternions`` only)
``labels``                  (N,) int64 class index into ``classes``
``object_ids``              list of N id strings
==========================  =====================================================================

Collaborative items (``agents=[...]``) add ``agents`` (A names, the ego first), ``agent_poses``
(A, 4, 4) float64 ``frame_T_agent``, ``agent_distance_m`` (A,) from the ego, ``agent_received``
(A,) bool, and ``visible_by`` (A, N) bool: which received agent's sensors saw each object (same
test as the label filter). With ``fusion="early"`` the received clouds are concatenated into
``points["fused"]`` with a trailing ``agent_index`` field (index into ``agents``), keeping the fields
every cloud has.

In collaborative items the reference time is still the frame's time (the ego's labels time); each
agent's cloud is taken at its own message time and moved through ``world``. With ``latency_ms`` an
agent's messages (and its pose) come from its last transmission at or before ``t - latency``;
``agent_timestamps_ns`` (A,) holds each agent's transmission frame time. With ``pose_noise`` or
``pose_source="predicted"``, everything of another agent placed through its pose (its clouds,
``agent_poses``, ``pairwise_T``) uses the transmitted pose; the ego's data never change.

``fusion="intermediate"`` (OpenCOOD's layout) keeps one cloud per received agent, ``points[agent]``, in
that agent's own frame ``agent_frames[a]`` (its first lidar, or its body frame without one; an agent's
other lidars are moved into it), and adds ``pairwise_T`` (L, L, 4, 4) float64 with L =
``max_agents``: ``pairwise_T[i, j] = j_T_i = inv(world_T_j) @ world_T_i``, which maps points of agent i
(in ``agent_frames[i]`` at its capture time) into agent j's frame, as OpenCOOD's
``pairwise_t_matrix[i, j]`` ("i_to_j"); and ``agent_mask`` (L,) bool. Agents are ordered ego first, then
the received ones, so the mask is a prefix; rows and columns of unreceived or padded slots are the
identity. ``fusion="late"`` adds each received agent's own label set in its own frame, from its
transmission's frame: ``agent_boxes`` agent -> (M, 7) float32, ``agent_labels`` agent -> (M,) int64,
``agent_object_ids`` agent -> list (collate with :func:`~avdata.loaders.collate_intermediate` /
:func:`~avdata.loaders.collate_late`).

Every tensor of an item is a view of one buffer. Clouds are read from the scene file with one
``preadv`` each and moved in place (one 4x4 per sensor, whatever the frame). Inside a DataLoader
worker the batch is assembled in memory the worker reuses, then written into a fresh shared-memory
file with one ``pwrite``, so it crosses to the main process as one handle and is never copied again
(``benchmarks/loaders.py`` measures why this matters).

Projection: a camera frame sits at that camera's own optical centre, so ``camera_T_frame`` already
holds any stereo baseline. The fourth column of ``P`` is, by the ROS/Foxglove (and KITTI P2/P3)
convention, the same baseline relative to the stereo pair's first camera, for points given in
that first camera's frame; it is therefore left out, and ``P[:, :3] @ R`` maps the camera frame to
rectified pixels. For KITTI this reproduces ``P2 @ R0_rect @ Tr_velo_to_cam``.
"""

from __future__ import annotations

import fnmatch
import os
import zlib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyarrow as pa
import torch
from torch.utils.data import Dataset, get_worker_info

from avdata.errors import AvdataError, ExtrapolationError, FrameLookupError, InputError
from avdata.frames import FrameGraph, Transform
from avdata.loaders.options import POINT_CLOUD_KINDS, Collaboration, FrameOptions, LabelFilter, as_patterns
from avdata.schema import DatasetReader, ObjectLabels, SceneReader, scene_path
from avdata.schema.index import VISIBILITY_SCHEMA

_XYZ = ("x", "y", "z")
_EYE3 = np.eye(3)


class _VisibilityIndex:
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


class FrameDataset(Dataset):
    """One item per annotated frame of a unified dataset (see the module docstring for the item).

    ``FrameDataset(root)`` returns the ego's point clouds (every lidar and radar of the ego agent)
    with all labelled objects, in the ego frame. A frame without any such message (a labels-only
    dataset, or a gap in a sensor's recording) gives an item without points; name ``sensors`` to
    require them in every frame.

    Args:
        root: the dataset folder.
        options: what an item holds (:class:`FrameOptions`: sensors, frame, label filter,
            velocities, quaternions, collaboration); None for the defaults.
        sensors: shortcut for ``options.sensors``: sensor frames or glob patterns ("ego/lidar_top",
            "ego/cam_*", "*/lidar"); ``[]`` gives labels only.
        frame: shortcut for ``options.frame``, e.g. "world" or "ego/cam_front".
        classes: shortcut for ``options.labels.classes``: unified class names to keep, in
            class-index order.
        agents: shortcut for ``options.collaboration.agents`` (collaborative items; a new
            :class:`Collaboration` with default link settings if ``options`` has none).
        with_velocity: shortcut for ``options.with_velocity``.
        with_quaternions: shortcut for ``options.with_quaternions``.
        scenes: restrict to these scene names.
        split: restrict to frames of this split ("train", "val", ...).
        annotated_only: skip frames whose objects were not labelled.

    Raises:
        AvdataError: an option is invalid, or a frame lacks a requested sensor or agent.
    """

    def __init__(
        self,
        root: str | Path,
        options: FrameOptions | None = None,
        *,
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
        self.root = Path(root)
        options = options if options is not None else FrameOptions()
        if not isinstance(options, FrameOptions):
            raise AvdataError(f"expected options as a FrameOptions, got {type(options).__name__}")
        if sensors is not None:
            options = replace(options, sensors=as_patterns(sensors, "sensors"))
        if frame is not None:
            options = replace(options, frame=frame)
        if classes is not None:
            options = replace(options, labels=replace(options.labels, classes=tuple(classes)))
        if with_velocity is not None:
            options = replace(options, with_velocity=with_velocity)
        if with_quaternions is not None:
            options = replace(options, with_quaternions=with_quaternions)
        if agents is not None:
            collaboration = options.collaboration
            agent_patterns = as_patterns(agents, "agents") or ()
            options = replace(options, collaboration=Collaboration(agents=agent_patterns) if collaboration is None
                              else replace(collaboration, agents=agent_patterns))
        self.options = options
        collaboration = options.collaboration
        reader = DatasetReader(self.root)
        self.classes: tuple[str, ...] = self.options.labels.classes
        self._sensor_kind: dict[str, str] = {
            name: str(spec.get("kind", "")) for name, spec in reader.manifest.get("sensors", {}).items()
        }
        frames = reader.frames()
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
        starts = np.maximum.accumulate(np.where(first, np.arange(len(scene)), 0))
        prev_time = np.where(first, -1, np.roll(time_ns, 1))
        keep = np.ones(len(scene), dtype=bool)
        if annotated_only:
            keep &= annotated
        if split is not None:
            keep &= frame_split == split
        if scenes is not None:
            missing = sorted(set(scenes) - set(reader.scenes))
            if missing:
                raise AvdataError(f"{self.root}: expected scenes of the dataset, got unknown {missing}")
            keep &= np.isin(scene, list(scenes))
        self._scene = scene[keep]
        self._frame_index = frame_index[keep]
        self._time_ns = time_ns[keep]
        self._prev_time_ns = prev_time[keep]
        self._scene_start_ns = time_ns[starts][keep]
        self._ego_frame = ego_frame[keep]
        self._sensor_times = [times for times, k in zip(sensor_times, keep, strict=True) if k]
        self._positions = {key: i for i, key in enumerate(zip(self._scene.tolist(), self._frame_index.tolist(), strict=True))}
        # every frame and sensor time of each scene: stamped lookups are batched over them
        self._scene_times: dict[str, np.ndarray] = {}
        # every frame of each scene (kept or not): a delayed transmission may come from any of them
        self._scene_frames: dict[str, tuple[np.ndarray, np.ndarray, list[dict[str, int]]]] = {}
        for name in np.unique(scene):
            rows = np.flatnonzero(scene == name)
            self._scene_frames[str(name)] = (time_ns[rows], frame_index[rows], [sensor_times[r] for r in rows])
            times = [time_ns[rows]] + [np.fromiter(sensor_times[r].values(), dtype=np.int64) for r in rows]
            self._scene_times[str(name)] = np.unique(np.concatenate(times))
        needs_visibility = self.options.labels.visible_to is not None or collaboration is not None
        self._visibility = _VisibilityIndex(reader.visibility() if needs_visibility else VISIBILITY_SCHEMA.empty_table())
        self._scenes_open: dict[str, tuple[SceneReader, SceneTransforms]] = {}
        self._scratch = _Scratch()
        self._check_sensors()

    # ----------------------------------------------------------------- dataset protocol
    def __len__(self) -> int:
        return len(self._scene)

    def __getitem__(self, index: int) -> dict[str, Any]:
        return self.__getitems__([index])[0]

    def __getitems__(self, indices: Sequence[int]) -> list[dict[str, Any]]:
        """The items at ``indices``, every tensor of them a view of one buffer.

        A DataLoader with a batch size calls this once per batch (torch >= 2.0), so in a worker the
        batch is allocated in shared memory once and crosses to the main process as one handle (a
        storage costs one file descriptor and one mapping whatever its size). A tensor kept from
        the batch keeps the whole batch's buffer alive.
        """
        keys = []
        for index in indices:
            if not -len(self) <= index < len(self):
                raise IndexError(f"expected an index in [0, {len(self)}), got {index}")
            position = int(index) % len(self)
            keys.append((str(self._scene[position]), int(self._frame_index[position])))
        return self.items(keys)

    def __getstate__(self) -> dict[str, Any]:
        state = {name: getattr(self, name) for name in self.__dict__}
        state["_scenes_open"] = {}
        state["_scratch"] = _Scratch()
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)

    def keys(self) -> list[tuple[str, int]]:
        """(scene, frame_index) of every item, in item order."""
        return list(zip(self._scene.tolist(), self._frame_index.tolist(), strict=True))

    def timestamp_ns(self, scene: str, frame_index: int) -> int:
        """The reference time of a frame of this dataset (the time of its labels), in ns."""
        return int(self._time_ns[self._position(scene, frame_index)])

    def reader(self, scene: str) -> SceneReader:
        """This process's reader of ``scene`` (opened on first use; a worker process opens its own)."""
        return self._open(scene)[0]

    def transforms(self, scene: str) -> SceneTransforms:
        """Memoised frame-graph lookups of ``scene``, batched over its frame and sensor times."""
        return self._open(scene)[1]

    # ----------------------------------------------------------------- items
    def item(self, scene: str, frame_index: int, reference: tuple[str, int] | None = None) -> dict[str, Any]:
        """The item of one frame.

        Args:
            scene: scene name.
            frame_index: frame index in the scene.
            reference: (frame name, time_ns) to express everything in instead of the dataset's
                ``frame`` at this frame's time (SequenceDataset uses the last observed frame).
        """
        return self.items([(scene, frame_index)], reference)[0]

    def items(self, keys: Sequence[tuple[str, int]], reference: tuple[str, int] | None = None) -> list[dict[str, Any]]:
        """The items of several frames, every tensor of them a view of one buffer (see :meth:`__getitems__`).

        Args:
            keys: (scene, frame_index) of each item.
            reference: as in :meth:`item`, for all of them.
        """
        return _pack([self._unpacked_item(scene, frame_index, reference) for scene, frame_index in keys], self._scratch)

    def _unpacked_item(self, scene: str, frame_index: int, reference: tuple[str, int] | None) -> _Unpacked:
        """The item with arrays and clouds still to be written into a buffer (see :func:`_pack`)."""
        position = self._position(scene, frame_index)
        reader, transforms = self._open(scene)
        _, labels = reader.labels(frame_index)
        t_ref = int(self._time_ns[position])
        frame, t_frame = reference if reference is not None else (self.options.frame, t_ref)
        item: dict[str, Any] = {"scene": scene, "frame_index": frame_index, "timestamp_ns": t_ref, "frame": frame}
        sensor_times = self._sensor_times[position]
        ego = str(self._ego_frame[position])
        collaboration = self.options.collaboration
        agents: list[str] | None = None
        received_agents: list[str] = []
        links: dict[str, _Link] = {}
        if collaboration is None:
            sensors = [(s, int(sensor_times[s])) if s in sensor_times else (s, -1) for s in self._sensors_of(position)]
        else:
            link_list = self._links(collaboration, position, transforms)
            links = {link.agent: link for link in link_list}
            agents = [link.agent for link in link_list]
            received = np.array([link.received for link in link_list], dtype=bool)
            received_agents = [a for a, r in zip(agents, received, strict=True) if r]
            sensors = [(s, int(links[_agent_of(s)].sensor_times[s])) for s in self._sensors_of(position)
                       if _agent_of(s) in received_agents and s in links[_agent_of(s)].sensor_times]
            poses = np.stack([self._sent(links[a], transforms, frame, t_frame, a, link.time_ns).as_matrix()
                              for a, link in zip(agents, link_list, strict=True)])
            item.update(agents=agents, agent_poses=poses,
                        agent_distance_m=np.array([link.distance_m for link in link_list], dtype=np.float64),
                        agent_received=received,
                        agent_timestamps_ns=np.array([link.time_ns for link in link_list], dtype=np.int64))
        images: dict[str, np.ndarray] = {}
        calibrations: dict[str, dict[str, Any]] = {}
        projections: dict[str, np.ndarray] = {}
        used_times: dict[str, int] = {}
        clouds: list[_SensorCloud] = []
        for sensor, t_sensor in sensors:
            if t_sensor < 0:
                raise AvdataError(f"scene {scene!r} frame {frame_index}: no message of sensor {sensor!r}; "
                                  f"has {sorted(sensor_times)}")
            used_times[sensor] = t_sensor
            link = links.get(_agent_of(sensor))
            frame_T_sensor = self._sent(link, transforms, frame, t_frame, sensor, t_sensor)
            kind = self._sensor_kind.get(sensor, "")
            if kind == "camera":
                data, _ = reader.image(sensor, t_sensor)
                images[sensor] = decode_image(data, f"scene {scene!r} sensor {sensor!r} at {t_sensor} ns")
                calibration = reader.camera_calibration(sensor, t_sensor)
                calibrations[sensor] = _calibration_dict(calibration)
                projections[sensor] = _projection(calibration, frame_T_sensor.inverse())
            else:
                clouds.append(_SensorCloud(sensor=sensor, time_ns=t_sensor, reader=reader,
                                           stored=reader.points(sensor, t_sensor), frame_T_sensor=frame_T_sensor))
        fusion = collaboration.fusion if collaboration is not None else None
        points: dict[str, _PendingCloud]
        if fusion == "early":
            names = _common_fields(cloud.stored for cloud in clouds)
            points = {"fused": _PendingCloud(members=clouds, names=names, agents=agents)}
        elif fusion in ("intermediate", "late"):
            assert collaboration is not None and agents is not None  # fusion is set only with a collaboration
            points, per_agent = self._per_agent(collaboration, scene, frame_index, agents, links, clouds, transforms)
            item.update(per_agent)
        else:
            points = {c.sensor: _PendingCloud(members=[c], names=tuple(c.stored.dtype.names or ()), agents=None)
                      for c in clouds}
        item.update(points=points, point_fields={key: cloud.fields for key, cloud in points.items()}, images=images,
                    calibrations=calibrations, projections=projections, sensor_timestamps_ns=used_times)
        item.update(self._boxes(position, transforms, labels, frame, t_frame, ego, agents, received_agents))
        noise: dict[str, float] = {}
        seeds: dict[str, list[int]] = {}
        if collaboration is not None:
            noise = {c.sensor: collaboration.noise_of(_agent_of(c.sensor)) for c in clouds if _agent_of(c.sensor) != ego}
            seeds = {s: [collaboration.seed, zlib.crc32(f"{scene}/{frame_index}/{s}".encode())] for s in noise}
        return _Unpacked(item=item, noise_std_m=noise, seeds=seeds)

    def _boxes(
        self,
        position: int,
        transforms: SceneTransforms,
        labels: ObjectLabels,
        frame: str,
        t_frame: int,
        ego: str,
        agents: list[str] | None,
        received_agents: list[str],
    ) -> dict[str, Any]:
        options = self.options.labels
        scene, frame_index = str(self._scene[position]), int(self._frame_index[position])
        t_ref = int(self._time_ns[position])
        boxes = labels.boxes
        all_ids, all_classes = np.asarray(boxes.ids), np.asarray(boxes.classes)  # ObjectLabels always has both
        frame_T_labels = transforms.between(frame, t_frame, boxes.frame, t_ref)
        class_index = class_indices(all_classes, self.classes)
        keep = class_index >= 0
        # An agent that is itself a labelled object (generated data names it in the scene metadata)
        # is not a target of its own sensors.
        own_object = self._open(scene)[0].metadata.get("agents", {}).get(ego, {}).get("object_id")
        if own_object is not None:
            keep &= all_ids != str(own_object)
        if options.max_range_m is not None and len(boxes):
            if not ego:
                raise AvdataError(f"scene {scene!r}: max_range_m needs an ego frame, got a scene without one")
            ego_T_labels = transforms.lookup(ego, boxes.frame, t_ref)
            centers_ego = ego_T_labels.apply(boxes.center)
            keep &= np.hypot(centers_ego[:, 0], centers_ego[:, 1]) <= options.max_range_m
        if options.visible_to is not None:
            seen = np.zeros(len(boxes), dtype=bool)
            for sensor in self._visibility.sensors_of(scene, frame_index):
                if _matches(sensor, options.visible_to) and (agents is None or _agent_of(sensor) in received_agents):
                    seen |= self._visibility.passes(scene, frame_index, sensor, all_ids, options)
            keep &= seen
        # Every box is moved (one vectorised call), then the kept ones taken: cheaper than a subset first.
        moved = boxes.transform(frame_T_labels, frame)
        ids = all_ids[keep]
        columns = [moved.center[keep], moved.size_lwh[keep], moved.yaw()[keep, None]]
        if self.options.with_velocity:
            columns.append(moved.velocity[keep, :2] if moved.velocity is not None else np.full((len(ids), 2), np.nan))
        result: dict[str, Any] = {
            "boxes": np.concatenate(columns, axis=1).astype(np.float32),
            "labels": class_index[keep],
            "object_ids": ids.tolist(),
        }
        if self.options.with_quaternions:
            result["boxes_quat_wxyz"] = moved.quat_wxyz[keep]
        if agents is not None:
            visible_by = np.zeros((len(agents), len(ids)), dtype=bool)
            for sensor in self._visibility.sensors_of(scene, frame_index):
                agent = _agent_of(sensor)
                if agent in received_agents:
                    visible_by[agents.index(agent)] |= self._visibility.passes(
                        scene, frame_index, sensor, ids, options)
            result["visible_by"] = visible_by
        return result

    def _links(self, collaboration: Collaboration, position: int, transforms: SceneTransforms) -> list[_Link]:
        """What the ego holds of each agent at a frame, the ego first.

        In the intermediate and late layouts the received agents come next, so that the agent mask is a
        prefix (as OpenCOOD's ``record_len`` assumes).
        """
        scene, t_ref = str(self._scene[position]), int(self._time_ns[position])
        ego = str(self._ego_frame[position])
        times, indices, all_sensor_times = self._scene_frames[scene]
        here = int(np.searchsorted(times, t_ref))
        prev_ns = int(self._prev_time_ns[position])
        links = []
        for agent in self._agents_of(collaboration, position):  # never empty: the ego matches (checked at construction)
            distance_m = float(np.linalg.norm(transforms.lookup(ego, agent, t_ref).translation))
            if agent == ego:
                links.append(_Link(agent=agent, received=True, distance_m=distance_m, frame_index=int(indices[here]),
                                   time_ns=t_ref, sensor_times=all_sensor_times[here], world_T_recorded=None))
                continue
            latency_ns = collaboration.latency_ns_of(agent)
            sent = _last_transmission(times, t_ref - latency_ns, collaboration.rate_of(agent))
            received = sent is not None and (prev_ns < 0 or int(times[sent]) > prev_ns - latency_ns)
            if collaboration.comm_range_m is not None and distance_m > collaboration.comm_range_m:
                received = False
            at = here if sent is None else sent
            link = _Link(agent=agent, received=received, distance_m=distance_m, frame_index=int(indices[at]),
                         time_ns=int(times[at]), sensor_times=all_sensor_times[at], world_T_recorded=None)
            if collaboration.moves_poses:
                link = replace(link, world_T_recorded=self._pose_error(collaboration, scene, link, transforms))
            links.append(link)
        if collaboration.fusion in ("intermediate", "late"):
            if len(links) > collaboration.max_agents:
                raise AvdataError(f"scene {scene!r} frame {int(self._frame_index[position])}: expected at most "
                                  f"max_agents={collaboration.max_agents} agents, got {[x.agent for x in links]}")
            links = links[:1] + sorted(links[1:], key=lambda x: not x.received)
        return links

    def _pose_error(self, collaboration: Collaboration, scene: str, link: _Link, transforms: SceneTransforms) -> Transform:
        """``world_sent_T_world`` at the link's time, the agent's pose error as transmitted.

        It moves what the recorded pose places into where the transmitted one (``pose_source``, then
        ``pose_noise``) places it.
        """
        agent, t_ns = link.agent, link.time_ns
        world_T_agent = transforms.lookup("world", agent, t_ns)
        world_T_sent = world_T_agent
        if collaboration.pose_source == "predicted":
            predicted = f"{agent}/vehicle_predicted"
            if transforms.graph.can_lookup("world", predicted, t_ns):
                world_T_sent = (transforms.lookup("world", predicted, t_ns)
                                @ transforms.lookup(f"{agent}/vehicle", agent, t_ns))
            elif not transforms.graph.can_lookup("world", agent, None):  # only a surveyed (static) pose may lack it
                raise AvdataError(f"scene {scene!r} agent {agent!r}: pose_source='predicted' needs frame "
                                  f"{predicted!r} at {t_ns} ns, got none")
        if collaboration.pose_noise is not None:
            rng = np.random.default_rng([collaboration.seed, zlib.crc32(f"{scene}/{link.frame_index}/{agent}/pose".encode())])
            delta = rng.normal(0.0, 1.0, 4) * np.array(collaboration.pose_noise[:3] + (np.deg2rad(collaboration.pose_noise[3]),))
            world_T_sent = Transform(rotation=Transform.from_yaw(delta[3]).rotation @ world_T_sent.rotation,
                                     translation=world_T_sent.translation + delta[:3])
        return world_T_sent @ world_T_agent.inverse()

    @staticmethod
    def _sent(link: _Link | None, transforms: SceneTransforms, frame: str, t_frame: int, source: str,
              t_source: int) -> Transform:
        """``frame(t_frame)_T_source(t_source)`` as the ego knows it.

        Through the transmitted pose of the source's agent when that differs from the recorded one.
        """
        if link is None or link.world_T_recorded is None:
            return transforms.between(frame, t_frame, source, t_source)
        return transforms.lookup(frame, "world", t_frame) @ link.world_T_recorded @ transforms.lookup("world", source, t_source)

    def _per_agent(
        self, collaboration: Collaboration, scene: str, frame_index: int, agents: list[str], links: Mapping[str, _Link],
        clouds: list[_SensorCloud], transforms: SceneTransforms,
    ) -> tuple[dict[str, _PendingCloud], dict[str, Any]]:
        """The intermediate / late layout (see the module docstring).

        Per-agent clouds in each agent's own frame, pairwise transforms, the agent mask and (late)
        per-agent label sets.
        """
        slots = collaboration.max_agents
        frames: list[str] = []
        frame_times: list[int] = []
        for agent in agents:
            own = [c for c in clouds if _agent_of(c.sensor) == agent]
            frames.append(own[0].sensor if own else agent)
            frame_times.append(own[0].time_ns if own else links[agent].time_ns)
        points: dict[str, _PendingCloud] = {}
        for agent, agent_frame, t_agent in zip(agents, frames, frame_times, strict=True):
            own = [replace(c, frame_T_sensor=transforms.between(agent_frame, t_agent, c.sensor, c.time_ns))
                   for c in clouds if _agent_of(c.sensor) == agent]
            if own:
                points[agent] = _PendingCloud(members=own, names=_common_fields(c.stored for c in own), agents=None)
        world_T_frame = np.stack([self._sent(links[a], transforms, "world", t, f, t).as_matrix()
                                  for a, f, t in zip(agents, frames, frame_times, strict=True)])
        pairwise = np.tile(np.eye(4), (slots, slots, 1, 1))
        n = len(agents)
        # pairwise[i, j] = j_T_i = inv(world_T_j) @ world_T_i: agent i's points into agent j's frame
        pairwise[:n, :n] = np.linalg.solve(world_T_frame[None, :, :, :], world_T_frame[:, None, :, :])
        mask = np.zeros(slots, dtype=bool)
        mask[:n] = [links[a].received for a in agents]
        pairwise[~np.outer(mask, mask)] = np.eye(4)
        out: dict[str, Any] = {"agent_frames": frames, "pairwise_T": pairwise, "agent_mask": mask}
        if collaboration.fusion == "late":
            out.update(self._agent_labels(scene, agents, frames, frame_times, links, transforms))
        return points, out

    def _agent_labels(
        self, scene: str, agents: list[str], frames: list[str], frame_times: list[int], links: Mapping[str, _Link],
        transforms: SceneTransforms,
    ) -> dict[str, Any]:
        """Each received agent's label set, from its transmission's frame, in its own frame.

        The label filter applies per agent: its classes, ``max_range_m`` from that agent's frame origin,
        ``visible_to`` by the agent's own sensors.
        """
        options = self.options.labels
        reader = self._open(scene)[0]
        boxes_out: dict[str, np.ndarray] = {}
        labels_out: dict[str, np.ndarray] = {}
        ids_out: dict[str, list[str]] = {}
        for agent, agent_frame, t_agent in zip(agents, frames, frame_times, strict=True):
            link = links[agent]
            if not link.received:
                continue
            _, labels = reader.labels(link.frame_index)
            boxes = labels.boxes.transform(transforms.between(agent_frame, t_agent, labels.boxes.frame, link.time_ns),
                                           agent_frame)
            ids = np.asarray(boxes.ids)
            class_index = class_indices(np.asarray(boxes.classes), self.classes)
            keep = class_index >= 0
            own_object = reader.metadata.get("agents", {}).get(agent, {}).get("object_id")
            if own_object is not None:
                keep &= ids != str(own_object)
            if options.max_range_m is not None:
                keep &= np.hypot(boxes.center[:, 0], boxes.center[:, 1]) <= options.max_range_m
            if options.visible_to is not None:
                seen = np.zeros(len(ids), dtype=bool)
                for sensor in self._visibility.sensors_of(scene, link.frame_index):
                    if _agent_of(sensor) == agent and _matches(sensor, options.visible_to):
                        seen |= self._visibility.passes(scene, link.frame_index, sensor, ids, options)
                keep &= seen
            boxes_out[agent] = np.concatenate([boxes.center[keep], boxes.size_lwh[keep], boxes.yaw()[keep, None]],
                                              axis=1).astype(np.float32)
            labels_out[agent] = class_index[keep]
            ids_out[agent] = ids[keep].tolist()
        return {"agent_boxes": boxes_out, "agent_labels": labels_out, "agent_object_ids": ids_out}

    # ----------------------------------------------------------------- index helpers
    def _position(self, scene: str, frame_index: int) -> int:
        position = self._positions.get((scene, int(frame_index)))
        if position is None:
            raise AvdataError(f"{self.root}: expected a frame of this dataset, got scene {scene!r} frame {frame_index}")
        return position

    def _open(self, scene: str) -> tuple[SceneReader, SceneTransforms]:
        """This process's reader and memoised transforms of ``scene`` (opened on first use)."""
        opened = self._scenes_open.get(scene)
        if opened is None:
            path = scene_path(self.root, scene)
            if not path.is_file():
                raise InputError(f"{path}: scene file listed in the index is missing")
            reader = SceneReader(path)
            opened = (reader, SceneTransforms(reader.graph, self._scene_times[scene]))
            self._scenes_open[scene] = opened
        return opened

    def _sensors_of(self, position: int) -> list[str]:
        """The requested sensors present in a frame, in pattern order.

        Without sensor patterns: the point-cloud sensors of the ego (collaborative: of every agent),
        sorted.
        """
        available = sorted(self._sensor_times[position])
        if self.options.sensors is None:
            ego = str(self._ego_frame[position])
            return [s for s in available if self._sensor_kind.get(s, "") in POINT_CLOUD_KINDS
                    and (self.options.collaboration is not None or _agent_of(s) == ego)]
        chosen: list[str] = []
        for pattern in self.options.sensors:
            chosen.extend(s for s in fnmatch.filter(available, pattern) if s not in chosen)
        return chosen

    def _agents_of(self, collaboration: Collaboration, position: int) -> list[str]:
        """Agents (sensor-frame prefixes and the ego) matching the agent patterns, the ego first."""
        ego = str(self._ego_frame[position])
        names = {_agent_of(s) for s in self._sensor_times[position]} | ({ego} if ego else set())
        matched = sorted(n for n in names if _matches(n, collaboration.agents))
        return sorted(matched, key=lambda n: n != ego)

    def _check_sensors(self) -> None:
        """Every sensor pattern (collaborative: also the ego) must be found in every frame."""
        collaboration = self.options.collaboration
        for position in range(len(self)):
            available = sorted(self._sensor_times[position])
            where = f"{self.root}: scene {str(self._scene[position])!r} frame {int(self._frame_index[position])}"
            sensors = self.options.sensors
            if sensors is None:
                pass  # the default takes whatever point clouds a frame has (module docstring)
            elif collaboration is None:
                for pattern in sensors:
                    if not fnmatch.filter(available, pattern):
                        raise AvdataError(f"{where}: expected a sensor matching {pattern!r}, got {available}")
            elif sensors and not any(_matches(s, sensors) for s in available):
                raise AvdataError(f"{where}: expected a sensor matching {list(sensors)}, got {available}")
            if collaboration is not None:
                ego = str(self._ego_frame[position])
                if not ego or not _matches(ego, collaboration.agents):
                    raise AvdataError(f"{where}: expected the ego agent {ego!r} among agents "
                                      f"{list(collaboration.agents)}")


class SceneTransforms:
    """Memoised lookups in one scene's frame graph (a pure cache, one per scene and process).

    A chain of static edges is looked up once; a chain with time-stamped edges is looked up once for
    every frame and sensor time of the scene in one batched (vectorised) query, then indexed. Times
    outside that set, or a batch that some time cannot satisfy, are looked up one by one, so errors
    (extrapolation, unknown frames) surface exactly as :meth:`FrameGraph.lookup` raises them.

    Args:
        graph: the scene's frame graph.
        times_ns: (T,) sorted unique times to batch stamped lookups over.
    """

    def __init__(self, graph: FrameGraph, times_ns: np.ndarray):
        self.graph = graph
        self._times_ns = times_ns
        self._static: dict[tuple[str, str], Transform] = {}
        self._batched: dict[tuple[str, str], Transform | None] = {}

    def lookup(self, target: str, source: str, time_ns: int) -> Transform:
        """``target_T_source`` at ``time_ns``."""
        key = (target, source)
        if key in self._static:
            return self._static[key]
        if key not in self._batched:
            try:
                self._static[key] = self.graph.lookup(target, source, None)
                return self._static[key]
            except ExtrapolationError:
                pass  # a time-stamped edge lies on the chain: batch it
            try:
                self._batched[key] = self.graph.lookup(target, source, self._times_ns)
            except FrameLookupError:
                self._batched[key] = None
        batch = self._batched[key]
        i = int(np.searchsorted(self._times_ns, time_ns))
        if batch is not None and i < len(self._times_ns) and self._times_ns[i] == time_ns:
            return batch[i]
        return self.graph.lookup(target, source, time_ns)

    def between(self, target: str, t_target: int, source: str, t_source: int) -> Transform:
        """``target(t_target)_T_source(t_source)``; through ``world`` when the two times differ."""
        if t_target == t_source:
            return self.lookup(target, source, t_target)
        return self.lookup(target, "world", t_target) @ self.lookup("world", source, t_source)


def transform_xyz_inplace(array: np.ndarray, target_T_source: Transform) -> None:
    """Moves the x, y, z columns of ``array`` (N, F) float32 into the target frame, in place.

    One pass of OpenCV's ``cv2.transform`` (SIMD, one (F, F + 1) matrix acting on each row) when the
    rows are contiguous and F <= 4 (OpenCV's channel limit): about 0.35 ms for 120k points, 2x faster
    than column-wise numpy. Otherwise element-wise float32 arithmetic, column by column: an
    (N, 3) @ (3, 3) product would go to BLAS, whose threads oversubscribe the CPU when several
    DataLoader workers each run one (measured 6x slower with 2 workers on 2 cores). The identity
    (e.g. KITTI's ego = velodyne) costs nothing.
    """
    if _is_identity(target_T_source):
        return
    n_fields = array.shape[1]
    if n_fields <= 4 and array.flags.c_contiguous and len(array):
        rows = array.reshape(-1, 1, n_fields)
        moved = cv2.transform(rows, _affine(target_T_source, n_fields), dst=rows)
        if moved is not rows:  # OpenCV allocated instead of writing in place
            rows[...] = moved
        return
    rotation = target_T_source.rotation.astype(np.float32)
    translation = target_T_source.translation.astype(np.float32)
    columns = [np.ascontiguousarray(array[:, j]) for j in range(3)]
    for i in range(3):
        row = columns[0] * rotation[i, 0]
        row += columns[1] * rotation[i, 1]
        row += columns[2] * rotation[i, 2]
        row += translation[i]
        array[:, i] = row


def _affine(target_T_source: Transform, n_fields: int) -> np.ndarray:
    """(F, F + 1) matrix moving x, y, z by ``target_T_source`` and keeping the other F - 3 fields."""
    matrix = np.eye(n_fields, n_fields + 1)
    matrix[:3, :3] = target_T_source.rotation
    matrix[:3, n_fields] = target_T_source.translation
    return matrix


def class_indices(classes: np.ndarray, names: tuple[str, ...]) -> np.ndarray:
    """(N,) int64 index of each class name (N,) in ``names`` (non-empty), -1 for a class not there."""
    order = np.argsort(names)
    sorted_names = np.asarray(names)[order]
    at = np.minimum(np.searchsorted(sorted_names, classes), len(names) - 1)
    found: np.ndarray = np.where(sorted_names[at] == classes, order[at], -1).astype(np.int64)
    return found


def decode_image(data: bytes, where: str) -> np.ndarray:
    """(C, H, W) uint8 RGB(A) or (1, H, W) grey array from encoded PNG/JPEG bytes (OpenCV, BGR converted)."""
    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"{where}: image bytes could not be decoded by OpenCV")
    if image.dtype != np.uint8:
        raise InputError(f"{where}: expected an 8-bit image, got {image.dtype}")
    if image.ndim == 2:
        image = image[:, :, None]
    elif image.shape[2] == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    elif image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGBA)
    return image.transpose(2, 0, 1)


_ALIGN = 64
_TORCH_DTYPES = {np.dtype(np.float32): torch.float32, np.dtype(np.float64): torch.float64,
                 np.dtype(np.int64): torch.int64, np.dtype(bool): torch.bool, np.dtype(np.uint8): torch.uint8}


@dataclass(frozen=True, slots=True, kw_only=True)
class _Link:
    """What the ego holds of one agent at a frame.

    Attributes:
        agent: the agent.
        received: whether its data arrive at this frame.
        distance_m: its distance from the ego at the frame's time.
        frame_index: the frame of the transmission held (the current frame for the ego and without latency).
        time_ns: that frame's time.
        sensor_times: that frame's sensor message times.
        world_T_recorded: ``world_sent_T_world`` (see ``FrameDataset._pose_error``), None when the
            transmitted pose is the recorded one.
    """

    agent: str
    received: bool
    distance_m: float
    frame_index: int
    time_ns: int
    sensor_times: Mapping[str, int]
    world_T_recorded: Transform | None


@dataclass(frozen=True, slots=True, kw_only=True)
class _SensorCloud:
    """One sensor's cloud of an item: where to read it, its layout and its pose in the item's frame.

    Attributes:
        sensor: the sensor frame.
        time_ns: the message time.
        reader: the scene's reader (its bytes are read with ``points_into`` when the item is packed).
        stored: (N,) structured zero-copy view of the stored cloud; only its length and fields are used.
        frame_T_sensor: the pose of the sensor in the item's frame.
    """

    sensor: str
    time_ns: int
    reader: SceneReader
    stored: np.ndarray
    frame_T_sensor: Transform


@dataclass(frozen=True, slots=True, kw_only=True)
class _PendingCloud:
    """A cloud to write into the item's buffer: its sensors' clouds, the fields kept, the agents (fused only)."""

    members: list[_SensorCloud]
    names: tuple[str, ...]
    agents: list[str] | None

    @property
    def fields(self) -> tuple[str, ...]:
        return self.names + (("agent_index",) if self.agents is not None else ())

    @property
    def shape(self) -> tuple[int, int]:
        return sum(len(member.stored) for member in self.members), len(self.fields)

    def fill(self, out: np.ndarray, noise_std_m: Mapping[str, float], seeds: Mapping[str, list[int]],
             scratch: _Scratch) -> None:
        """Writes the clouds into ``out`` (N, F): fields, point noise in the sensor frame, pose, agent index.

        A packed float32 cloud whose fields are exactly the rows' (KITTI's x, y, z, intensity) is read
        straight into its rows (one ``preadv``) and moved there in place; any other cloud is read into
        ``scratch`` first, then its fields written into the rows.
        """
        start = 0
        for member in self.members:
            sensor, frame_T_sensor = member.sensor, member.frame_T_sensor
            rows = out[start : start + len(member.stored)]
            start += len(member.stored)
            if _packed_float32(member.stored, self.names) is not None and rows.shape[1] == len(self.names):
                member.reader.points_into(sensor, member.time_ns, rows)
                cloud = None
            else:
                cloud = member.reader.points_into(sensor, member.time_ns, scratch.take("cloud", member.stored.nbytes))
            if noise_std_m.get(sensor, 0.0) > 0.0:
                if cloud is not None:
                    _copy_fields(cloud, self.names, rows)
                rng = np.random.default_rng(seeds[sensor])
                rows[:, :3] += rng.normal(0.0, noise_std_m[sensor], size=(len(rows), 3)).astype(np.float32)
                transform_xyz_inplace(rows, frame_T_sensor)
            elif cloud is None:
                transform_xyz_inplace(rows, frame_T_sensor)
            else:
                _write_moved(cloud, self.names, rows, frame_T_sensor)
            if self.agents is not None:
                rows[:, -1] = self.agents.index(_agent_of(sensor))


class _Scratch:
    """Process-local byte buffers reused from item to item (grown when too small, never shared).

    A fresh buffer costs a page fault per 4 KiB page on first write; these are paid once per process.
    """

    def __init__(self) -> None:
        self._buffers: dict[str, np.ndarray] = {}

    def take(self, name: str, nbytes: int) -> np.ndarray:
        """(nbytes,) uint8 view of the buffer ``name``, 64-byte aligned; its former contents are garbage."""
        buffer = self._buffers.get(name, np.empty(0, dtype=np.uint8))
        if len(buffer) < nbytes + _ALIGN:
            # A quarter more than asked: batches of varying size reallocate rarely.
            buffer = self._buffers[name] = np.empty(nbytes + nbytes // 4 + _ALIGN, dtype=np.uint8)
        skip = -buffer.ctypes.data % _ALIGN
        return buffer[skip : skip + nbytes]


@dataclass(frozen=True, slots=True, kw_only=True)
class _Unpacked:
    """An item whose array leaves (and pending clouds) are not yet in a tensor buffer, with its point noise."""

    item: dict[str, Any]
    noise_std_m: Mapping[str, float]
    seeds: Mapping[str, list[int]]


def _pack(unpacked: list[_Unpacked], scratch: _Scratch) -> list[dict[str, Any]]:
    """The items with every array leaf turned into a tensor view of one buffer, clouds written in place.

    One buffer for all of them: inside a DataLoader worker it is put in shared memory, so the items
    reach the main process as one handle (torch passes one file descriptor per storage, a per-handle
    cost that dominates small tensors) and are never copied again (torch moves any other tensor into
    shared memory when it leaves the worker: a further copy). In a worker the items are assembled in
    ``scratch`` and then written into the shared memory in one call (see :func:`_to_shared_memory`).
    """
    leaves: list[tuple[dict[str, Any], str, np.ndarray | _PendingCloud, _Unpacked]] = []

    def collect(node: dict[str, Any], owner: _Unpacked) -> None:
        for key, value in node.items():
            if isinstance(value, dict):
                collect(value, owner)
            elif isinstance(value, (np.ndarray, _PendingCloud)):
                leaves.append((node, key, value, owner))

    for one in unpacked:
        collect(one.item, one)
    offsets, total = [], 0
    for _, _, value, _ in leaves:
        nbytes = int(np.prod(value.shape)) * (4 if isinstance(value, _PendingCloud) else value.dtype.itemsize)
        offsets.append((total, nbytes))
        total += -(-nbytes // _ALIGN) * _ALIGN
    in_worker = get_worker_info() is not None
    if in_worker:
        target = scratch.take("batch", total)
    else:
        buffer = torch.empty(total, dtype=torch.uint8)
        target = buffer.numpy()
    for (_, _, value, owner), (offset, nbytes) in zip(leaves, offsets, strict=True):
        array = target[offset : offset + nbytes].view(
            np.float32 if isinstance(value, _PendingCloud) else value.dtype).reshape(value.shape)
        if isinstance(value, _PendingCloud):
            value.fill(array, owner.noise_std_m, owner.seeds, scratch)
        else:
            array[...] = value
    if in_worker:
        buffer = _to_shared_memory(target)
    for (node, key, value, _), (offset, nbytes) in zip(leaves, offsets, strict=True):
        dtype = torch.float32 if isinstance(value, _PendingCloud) else _TORCH_DTYPES[value.dtype]
        node[key] = buffer[offset : offset + nbytes].view(dtype).view(value.shape)
    return [one.item for one in unpacked]


def _to_shared_memory(data: np.ndarray) -> torch.Tensor:
    """(B,) uint8 tensor in shared memory holding a copy of ``data`` (B,) uint8.

    With torch's default ``file_descriptor`` sharing on Linux the bytes go into a fresh ``memfd`` with
    one ``pwrite`` and the storage maps that file: the kernel fills the pages as it allocates them.
    Writing through a mapping instead costs a page fault per 4 KiB page, and torch's own
    ``UntypedStorage._new_shared`` also zero-fills every page first; for a 1.9 MB KITTI cloud that
    was ~2.4 ms against ~1.5 ms here (``benchmarks/loaders.py``). Another sharing strategy gets
    torch's own shared storage (which the strategy can pass on), filled through its mapping.
    """
    if not len(data):
        return torch.empty(0, dtype=torch.uint8)  # torch sends empty storages without shared memory
    if not hasattr(os, "memfd_create") or torch.multiprocessing.get_sharing_strategy() != "file_descriptor":
        buffer = torch.empty(0, dtype=torch.uint8).set_(torch.UntypedStorage._new_shared(len(data)))
        buffer.numpy()[...] = data
        return buffer
    fd = os.memfd_create("avdata-items", os.MFD_CLOEXEC)
    try:
        os.ftruncate(fd, len(data))
        written = 0
        while written < len(data):  # pwrite may write less than asked
            written += os.pwrite(fd, data[written:].data, written)
        # torch's own receiving side (rebuild_storage_fd) builds its storage the same way; it maps a duplicate of fd
        storage = torch.UntypedStorage._new_shared_fd_cpu(fd, len(data))  # type: ignore[attr-defined]
    finally:
        os.close(fd)
    return torch.empty(0, dtype=torch.uint8).set_(storage)


def _write_moved(cloud: np.ndarray, names: tuple[str, ...], out: np.ndarray, target_T_sensor: Transform) -> None:
    """Writes fields ``names`` of a cloud (N,) held in scratch memory into the first columns of ``out`` (N, F), x, y, z moved.

    A packed float32 cloud of at most 4 fields is moved in place (one ``cv2.transform`` pass), then
    copied in; other clouds are copied, then moved in place.
    """
    packed = _packed_float32(cloud, names)
    if packed is None or len(names) > 4:
        _copy_fields(cloud, names, out)
        transform_xyz_inplace(out, target_T_sensor)
        return
    transform_xyz_inplace(packed, target_T_sensor)
    _copy_columns(packed, out)


def _copy_fields(cloud: np.ndarray, names: tuple[str, ...], out: np.ndarray) -> None:
    """Writes fields ``names`` of a structured cloud (N,) into the first columns of ``out`` (N, F) as float32."""
    packed = _packed_float32(cloud, names)
    if packed is not None:
        _copy_columns(packed, out)
        return
    for i, name in enumerate(names):
        out[:, i] = cloud[name]


def _copy_columns(packed: np.ndarray, out: np.ndarray) -> None:
    """Writes rows (N, F) into the first F columns of ``out`` (N, G), both C-contiguous float32.

    Rows wider than the source (fused clouds: F = 4 fields and an agent index) are filled with
    OpenCV's ``mixChannels``, 3.5x faster than numpy's strided copy (0.47 against 1.7 ms for 60k points).
    """
    n_fields, width = packed.shape[1], out.shape[1]
    if n_fields == width:
        np.copyto(out, packed)
    elif len(packed):
        cv2.mixChannels([packed.reshape(-1, 1, n_fields)], [out.reshape(-1, 1, width)],
                        [channel for i in range(n_fields) for channel in (i, i)])


def _packed_float32(cloud: np.ndarray, names: tuple[str, ...]) -> np.ndarray | None:
    """(N, F) float32 view of a structured cloud whose fields are exactly ``names``, packed float32; else None."""
    fields: Mapping[str, Any] = cloud.dtype.fields or {}
    packed = cloud.dtype.itemsize == 4 * len(names) and all(
        name in fields and fields[name][0] == np.dtype("<f4") and fields[name][1] == 4 * i for i, name in enumerate(names)
    )
    if not packed or not cloud.flags.c_contiguous:
        return None
    return cloud.view(np.float32).reshape(len(cloud), len(names))


def _is_identity(transform: Transform) -> bool:
    return not transform.translation.any() and bool((transform.rotation == _EYE3).all())


def _common_fields(clouds: Iterable[np.ndarray]) -> tuple[str, ...]:
    """The fields every cloud has, in the first cloud's order (x, y, z at least)."""
    names = [tuple(cloud.dtype.names or ()) for cloud in clouds]
    if not names:
        return _XYZ
    return tuple(name for name in names[0] if all(name in other for other in names[1:]))


def _calibration_dict(calibration: Any) -> dict[str, Any]:
    return {
        "K": np.asarray(calibration.K, dtype=np.float64).reshape(3, 3),
        "D": np.asarray(calibration.D, dtype=np.float64),
        "R": np.asarray(calibration.R, dtype=np.float64).reshape(3, 3),
        "P": np.asarray(calibration.P, dtype=np.float64).reshape(3, 4),
        "width": int(calibration.width),
        "height": int(calibration.height),
        "distortion_model": str(calibration.distortion_model),
    }


def _projection(calibration: Any, camera_T_frame: Transform) -> np.ndarray:
    """(3, 4) ``P[:, :3] @ [R | 0] @ camera_T_frame`` (module docstring: why P's 4th column is dropped)."""
    R = np.asarray(calibration.R, dtype=np.float64).reshape(3, 3)
    P = np.asarray(calibration.P, dtype=np.float64).reshape(3, 4)
    return P[:, :3] @ R @ camera_T_frame.as_matrix()[:3, :]


def _last_transmission(times_ns: np.ndarray, latest_ns: int, rate_hz: float | None) -> int | None:
    """Index of the last sending frame in ``times_ns`` (sorted) at or before ``latest_ns``, or None.

    An agent of rate ``rate_hz`` sends in the first frame of each slot; None sends every frame.
    """
    k = int(np.searchsorted(times_ns, latest_ns, side="right")) - 1
    if rate_hz is not None:
        while k >= 0 and not _opens_slot(int(times_ns[0]), int(times_ns[k - 1]) if k else -1, int(times_ns[k]), rate_hz):
            k -= 1
    return k if k >= 0 else None


def _opens_slot(start_ns: int, prev_ns: int, time_ns: int, rate_hz: float) -> bool:
    """Whether the frame at ``time_ns`` is the first of a new 1/rate slot counted from ``start_ns``."""
    if prev_ns < 0:
        return True
    period_ns = 1e9 / rate_hz
    return int((time_ns - start_ns) // period_ns) > int((prev_ns - start_ns) // period_ns)


def _agent_of(sensor: str) -> str:
    return sensor.split("/", 1)[0]


def _matches(name: str, patterns: tuple[str, ...]) -> bool:
    return any(fnmatch.fnmatchcase(name, p) for p in patterns)
