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


The modules beside this one hold the parts: :mod:`~avdata.loaders.frame_index` (which frames, in item
order), :mod:`~avdata.loaders.items` (boxes, images, calibrations and projections),
:mod:`~avdata.loaders.communication` (range, rate, latency and pose error),
:mod:`~avdata.loaders.fusion` (the intermediate and late layouts) and :mod:`~avdata.loaders.packing`
(every tensor of a batch is a view of one buffer, crossing from a DataLoader worker as one handle).
"""

from __future__ import annotations

import fnmatch
import operator
import zlib
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from torch.utils.data import Dataset

from avdata.errors import AvdataError
from avdata.loaders.communication import Link, links, sent
from avdata.loaders.frame_index import FrameIndex, VisibilityIndex
from avdata.loaders.fusion import per_agent_layout
from avdata.loaders.items import ItemFrame, calibration_dict, decode_image, frame_boxes, projection
from avdata.loaders.options import POINT_CLOUD_KINDS, Collaboration, FrameOptions, agent_of, as_patterns, matches
from avdata.loaders.packing import PendingCloud, Scratch, SensorCloud, Unpacked, common_fields, pack
from avdata.loaders.transforms import SceneTransforms
from avdata.schema import DatasetReader, SceneReader, topics
from avdata.schema.dataset import dataset_root, open_scene
from avdata.schema.index import VISIBILITY_SCHEMA
from avdata.storage import Location


class FrameDataset(Dataset[dict[str, Any]]):
    """One item per annotated frame of a unified dataset (see the module docstring for the item).

    ``FrameDataset(root)`` returns the ego's point clouds (every lidar and radar of the ego agent)
    with all labelled objects, in the ego frame. A frame without any such message (a labels-only
    dataset, or a gap in a sensor's recording) gives an item without points; name ``sensors`` to
    require them in every frame.

    Args:
        root: the dataset folder, or its prefix in an object store (``s3://bucket/prefix``, ``gs://...``):
            each scene is then read by ranged requests, its summary first, then only the chunks an item needs.
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
        cache_dir: for a dataset in a store, a local folder keeping the fetched scene bytes (None:
            ``$AVDATA_CACHE_DIR`` if set, else none); an object changed since is fetched again.

    Raises:
        AvdataError: an option is invalid, or a frame lacks a requested sensor or agent.
    """

    def __init__(
        self,
        root: str | Path | Location,
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
        cache_dir: str | Path | None = None,
    ):
        self.root = dataset_root(root)
        self.cache_dir = cache_dir
        options = options if options is not None else FrameOptions()
        if not isinstance(options, FrameOptions):
            raise AvdataError(f"expected options as a FrameOptions, got {type(options).__name__}")
        if sensors is not None:
            options = replace(options, sensors=as_patterns(sensors, "sensors"))
        if frame is not None:
            options = replace(options, frame=frame)
        if classes is not None:
            options = replace(options, labels=replace(options.labels, classes=as_patterns(classes, "classes") or ()))
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
        reader = DatasetReader(self.root, cache_dir=cache_dir)
        self.classes: tuple[str, ...] = self.options.labels.classes
        self._sensor_kind: dict[str, str] = {
            name: str(spec.get("kind", "")) for name, spec in reader.manifest.get("sensors", {}).items()
        }
        self._index = FrameIndex(self.root, reader.frames(), reader.scenes, scenes=scenes, split=split,
                                 annotated_only=annotated_only)
        needs_visibility = self.options.labels.visible_to is not None or collaboration is not None
        self._visibility = VisibilityIndex(reader.visibility() if needs_visibility else VISIBILITY_SCHEMA.empty_table())
        self._scenes_open: dict[str, tuple[SceneReader, SceneTransforms]] = {}
        self._scratch = Scratch()
        self._check_sensors()
        self._check_visible_to()

    # ----------------------------------------------------------------- dataset protocol
    def __len__(self) -> int:
        return len(self._index)

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
        for index in map(operator.index, indices):  # 1.5 is a TypeError, as for a list, not item 1
            if not -len(self) <= index < len(self):
                raise IndexError(f"expected an index in [0, {len(self)}), got {index}")
            position = int(index) % len(self)
            keys.append((str(self._index.scene[position]), int(self._index.frame_index[position])))
        return self.items(keys)

    def __getstate__(self) -> dict[str, Any]:
        state = {name: getattr(self, name) for name in self.__dict__}
        state["_scenes_open"] = {}
        state["_scratch"] = Scratch()
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)

    def keys(self) -> list[tuple[str, int]]:
        """(scene, frame_index) of every item, in item order."""
        return self._index.keys()

    def timestamp_ns(self, scene: str, frame_index: int) -> int:
        """The reference time of a frame of this dataset (the time of its labels), in ns."""
        return int(self._index.time_ns[self._index.position(scene, frame_index)])

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
        return pack([self._unpacked_item(scene, frame_index, reference) for scene, frame_index in keys], self._scratch)

    def _item_frame(self, scene: str, frame_index: int, reference: tuple[str, int] | None) -> ItemFrame:
        position = self._index.position(scene, frame_index)
        reader, transforms = self._open(scene)
        t_ref = int(self._index.time_ns[position])
        frame, t_frame = reference if reference is not None else (self.options.frame, t_ref)
        return ItemFrame(options=self.options, visibility=self._visibility, reader=reader, transforms=transforms,
                         scene=scene, frame_index=int(frame_index), time_ns=t_ref,
                         prev_time_ns=int(self._index.prev_time_ns[position]), ego=str(self._index.ego_frame[position]),
                         frame=frame, frame_time_ns=t_frame)

    def _unpacked_item(self, scene: str, frame_index: int, reference: tuple[str, int] | None) -> Unpacked:
        """The item with arrays and clouds still to be written into a buffer (see :func:`~avdata.loaders.packing.pack`)."""
        at = self._item_frame(scene, frame_index, reference)
        position = self._index.position(scene, frame_index)
        _, labels = at.reader.labels(frame_index)
        item: dict[str, Any] = {"scene": scene, "frame_index": frame_index, "timestamp_ns": at.time_ns, "frame": at.frame}
        sensor_times = self._index.sensor_times[position]
        collaboration = self.options.collaboration
        agents: list[str] | None = None
        received_agents: list[str] = []
        by_agent: dict[str, Link] = {}
        if collaboration is None:
            sensors = [(s, int(sensor_times[s])) if s in sensor_times else (s, -1) for s in self._sensors_of(position)]
        else:
            link_list = links(collaboration, at, self._agents_of(collaboration, position), self._index.scene_frames[scene])
            by_agent = {link.agent: link for link in link_list}
            agents = [link.agent for link in link_list]
            received_agents = [link.agent for link in link_list if link.received]
            sensors = [(s, int(by_agent[agent_of(s)].sensor_times[s])) for s in self._sensors_of(position)
                       if agent_of(s) in received_agents and s in by_agent[agent_of(s)].sensor_times]
            item.update(_link_keys(at, link_list))
        clouds = self._sensor_data(at, sensors, sensor_times, by_agent, item)
        fusion = collaboration.fusion if collaboration is not None else None
        points: dict[str, PendingCloud]
        if fusion == "early":
            points = {"fused": PendingCloud(members=clouds, names=common_fields(c.stored for c in clouds), agents=agents)}
        elif collaboration is not None and agents is not None and fusion in ("intermediate", "late"):
            points, per_agent = per_agent_layout(collaboration, at, agents, by_agent, clouds)
            item.update(per_agent)
        else:
            points = {c.sensor: PendingCloud(members=[c], names=tuple(c.stored.dtype.names or ()), agents=None)
                      for c in clouds}
        item.update(points=points, point_fields={key: cloud.fields for key, cloud in points.items()})
        captures = {link.agent: link.frame_index for link in by_agent.values() if link.received}
        item.update(frame_boxes(at, labels, agents, captures))
        noise: dict[str, float] = {}
        seeds: dict[str, list[int]] = {}
        if collaboration is not None:
            noise = {c.sensor: collaboration.noise_of(agent_of(c.sensor)) for c in clouds if agent_of(c.sensor) != at.ego}
            seeds = {s: [collaboration.seed, zlib.crc32(f"{scene}/{frame_index}/{s}".encode())] for s in noise}
        return Unpacked(item=item, noise_std_m=noise, seeds=seeds)

    def _sensor_data(self, at: ItemFrame, sensors: list[tuple[str, int]], sensor_times: dict[str, int],
                     by_agent: dict[str, Link], item: dict[str, Any]) -> list[SensorCloud]:
        """Adds the cameras' images, calibrations and projections and the sensor times to ``item``; the clouds to read."""
        images: dict[str, np.ndarray] = {}
        calibrations: dict[str, dict[str, Any]] = {}
        projections: dict[str, np.ndarray] = {}
        used_times: dict[str, int] = {}
        clouds: list[SensorCloud] = []
        reader = at.reader
        # From a store, the frame's sensor messages come in parallel requests, not one after another.
        suffix = {sensor: topics.IMAGE_SUFFIX if self._sensor_kind.get(sensor, "") == "camera" else topics.POINTS_SUFFIX
                  for sensor, _ in sensors}
        reader.prefetch((topics.sensor_topic(sensor, suffix[sensor]), t) for sensor, t in sensors if t >= 0)
        for sensor, t_sensor in sensors:
            if t_sensor < 0:
                raise AvdataError(f"scene {at.scene!r} frame {at.frame_index}: no message of sensor {sensor!r}; "
                                  f"has {sorted(sensor_times)}")
            used_times[sensor] = t_sensor
            frame_T_sensor = sent(by_agent.get(agent_of(sensor)), at.transforms, at.frame, at.frame_time_ns, sensor, t_sensor)
            if self._sensor_kind.get(sensor, "") == "camera":
                data, _ = reader.image(sensor, t_sensor)
                images[sensor] = decode_image(data, f"scene {at.scene!r} sensor {sensor!r} at {t_sensor} ns")
                calibration = reader.camera_calibration(sensor, t_sensor)
                calibrations[sensor] = calibration_dict(calibration)
                projections[sensor] = projection(calibration, frame_T_sensor.inverse())
            else:
                clouds.append(SensorCloud(sensor=sensor, time_ns=t_sensor, stored=reader.points(sensor, t_sensor),
                                          frame_T_sensor=frame_T_sensor))
        item.update(images=images, calibrations=calibrations, projections=projections, sensor_timestamps_ns=used_times)
        return clouds

    # ----------------------------------------------------------------- index helpers
    def _open(self, scene: str) -> tuple[SceneReader, SceneTransforms]:
        """This process's reader and memoised transforms of ``scene`` (opened on first use)."""
        opened = self._scenes_open.get(scene)
        if opened is None:
            reader = open_scene(self.root, scene, cache_dir=self.cache_dir)
            opened = (reader, SceneTransforms(reader.graph, self._index.scene_times[scene]))
            self._scenes_open[scene] = opened
        return opened

    def _sensors_of(self, position: int) -> list[str]:
        """The requested sensors present in a frame, in pattern order.

        Without sensor patterns: the point-cloud sensors of the ego (collaborative: of every agent),
        sorted.
        """
        available = sorted(self._index.sensor_times[position])
        if self.options.sensors is None:
            ego = str(self._index.ego_frame[position])
            return [s for s in available if self._sensor_kind.get(s, "") in POINT_CLOUD_KINDS
                    and (self.options.collaboration is not None or agent_of(s) == ego)]
        chosen: list[str] = []
        for pattern in self.options.sensors:
            chosen.extend(s for s in fnmatch.filter(available, pattern) if s not in chosen)
        return chosen

    def _agents_of(self, collaboration: Collaboration, position: int) -> list[str]:
        """Agents (sensor-frame prefixes and the ego) matching the agent patterns, the ego first.

        Never empty: the ego matches (checked at construction).
        """
        ego = str(self._index.ego_frame[position])
        names = {agent_of(s) for s in self._index.sensor_times[position]} | ({ego} if ego else set())
        matched = sorted(n for n in names if matches(n, collaboration.agents))
        return sorted(matched, key=lambda n: n != ego)

    def _check_sensors(self) -> None:
        """Every sensor pattern (collaborative: also the ego) must be found in every frame."""
        collaboration = self.options.collaboration
        for position in range(len(self)):
            available = sorted(self._index.sensor_times[position])
            where = (f"{self.root}: scene {str(self._index.scene[position])!r} "
                     f"frame {int(self._index.frame_index[position])}")
            sensors = self.options.sensors
            if sensors is None:
                pass  # the default takes whatever point clouds a frame has (module docstring)
            elif collaboration is None:
                for pattern in sensors:
                    if not fnmatch.filter(available, pattern):
                        raise AvdataError(f"{where}: expected a sensor matching {pattern!r}, got {available}")
            elif sensors and not any(matches(s, sensors) for s in available):
                raise AvdataError(f"{where}: expected a sensor matching {list(sensors)}, got {available}")
            if collaboration is not None:
                ego = str(self._index.ego_frame[position])
                if not ego or not matches(ego, collaboration.agents):
                    raise AvdataError(f"{where}: expected the ego agent {ego!r} among agents "
                                      f"{list(collaboration.agents)}")


    def _check_visible_to(self) -> None:
        """Every ``visible_to`` pattern must match a sensor of the dataset: a typo would drop every object.

        A sensor that saw nothing (no visibility rows) is a real answer, so the dataset's sensors are the
        manifest's, the index's and the visibility labels'.
        """
        sensors = set(self._sensor_kind) | {sensor for _, _, sensor in self._visibility.groups}
        sensors.update(*(times.keys() for times in self._index.sensor_times))
        for pattern in self.options.labels.visible_to or ():
            if not fnmatch.filter(sorted(sensors), pattern):
                raise AvdataError(f"{self.root}: expected a sensor matching visible_to {pattern!r}, got {sorted(sensors)}")


def _link_keys(at: ItemFrame, link_list: list[Link]) -> dict[str, Any]:
    """The collaborative keys of an item: agents, their poses as sent, distances, reception and transmission times."""
    poses = np.stack([sent(link, at.transforms, at.frame, at.frame_time_ns, link.agent, link.time_ns).as_matrix()
                      for link in link_list])
    return {"agents": [link.agent for link in link_list], "agent_poses": poses,
            "agent_distance_m": np.array([link.distance_m for link in link_list], dtype=np.float64),
            "agent_received": np.array([link.received for link in link_list], dtype=bool),
            "agent_timestamps_ns": np.array([link.time_ns for link in link_list], dtype=np.int64)}
