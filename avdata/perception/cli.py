"""``avdata track OUT --detections PATH --format FORMAT``: a tracker over a detector's result files, one per scene.

Detections are read by :func:`avdata.perception.detection_files.read_detections` and tracked in
``ego/cam0_flu`` (KITTI's rectified camera 0 turned upright: the files carry no poses, so this is the sensor
frame, as AB3DMOT tracks without ego motion). Each scene becomes ``OUT/<scene>.txt`` in KITTI's tracking
result format: the track's box, its id, and the 2D box and raw score of the detection that last updated it,
as AB3DMOT writes them; ``avdata eval tracking --protocol kitti`` or ``kitti-3dmot`` scores the folder.

A scene whose result file exists is skipped (resumable; ``--force`` redoes it); files are written under a
temporary name and renamed. Unreadable detection records are printed one per line and cost that record;
the exit status is then 1.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from avdata.errors import InputError
from avdata.executors.base import TaskFailure, make_executor
from avdata.inputs import UniqueKeyLoader
from avdata.outputs import write_atomically
from avdata.perception.detection_files import FORMATS, NON_KITTI_FORMATS, UPRIGHT_FRAME, camera_boxes, read_detections, upright
from avdata.perception.detections import Detections
from avdata.perception.tracker import ClassConfig, KalmanTracker, Tracker, TrackerConfig
from avdata.sources.kitti.detections import KittiDetectionRows, format_kitti_tracking_lines

__all__ = ["add_track_subparser", "load_tracker_config", "track_scene"]


def add_track_subparser(subparsers: Any) -> None:
    """Adds ``avdata track`` to the command line."""
    parser = subparsers.add_parser("track", help="track a detector's result files; write KITTI tracking results")
    parser.add_argument("out", type=Path, help="folder for <scene>.txt KITTI tracking results (created if missing)")
    parser.add_argument("--detections", type=Path, required=True, help="detection file or folder (required)")
    parser.add_argument("--format", required=True, choices=sorted(f for f in FORMATS if f not in NON_KITTI_FORMATS),
                        help="format of the detections (required; KITTI-style; the unified table is read by read_detections)")
    parser.add_argument("--tracker", default="kalman", help="'kalman' or MODULE:CALLABLE returning a tracker (default: kalman)")
    parser.add_argument("--config", type=Path, help="YAML of TrackerConfig fields (classes: {car: {...}}, ...) "
                        "(default: AB3DMOT's KITTI settings)")
    parser.add_argument("--scenes", nargs="+", help="only these scenes (default: every scene in the detections)")
    parser.add_argument("--workers", type=int, default=1, help="scenes tracked in parallel (default: 1)")
    parser.add_argument("--executor", default="local", choices=("local", "ray"),
                        help="where scenes run: local processes or a Ray cluster (default: local)")
    parser.add_argument("--force", action="store_true", help="redo scenes whose result file exists (default: keep them)")
    parser.set_defaults(run=_run_track)


@dataclass(frozen=True, slots=True)
class _Task:
    scene: str
    frames: dict[int, Detections]
    tracker: str
    config: TrackerConfig


def load_tracker_config(path: Path | None) -> TrackerConfig:
    """A :class:`TrackerConfig` from YAML (any subset of its fields; ``classes`` maps class -> ClassConfig fields)."""
    if path is None:
        return TrackerConfig()
    import yaml

    try:
        data = yaml.load(path.read_text(encoding="utf-8"), Loader=UniqueKeyLoader) or {}
    except (OSError, UnicodeDecodeError, ValueError, yaml.YAMLError) as error:
        raise InputError(f"{path}: cannot read tracker config ({' '.join(str(error).split())})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a mapping of TrackerConfig fields, got {type(data).__name__}")
    known = set(TrackerConfig.__dataclass_fields__)
    if unknown := sorted(set(data) - known):
        raise InputError(f"{path}: unknown tracker config keys {unknown}, expected some of {sorted(known)}")
    try:
        if "classes" in data:
            classes = dict(TrackerConfig().classes)
            classes.update({str(c): ClassConfig(**fields) for c, fields in data["classes"].items()})
            data["classes"] = classes
        for key in ("process_sigma", "measurement_sigma", "initial_sigma"):
            if key in data:
                data[key] = tuple(float(v) for v in data[key])
        return TrackerConfig(**data)
    except (TypeError, ValueError, AttributeError, InputError) as error:
        raise InputError(f"{path}: invalid tracker config ({error})") from None


def _make_tracker(spec: str, config: TrackerConfig) -> Tracker:
    if spec == "kalman":
        return KalmanTracker(config)
    module, _, name = spec.partition(":")
    if not module or not name:
        raise InputError(f"--tracker: expected 'kalman' or MODULE:CALLABLE, got {spec!r}")
    try:
        factory = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as error:
        raise InputError(f"--tracker {spec}: cannot import ({error})") from None
    tracker: Tracker = factory()
    return tracker


def track_scene(task: _Task) -> list[str]:
    """The KITTI tracking result lines of one scene (every frame from 0 to the last detected one, in order)."""
    tracker = _make_tracker(task.tracker, task.config)
    last = max(task.frames) if task.frames else -1
    lines: list[str] = []
    template = next(iter(task.frames.values()))
    for frame_index in range(last + 1):
        dets = task.frames.get(frame_index)
        if dets is None:
            dets = template.select(np.zeros(0, dtype=np.int64))
            dets = Detections(boxes=dets.boxes, scores=dets.scores, sensors=dets.sensors,
                              timestamp_ns=frame_index * 100_000_000, extras=dets.extras)
        tracks = tracker(upright(dets))
        if not len(tracks.boxes):
            continue
        if tracks.boxes.frame != UPRIGHT_FRAME:
            raise InputError(f"--tracker {task.tracker}: expected tracks in {UPRIGHT_FRAME!r}, got {tracks.boxes.frame!r}")
        hwl, bottom, rotation_y = camera_boxes(tracks.boxes)
        n = len(tracks.boxes)
        rows = KittiDetectionRows(
            scene=np.full(n, task.scene), frame=np.full(n, frame_index), kitti_class=tracks.extras["kitti_class"],
            track_id=np.asarray(tracks.boxes.ids).astype(np.int64), box2d_px=tracks.extras["box2d_px"], hwl_m=hwl,
            bottom_cam0_m=bottom, rotation_y_rad=rotation_y, alpha_rad=tracks.extras["alpha_rad"],
            score_raw=np.where(np.isnan(tracks.extras["score_raw"]), tracks.scores, tracks.extras["score_raw"]))
        lines += format_kitti_tracking_lines(rows)
    return lines


def _run_track(args: argparse.Namespace) -> int:
    config = load_tracker_config(args.config)
    found = read_detections(args.detections, args.format)
    for problem in found.problems:
        print(f"avdata: error: {problem}", file=sys.stderr)
    scenes = sorted(found.scenes)
    if args.scenes:
        if missing := sorted(set(args.scenes) - set(scenes)):
            raise InputError(f"--scenes: {missing} have no detections in {args.detections}")
        scenes = [s for s in scenes if s in args.scenes]
    todo = [s for s in scenes if args.force or not (args.out / f"{s}.txt").exists()]
    tasks = [_Task(s, found.scenes[s], args.tracker, config) for s in todo]
    failed = []

    def done(index: int, result: list[str] | TaskFailure) -> None:
        scene = todo[index]
        if isinstance(result, TaskFailure):
            failed.append(scene)
            print(f"avdata: error: scene {scene}: {result.message}", file=sys.stderr)
            return
        write_atomically(args.out / f"{scene}.txt", "".join(line + "\n" for line in result))
        print(f"track: {scene} ({index + 1}/{len(tasks)}): {len(result)} track boxes", file=sys.stderr)

    with make_executor(args.executor, workers=args.workers) as executor:
        executor.map(track_scene, tasks, on_done=done)
    print(f"track: {len(tasks)} scenes tracked, {len(scenes) - len(todo)} already done, into {args.out}")
    return 1 if found.problems or failed else 0
