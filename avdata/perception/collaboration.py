"""Collaborative perception: which sensors' detections reach the ego, moved into the ego frame through the graph.

Per frame, the ego's own lidars always detect (noise ``ego_noise``). A collaborator's sensor (an
infrastructure lidar, or another vehicle's) sends its detections when its horizontal distance to the ego is
at most ``comm_range_m`` and the frame falls on its send period (``frame_rate / rate_hz`` frames); they arrive
``latency_frames`` later. Every detection is moved sensor -> ``world`` at its measurement time and
``world`` -> ego at its arrival time through the scene's :class:`~avdata.frames.FrameGraph` (no hand-written
transforms). The ego keeps detections within ``max_range_m`` of itself (AVstack's preprocessing) and merges
detections of one class whose BEV centres lie within ``merge_distance_m`` (greedy by score, score-weighted
centre, the best detection's size and orientation), so an object seen by several sensors is one measurement.
"""

from __future__ import annotations

import fnmatch
from collections import deque
from dataclasses import dataclass, replace

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from avdata.errors import InputError
from avdata.frames import Boxes3D
from avdata.perception.detections import NOISE_LEVELS, Detections, DetectionSimulator, NoiseModel, rng_for
from avdata.schema import DatasetReader
from avdata.schema.records import required_ids_and_classes

__all__ = ["CollaborationConfig", "CollaborativePerception", "FrameDelivery", "boxes_by_frame", "merge_detections"]


@dataclass(frozen=True, slots=True, kw_only=True)
class CollaborationConfig:
    """One collaboration case.

    Attributes:
        ego: the receiving agent.
        ego_noise: noise level name (:data:`~avdata.perception.detections.NOISE_LEVELS`) of the ego's own detections.
        collaborators: glob over agent names whose lidars may send (``"infra_*"``).
        comm_range_m: communication range; ``None`` means no collaboration (the base case).
        rate_hz: how often collaborators send.
        latency_frames: frames between a collaborator's measurement and its arrival at the ego.
        noise: noise level name of the collaborators' detections.
        min_points: lidar returns an object needs in a sensor's view to be detectable by it.
        max_range_m: the ego ignores detections farther than this from itself.
        merge_distance_m: detections of one class closer than this (BEV) are merged.
        seed: seed of every random draw (with frame and sensor).
    """

    ego: str = "ego"
    ego_noise: str = "low"
    collaborators: str = "infra_*"
    comm_range_m: float | None = None
    rate_hz: float = 10.0
    latency_frames: int = 0
    noise: str = "none"
    min_points: int = 1
    max_range_m: float = 100.0
    merge_distance_m: float = 1.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("ego_noise", "noise"):
            if getattr(self, name) not in NOISE_LEVELS:
                raise InputError(f"collaboration: expected {name} in {sorted(NOISE_LEVELS)}, got {getattr(self, name)!r}")
        if self.comm_range_m is not None and not (self.comm_range_m >= 0):
            raise InputError(f"collaboration: expected comm_range_m >= 0 or none, got {self.comm_range_m!r}")
        if not (self.rate_hz > 0):
            raise InputError(f"collaboration: expected rate_hz > 0, got {self.rate_hz!r}")
        if self.latency_frames < 0:
            raise InputError(f"collaboration: expected latency_frames >= 0, got {self.latency_frames!r}")


@dataclass(frozen=True, slots=True, kw_only=True)
class FrameDelivery:
    """What the ego has at one frame.

    Attributes:
        frame_index: the frame.
        timestamp_ns: its time.
        detections: merged detections in the ego frame.
        sensors_in_range: collaborator sensors within communication range at this frame.
        collaborative_detections: detections received from collaborators at this frame (before merging).
    """

    frame_index: int
    timestamp_ns: int
    detections: Detections
    sensors_in_range: int
    collaborative_detections: int


def merge_detections(detections: Detections, merge_distance_m: float) -> Detections:
    """Merges detections of one class whose BEV centres are within ``merge_distance_m`` (greedy by score)."""
    n = len(detections)
    if n < 2 or merge_distance_m <= 0:
        return detections
    order = np.argsort(-detections.scores, kind="stable")
    centre = detections.boxes.center[order]
    classes = np.asarray(detections.boxes.classes)[order]
    scores = detections.scores[order]
    close = np.hypot(*(centre[:, None, :2] - centre[None, :, :2]).transpose(2, 0, 1)) <= merge_distance_m
    close &= classes[:, None] == classes[None, :]
    owner = np.full(n, -1)
    for i in range(n):  # greedy clustering: at most a few hundred detections per frame
        if owner[i] < 0:
            owner[np.flatnonzero(close[i] & (owner < 0))] = i
    leaders = np.flatnonzero(owner == np.arange(n))
    weight = np.zeros((len(leaders), n))
    weight[np.searchsorted(leaders, owner), np.arange(n)] = scores
    merged_centre = (weight @ centre) / weight.sum(axis=1, keepdims=True)
    kept = detections.select(order[leaders])
    boxes = replace(kept.boxes, center=merged_centre)
    return replace(kept, boxes=boxes)


class CollaborativePerception:
    """Simulated detections that reach the ego in one scene of a unified dataset, frame by frame.

    Args:
        dataset: the unified dataset (with visibility labels per sensor).
        scene: the scene name.
        config: the collaboration case.
    """

    def __init__(self, dataset: DatasetReader, scene: str, config: CollaborationConfig):
        self.config = config
        self.scene = scene
        reader = dataset.scene(scene)
        self.graph = reader.graph
        frames = dataset.frames().filter(pc.equal(dataset.frames()["scene"], scene))
        if len(frames) == 0:
            raise InputError(f"{dataset.root}: expected scene {scene!r} in index/frames.parquet, got no rows")
        self.frame_index = frames["frame_index"].to_numpy().astype(np.int64)
        self.timestamp_ns = frames["timestamp_ns"].to_numpy().astype(np.int64)
        sensors = reader.sensors()
        lidars = sorted(name for name, spec in sensors.items() if spec.get("kind") == "lidar")
        self.ego_sensors = [s for s in lidars if s.split("/")[0] == config.ego]
        if not self.ego_sensors:
            raise InputError(f"{scene}: expected a lidar of agent {config.ego!r}, got lidars {lidars}")
        self.collaborator_sensors = [s for s in lidars if s.split("/")[0] != config.ego
                                     and fnmatch.fnmatchcase(s.split("/")[0], config.collaborators)]
        self._specs = {s: sensors[s] for s in lidars}
        self._sensor_index = {s: i for i, s in enumerate(lidars)}
        agents = reader.metadata.get("agents", {})
        #: Object ids that are agents themselves (a vehicle agent's own box is not something it detects).
        self.own_object_ids = sorted(str(a["object_id"]) for a in agents.values() if isinstance(a, dict) and "object_id" in a)
        objects = dataset.objects().filter(pc.equal(dataset.objects()["scene"], scene))
        objects = objects.filter(pc.invert(pc.is_in(objects["object_id"], pa.array(self.own_object_ids, pa.string()))))
        self._objects = boxes_by_frame(objects)
        vis = dataset.visibility().filter(pc.equal(dataset.visibility()["scene"], scene))
        self._visibility = _by_frame_sensor(vis)
        self.frame_rate_hz = _frame_rate_hz(self.timestamp_ns)
        self.send_period_frames = _send_period_frames(self.frame_rate_hz, config.rate_hz, scene)

    def _simulator(self, sensor: str, noise: NoiseModel) -> DetectionSimulator:
        spec = self._specs[sensor]
        return DetectionSimulator(noise=noise, min_points=self.config.min_points,
                                  max_range_m=float(spec.get("max_range_m", 100.0)),
                                  horizontal_fov_deg=float(spec.get("horizontal_fov_deg", 360.0)))

    def _detect(self, sensor: str, frame: int, t_ns: int, noise: NoiseModel) -> Detections:
        gt = self._objects.get(frame)
        if gt is None or not len(gt):
            return Detections.empty(sensor, t_ns)
        n_points, occlusion = self._visibility_of(frame, sensor, gt)
        world_T_sensor = self.graph.lookup("world", sensor, t_ns)
        rng = rng_for(self.config.seed, self.scene, frame, self._sensor_index[sensor])
        return self._simulator(sensor, noise).detect(gt, n_points, occlusion, world_T_sensor, sensor, t_ns, rng)

    def _visibility_of(self, frame: int, sensor: str, gt: Boxes3D) -> tuple[np.ndarray, np.ndarray]:
        """(N,) lidar returns and occlusion of each ground-truth box as this sensor saw it.

        A sensor without visibility labels of its own (KITTI labels what camera 2 sees, not the velodyne)
        borrows its agent's other sensors' labels; an unknown point count (-1) in the field of view counts as seen.
        """
        rows = self._visibility.get((frame, sensor))
        if rows is None:
            agent = sensor.split("/")[0]
            borrowed = [v for (f, s), v in self._visibility.items() if f == frame and s.split("/")[0] == agent]
            rows = tuple(np.concatenate([b[i] for b in borrowed]) for i in range(3)) if borrowed else None  # type: ignore[assignment]  # three arrays, as stored
        if rows is None or not len(rows[0]):
            return np.zeros(len(gt), np.int64), np.full(len(gt), 3)
        ids, n_points, occlusion = rows
        n_points = np.where(n_points < 0, self.config.min_points, n_points)
        order = np.lexsort((occlusion, ids))  # per id, the best (lowest) occlusion first
        ids, n_points, occlusion = ids[order], n_points[order], occlusion[order]
        gt_ids = required_ids_and_classes(gt)[0]
        pos = np.clip(np.searchsorted(ids, gt_ids), 0, len(ids) - 1)
        found = ids[pos] == gt_ids
        return np.where(found, n_points[pos], 0), np.where(found, occlusion[pos], 3)

    def run(self) -> list[FrameDelivery]:
        """The ego's detections at every frame, in order."""
        cfg = self.config
        ego_noise, noise = NOISE_LEVELS[cfg.ego_noise], NOISE_LEVELS[cfg.noise]
        in_flight: deque[tuple[int, Detections]] = deque()
        out = []
        for frame, t_ns in zip(self.frame_index.tolist(), self.timestamp_ns.tolist(), strict=True):
            world_T_ego = self.graph.lookup("world", cfg.ego, t_ns)
            ego_T_world = world_T_ego.inverse()
            parts = []
            for sensor in self.ego_sensors:
                own = self._detect(sensor, frame, t_ns, ego_noise)
                parts.append(own.to(cfg.ego, self.graph.lookup(cfg.ego, sensor, t_ns)))
            in_range = 0
            if cfg.comm_range_m is not None:
                for sensor in self.collaborator_sensors:
                    sensor_xy = self.graph.lookup("world", sensor, t_ns).translation[:2]
                    if np.hypot(*(sensor_xy - world_T_ego.translation[:2])) > cfg.comm_range_m:
                        continue
                    in_range += 1
                    if frame % self.send_period_frames:
                        continue
                    sent = self._detect(sensor, frame, t_ns, noise)
                    in_flight.append((frame + cfg.latency_frames, sent.to("world", self.graph.lookup("world", sensor, t_ns))))
            received = []
            while in_flight and in_flight[0][0] <= frame:
                received.append(in_flight.popleft()[1].to(cfg.ego, ego_T_world))
            n_received = sum(len(r) for r in received)
            dets = Detections.concatenate(parts + received, cfg.ego, t_ns)
            dets = dets.select(np.hypot(dets.boxes.center[:, 0], dets.boxes.center[:, 1]) <= cfg.max_range_m)
            out.append(FrameDelivery(frame_index=frame, timestamp_ns=t_ns,
                                     detections=merge_detections(dets, cfg.merge_distance_m),
                                     sensors_in_range=in_range, collaborative_detections=n_received))
        return out


#: How far a send period may be from a whole number of frames: real logs' frame times jitter by a few percent.
PERIOD_TOLERANCE = 0.01


def _send_period_frames(frame_rate_hz: float, rate_hz: float, scene: str) -> int:
    """The frames between a collaborator's sends; a rate the frames cannot honour is refused.

    A collaborator sends on whole frames: 3 Hz in a 10 Hz scene ran at 3.33 Hz, and 1000 Hz at 10 Hz, while the
    study's report said 3 and 1000.
    """
    period = frame_rate_hz / rate_hz
    if round(period) < 1 or abs(period - round(period)) > PERIOD_TOLERANCE * period:
        raise InputError(f"{scene}: collaboration rate_hz: expected the frame rate {frame_rate_hz:.4g} Hz divided by a "
                         f"whole number (collaborators send on whole frames), got {rate_hz:g}")
    return int(round(period))


def _frame_rate_hz(timestamp_ns: np.ndarray) -> float:
    if len(timestamp_ns) < 2:
        return 10.0
    step = float(np.median(np.diff(timestamp_ns)))
    if step <= 0:
        raise InputError(f"expected increasing frame times, got a median step of {step} ns")
    return 1e9 / step


def _col(table: pa.Table, name: str) -> np.ndarray:
    values: np.ndarray = table[name].to_numpy(zero_copy_only=False)
    return values


def boxes_by_frame(objects: pa.Table) -> dict[int, Boxes3D]:
    """Per frame index: the rows of an objects table (index/objects.parquet columns) as boxes in ``world``."""
    frame = _col(objects, "frame_index").astype(np.int64)
    centre = np.stack([_col(objects, c).astype(float) for c in ("x_world_m", "y_world_m", "z_world_m")], axis=1)
    size = np.stack([_col(objects, c).astype(float) for c in ("length_m", "width_m", "height_m")], axis=1)
    quat = np.stack([_col(objects, c).astype(float) for c in ("qw_world", "qx_world", "qy_world", "qz_world")], axis=1)
    ids, classes = _col(objects, "object_id").astype(str), _col(objects, "class").astype(str)
    out = {}
    for f, i in _groups(frame):
        out[int(f)] = Boxes3D(center=centre[i], size_lwh=size[i], quat_wxyz=quat[i], frame="world", ids=ids[i],
                              classes=classes[i])
    return out


def _by_frame_sensor(vis: pa.Table) -> dict[tuple[int, str], tuple[np.ndarray, np.ndarray, np.ndarray]]:
    frame = _col(vis, "frame_index").astype(np.int64)
    sensor = _col(vis, "sensor").astype(str)
    ids = _col(vis, "object_id").astype(str)
    in_fov = _col(vis, "in_fov").astype(bool)
    # -1 (unknown, e.g. labels of a camera) stays -1 in the field of view; outside it the sensor saw nothing.
    n_points = np.where(in_fov, _col(vis, "n_points").astype(np.int64), 0)
    occlusion = _col(vis, "occlusion").astype(np.int64)
    key = np.char.add(np.char.add(frame.astype(str), "\x1f"), sensor)
    out = {}
    for k, i in _groups(key):
        f, s = k.split("\x1f")
        out[(int(f), s)] = (ids[i], n_points[i], occlusion[i])
    return out


def _groups(key: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """(key, row indices) for each distinct key, rows in their original order."""
    if not len(key):
        return []
    order = np.argsort(key, kind="stable")
    uniq, start = np.unique(key[order], return_index=True)
    return list(zip(uniq.tolist(), np.split(order, start[1:]), strict=True))
