"""The stages of a study run: detect -> track -> predict, each a component a case chooses, each timed.

A detection stage yields one :class:`FrameInput` per frame of the scene, its detections already in ``world``:

* ``simulated``: :class:`~avdata.perception.collaboration.CollaborativePerception` (the ego's noisy ground
  truth, plus collaborators' within range), or with a ``camera``, :class:`~avdata.perception.camera.CameraPerception`
  (what that camera sees, with each detection's 2D box in its image);
* ``model``: a :class:`~avdata.perception.detector.Detector` over the scene's
  :class:`~avdata.loaders.FrameDataset` items (every ego cloud, in the ego frame), moved to ``world``
  through the frame graph;
* ``files``: a detector's published results, read by :func:`avdata.perception.detection_files.read_detections`
  and moved to ``world`` from the frame they name.

The tracker and the predictor are the case's (``kalman`` / ``constant-velocity``, or a factory by name).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pyarrow.compute as pc

from avdata.errors import InputError
from avdata.perception.camera import CameraPerception
from avdata.perception.collaboration import CollaborationConfig, CollaborativePerception
from avdata.perception.detections import Detections
from avdata.perception.detector import detect_items, load_callable, load_detector
from avdata.perception.predictor import predict_constant_velocity
from avdata.perception.tracker import Tracker, Tracks, load_tracker
from avdata.schema import DatasetReader, SceneReader
from avdata.studies.config import CONSTANT_VELOCITY, CaseConfig, EvaluationConfig

__all__ = ["FrameInput", "SceneFrames", "StageTimer", "detection_stage", "make_predictor", "make_tracker"]

#: (tracks, horizon_steps, step_s) -> (N, T, 2) future x, y in the tracks' frame.
Predictor = Callable[[Tracks, int, float], np.ndarray]


@dataclass(frozen=True, slots=True)
class FrameInput:
    """What the tracker gets at one frame.

    Attributes:
        frame_index: the dataset's frame index.
        timestamp_ns: the frame's time.
        detections: the ego's (merged) detections in ``world``.
        sensors_in_range: collaborating sensors in range (simulated collaboration; else 0).
        collaborative_detections: detections received from collaborators (else 0).
    """

    frame_index: int
    timestamp_ns: int
    detections: Detections
    sensors_in_range: int = 0
    collaborative_detections: int = 0


@dataclass(slots=True)
class StageTimer:
    """Wall seconds spent in each stage of one run (kept beside the result, never in it: times are not inputs)."""

    seconds: dict[str, float] = field(default_factory=dict)

    def add(self, stage: str, start: float) -> None:
        """Adds the time since ``start`` (a ``time.perf_counter()``) to ``stage``."""
        self.seconds[stage] = self.seconds.get(stage, 0.0) + time.perf_counter() - start


@dataclass(frozen=True, slots=True)
class SceneFrames:
    """A detection stage over one scene.

    Attributes:
        frames: the per-frame inputs, lazily (timed by the caller).
        own_object_ids: ground-truth objects that are agents themselves (never detected, never scored).
        frame_rate_hz: the scene's frame rate.
        camera: the camera whose image the detections' ``extras["box2d_px"]`` are in (None: no 2D boxes).
    """

    frames: Iterator[FrameInput]
    own_object_ids: tuple[str, ...]
    frame_rate_hz: float
    camera: str | None = None


def detection_stage(ds: DatasetReader, scene: str, case: CaseConfig, evaluation: EvaluationConfig, *, ego: str,
                    seed: int) -> SceneFrames:
    """The case's detection stage over ``scene``."""
    kind = case.detector.kind
    if kind == "simulated" and case.detector.cameras:
        return _camera_stage(ds, scene, case, evaluation, seed)
    if kind == "simulated":
        config = CollaborationConfig(ego=ego, ego_noise=case.ego_noise, comm_range_m=case.comm_range_m,
                                     rate_hz=case.rate_hz, latency_frames=case.latency_frames, noise=case.noise,
                                     max_range_m=evaluation.max_range_m, seed=seed)
        perception = CollaborativePerception(ds, scene, config)
        graph = perception.graph

        def simulated() -> Iterator[FrameInput]:
            for d in perception.run():
                world = d.detections.to("world", graph.lookup("world", ego, d.timestamp_ns))
                yield FrameInput(d.frame_index, d.timestamp_ns, world, d.sensors_in_range, d.collaborative_detections)

        return SceneFrames(simulated(), tuple(perception.own_object_ids), perception.frame_rate_hz)
    reader = ds.scene(scene)
    graph = reader.graph
    agents = reader.metadata.get("agents", {})
    own = tuple(sorted(str(a["object_id"]) for a in agents.values() if isinstance(a, dict) and "object_id" in a))
    frames = ds.frames().filter(pc.equal(ds.frames()["scene"], scene))
    times = frames["timestamp_ns"].to_numpy().astype(np.int64)
    rate_hz = _frame_rate_hz(times)
    found = (_model_frames(ds, scene, case, evaluation, ego) if kind == "model"
             else _file_frames(ds, scene, case, frames["frame_index"].to_numpy(), times))
    camera = _camera_of(reader, case) if case.detector.cameras else None
    return SceneFrames(_scored(found, case.detector.min_score), own, rate_hz, camera)


def _camera_of(reader: SceneReader, case: CaseConfig) -> str:
    """The first of the case's cameras that the scene has."""
    cameras = sorted(name for name, spec in reader.sensors().items() if spec.get("kind") == "camera")
    found = next((c for c in case.detector.cameras if c in cameras), None)
    if found is None:
        raise InputError(f"case {case.name}: detector.camera: scene {reader.name!r} has none of "
                         f"{list(case.detector.cameras)}; its cameras are {cameras}")
    return found


def _camera_stage(ds: DatasetReader, scene: str, case: CaseConfig, evaluation: EvaluationConfig,
                  seed: int) -> SceneFrames:
    """The simulated camera detector over ``scene`` (2D boxes where the scene has the camera's calibration)."""
    camera = _camera_of(ds.scene(scene), case)
    perception = CameraPerception(ds, scene, camera, case.ego_noise, max_range_m=evaluation.max_range_m, seed=seed)
    frames = (FrameInput(f.frame_index, f.timestamp_ns, f.detections) for f in perception.run())
    return SceneFrames(frames, tuple(perception.own_object_ids), _frame_rate_hz(perception.timestamp_ns),
                       camera if perception.has_2d_boxes else None)


def _frame_rate_hz(times: np.ndarray) -> float:
    """Frames per second of a scene from its frame times (10 Hz for a single frame)."""
    return float(1e9 / np.median(np.diff(times))) if len(times) > 1 else 10.0


def _scored(frames: Iterator[FrameInput], min_score: float | None) -> Iterator[FrameInput]:
    """The frames with detections scored below ``min_score`` dropped (None: all kept)."""
    for frame in frames:
        if min_score is not None:
            frame = replace(frame, detections=frame.detections.select(frame.detections.scores >= min_score))
        yield frame


def _within(detections: Detections, max_range_m: float) -> Detections:
    """The detections within ``max_range_m`` (BEV) of the origin of their frame (the ego: AVstack's preprocessing)."""
    return detections.select(np.hypot(detections.boxes.center[:, 0], detections.boxes.center[:, 1]) <= max_range_m)


def _model_frames(ds: DatasetReader, scene: str, case: CaseConfig, evaluation: EvaluationConfig,
                  ego: str) -> Iterator[FrameInput]:
    from avdata.loaders import FrameDataset

    detector = load_detector(str(case.detector.callable), case.detector.checkpoint)
    frames = FrameDataset(ds.root, frame=ego, scenes=[scene], annotated_only=False)
    graph = ds.scene(scene).graph
    batch = max(1, int(getattr(detector, "batch_size", 1)))
    for start in range(0, len(frames), batch):
        items = [frames[i] for i in range(start, min(start + batch, len(frames)))]
        with _one_thread():
            detected = detect_items(detector, items)
        for item, found in zip(items, detected, strict=True):
            if found.boxes.frame != ego:
                raise InputError(f"detector {case.detector.callable}: expected detections in the item's frame "
                                 f"{ego!r}, got {found.boxes.frame!r}")
            t = int(item["timestamp_ns"])
            world = _within(found, evaluation.max_range_m).to("world", graph.lookup("world", ego, t))
            yield FrameInput(int(item["frame_index"]), t, world)


@contextmanager
def _one_thread() -> Iterator[None]:
    """Runs torch on one thread while a model detects, so the results are the same bytes on any executor.

    A convolution's sums add in an order that depends on the thread count (Ray workers run one thread, a
    local process as many as there are cores); the last bits of the boxes, and of every metric, followed it.
    """
    torch = sys.modules.get("torch")
    if torch is None:
        yield
        return
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def _file_frames(ds: DatasetReader, scene: str, case: CaseConfig, frame_index: np.ndarray,
                 times: np.ndarray) -> Iterator[FrameInput]:
    from avdata.perception.detection_files import read_detections

    found = read_detections(Path(str(case.detector.path)), str(case.detector.format))
    if found.problems:
        raise InputError(f"{case.detector.path}: {len(found.problems)} unreadable detection record(s); first: "
                         f"{found.problems[0]}")
    reader = ds.scene(scene)
    # Result files name scenes as their dataset does (KITTI: the sequence number "0001").
    names = [scene, str(reader.metadata.get("kitti_sequence", scene))]
    per_frame = next((found.scenes[n] for n in names if n in found.scenes), None)
    if per_frame is None:
        raise InputError(f"{case.detector.path}: no detections of scene {scene!r} (as {sorted(set(names))}); "
                         f"the files hold {sorted(found.scenes)[:5]}")
    if case.detector.cameras and per_frame and "box2d_px" not in next(iter(per_frame.values())).extras:
        raise InputError(f"case {case.name}: detector.camera: the {case.detector.format} detections of "
                         f"{case.detector.path} carry no 2D boxes")
    graph = reader.graph
    # A frame without detections is the files' empty selection: the same frame and extras (a 2D box, the raw
    # score) as every other frame, which the tracker expects of one detector.
    none = next(iter(per_frame.values())).select(np.zeros(0, np.int64)) if per_frame else None
    for index, t in zip(frame_index.tolist(), times.tolist(), strict=True):
        detections = per_frame.get(int(index), none)
        if detections is None:
            yield FrameInput(int(index), int(t), Detections.empty("world", int(t)))
            continue
        # The files' own times are nominal; the dataset's time of the frame places them in the graph.
        world = detections.to("world", graph.lookup("world", detections.boxes.frame, int(t)))
        yield FrameInput(int(index), int(t), replace(world, timestamp_ns=int(t)))


def make_tracker(case: CaseConfig) -> Tracker:
    """A fresh tracker of the case (one per scene)."""
    return load_tracker(case.tracker, f"case {case.name}: tracker")


def make_predictor(case: CaseConfig) -> Predictor:
    """The case's predictor."""
    if case.predictor == CONSTANT_VELOCITY:
        return predict_constant_velocity
    return load_callable(case.predictor, f"case {case.name}: predictor")
