"""``avdata track DATASET OUT --detections PATH --format FORMAT``: one tracker per scene of a unified dataset.

Detections are read by :func:`avdata.perception.detection_files.read_detections`, matched to the dataset's
scenes and frames by :func:`~avdata.perception.detection_files.match_to_dataset`, and tracked per scene by
:func:`avdata.perception.track_run.track_scene`: in ``world`` where the scene has poses, else in the sensor frame
(one line says so). Output in the dataset's native tracking format (``--output-format``; see
:mod:`avdata.perception.track_run`), scored by ``avdata eval tracking`` and by the dataset's own tools.

Scenes run through the scene-run pipeline of convert (:mod:`avdata.executors.pipeline`: local processes or Ray,
progress, the output folder's lock). A scene whose output file exists is complete (``--force`` redoes it);
files are written under a temporary name and renamed. Unreadable detection records and detections of a
scene or frame the dataset lacks are printed one per line and cost those records; the exit status is then 1.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from avdata.errors import InputError
from avdata.executors.folder import OutputFolder
from avdata.executors.pipeline import EngineConfig, scene_run
from avdata.executors.scenes import WRITTEN
from avdata.inputs import UniqueKeyLoader
from avdata.perception.detection_files import FORMATS, NON_KITTI_FORMATS, match_to_dataset, read_detections
from avdata.perception.track_run import (
    OUTPUT_FORMATS,
    TrackTask,
    default_output_format,
    scene_output,
    track_scene,
    write_table,
)
from avdata.perception.tracker import ClassConfig, TrackerConfig

__all__ = ["add_track_subparser", "load_tracker_config"]


def add_track_subparser(subparsers: Any) -> None:
    """Adds ``avdata track`` to the command line."""
    parser = subparsers.add_parser(
        "track", help="track a detector's result files over a dataset's scenes; write its tracking format")
    parser.add_argument("dataset", help="the unified dataset the detections were made on (a path, s3://... or gs://...)")
    parser.add_argument("out", help="folder for the tracking results (created if missing; a path, s3://... or gs://...)")
    parser.add_argument("--detections", type=Path, required=True, help="detection file or folder (required)")
    parser.add_argument("--format", required=True, choices=sorted(FORMATS), help="format of the detections (required)")
    parser.add_argument("--output-format", choices=OUTPUT_FORMATS,
                        help="kitti (OUT/<seq>.txt), nuscenes (OUT/tracking_results.json) or unified (OUT/tracks.parquet) "
                             "(default: the dataset source's own: kitti for KITTI, nuscenes for nuScenes/Lyft, else unified)")
    parser.add_argument("--frame", choices=("world", "sensor"), default="world",
                        help="track in world where a scene has poses, or always in the sensor frame (default: world)")
    parser.add_argument("--tracker", default="kalman", help="'kalman' or MODULE:CALLABLE returning a tracker (default: kalman)")
    parser.add_argument("--config", type=Path, help="YAML of TrackerConfig fields (classes: {car: {...}}, ...) "
                        "(default: AB3DMOT's KITTI settings)")
    parser.add_argument("--scenes", nargs="+", help="only these dataset scenes (default: every scene of the dataset)")
    parser.add_argument("--workers", type=int, default=1, help="scenes tracked in parallel (--executor local; default: 1)")
    parser.add_argument("--executor", default="local", choices=("local", "ray"),
                        help="where scenes run: local processes or a Ray cluster (default: local)")
    parser.add_argument("--ray-address", help="Ray cluster to join, e.g. 'auto' or HOST:6379 (default: start one)")
    parser.add_argument("--quiet", action="store_true", help="no progress output (default: progress on stderr)")
    parser.add_argument("--force", action="store_true", help="redo scenes whose output exists (default: keep them)")
    parser.set_defaults(run=_run_track)


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
            if isinstance(data.get(key), list):  # TrackerConfig checks each value: float("1e3") hid a string
                data[key] = tuple(data[key])
        return TrackerConfig(**data)
    except (TypeError, ValueError, AttributeError, InputError) as error:
        raise InputError(f"{path}: invalid tracker config ({error})") from None


def _run_track(args: argparse.Namespace) -> int:
    from avdata.schema.dataset import DatasetReader, dataset_root

    config = load_tracker_config(args.config)
    dataset, out = dataset_root(args.dataset), OutputFolder.of(args.out)
    reader = DatasetReader(dataset, verify=True)
    found = read_detections(args.detections, args.format, dataset=args.dataset)
    matched = match_to_dataset(found, args.format, args.detections, args.dataset)
    for problem in (*found.problems, *matched.problems):
        print(f"avdata: error: {problem}", file=sys.stderr)
    output_format = args.output_format or default_output_format(str(reader.manifest["source"]["name"]), args.format)
    if output_format == "kitti" and args.format in NON_KITTI_FORMATS:
        raise InputError(f"--output-format kitti: expected KITTI-style detections (their 2D boxes and raw scores), "
                         f"got --format {args.format}")
    scenes = list(reader.scenes)
    if args.scenes:
        if missing := sorted(set(args.scenes) - set(scenes)):
            raise InputError(f"--scenes: {missing} are not scenes of {args.dataset}")
        scenes = [s for s in scenes if s in args.scenes]
    posed = _posed_scenes(reader.frames())
    tasks, complete = [], []
    # KITTI result files are named by sequence, unless two scenes share one (training and testing 0001).
    sequences = {scene: str(reader.scene(scene).metadata.get("kitti_sequence", scene)) for scene in scenes}
    if len(set(sequences.values())) < len(sequences):
        sequences = {scene: scene for scene in scenes}
    names = {scene: scene_output(scene, sequences[scene], output_format) for scene in scenes}
    existing = out.identities(names.values())
    for scene in scenes:
        world = args.frame == "world" and scene in posed
        if args.frame == "world" and not world and args.format not in ("nuscenes", "unified"):
            print(f"track: {scene}: no poses (world_T_ego is the identity), tracked in the sensor frame", file=sys.stderr)
        if existing[names[scene]] is not None and not args.force:
            complete.append(scene)
            continue
        tasks.append(TrackTask(dataset=str(dataset), scene=scene, frames=matched.scenes.get(scene, {}),
                               tracker=args.tracker, config=config, world=world, output_format=output_format,
                               out=str(out), name=names[scene]))
    engine = EngineConfig(executor=args.executor, workers=args.workers, ray_address=args.ray_address, quiet=args.quiet)
    with scene_run(out.root, engine, [dataset, out.root]) as run:
        run.clean()
        outcomes = run.run(track_scene, tasks, [t.scene for t in tasks], "track")
    failed = [o for o in outcomes if o.status != WRITTEN]
    for outcome in failed:
        for failure in outcome.problems:
            print(f"avdata: error: scene {outcome.scene}: {failure.message}", file=sys.stderr)
    target = str(out)
    if output_format != "kitti" and not failed:
        target = write_table(out, output_format, scenes)
    print(f"track: {len(outcomes) - len(failed)} scenes tracked, {len(complete)} already complete, {len(failed)} failed; "
          f"{sum(o.data for o in outcomes if o.status == WRITTEN)} track boxes -> {target}")
    return 1 if found.problems or matched.problems or failed else 0


def _posed_scenes(frames: Any) -> set[str]:
    """Scenes with a world_T_ego other than the identity at some frame (a converter without poses writes identities)."""
    columns = frames.select(["scene", "world_T_ego_x_m", "world_T_ego_y_m", "world_T_ego_z_m", "world_T_ego_qx",
                             "world_T_ego_qy", "world_T_ego_qz"]).to_pydict()
    scene = np.asarray(columns.pop("scene"), dtype=str)
    moved = np.any(np.c_[tuple(np.asarray(v, dtype=np.float64) for v in columns.values())] != 0.0, axis=1)
    return set(np.unique(scene[moved]).tolist())
