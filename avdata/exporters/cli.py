"""``avdata export FORMAT DATASET DST``: one sub-command per exporter, one task per scene on an executor."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from avdata.errors import AvdataError
from avdata.executors.base import add_executor_arguments

if TYPE_CHECKING:
    from avdata.executors.pipeline import SceneRunResult
    from avdata.exporters.driver import ExportConfig


def add_export_subparser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Registers ``export`` with its formats (``kitti-object``, ``nuscenes``)."""
    export = subparsers.add_parser("export", help="write a unified dataset in another dataset's file layout")
    formats = export.add_subparsers(title="formats", metavar="FORMAT", dest="format")
    kitti = formats.add_parser("kitti-object", help="KITTI 3D object files (calib, label_2, velodyne, image_2, ImageSets)")
    kitti.add_argument("dataset", help="unified dataset folder (a path, s3://... or gs://...)")
    kitti.add_argument("dst", help="KITTI folder to write (a path, s3://... or gs://...)")
    kitti.add_argument("--lidar", default=None, help="lidar sensor frame (default <agent>/velodyne or the first lidar)")
    kitti.add_argument("--camera", default=None, help="camera for image_2 (default <agent>/cam2 or the first camera)")
    kitti.set_defaults(run=_run_kitti_object)
    nusc = formats.add_parser("nuscenes", help="nuScenes tables and files (13 tables, samples/, sweeps/, maps/)")
    nusc.add_argument("dataset", help="unified dataset folder (a path, s3://... or gs://...)")
    nusc.add_argument("dst", help="nuScenes dataroot to write (a path, s3://... or gs://...)")
    nusc.add_argument("--version", default="v1.0-avdata", help="table folder name (default v1.0-avdata)")
    nusc.add_argument("--channel", action="append", default=[], metavar="SENSOR=CHANNEL",
                      help="name a sensor's channel, e.g. ego/cam3=CAM_FRONT_RIGHT (repeatable; default: the ego's "
                           "sensors with a nuScenes equivalent get its name, e.g. ego/velodyne=LIDAR_TOP)")
    nusc.set_defaults(run=_run_nuscenes)
    for parser in (kitti, nusc):
        parser.add_argument("--scenes", nargs="+", default=None, help="export only these scenes (the export holds only them)")
        parser.add_argument("--quiet", action="store_true", help="no progress bar")
        add_executor_arguments(parser, "scenes exported")


def _config(args: argparse.Namespace) -> ExportConfig:
    from avdata.exporters.driver import ExportConfig
    from avdata.schema.dataset import dataset_root

    return ExportConfig(dataset=dataset_root(args.dataset), dst=dataset_root(args.dst), executor=args.executor,
                        workers=args.workers, ray_address=args.ray_address, force=args.force, quiet=args.quiet)


def _scenes_line(result: SceneRunResult) -> str:
    n_warnings = len(result.problems) - result.n_errors
    return (f"{len(result.written)} scenes written, {len(result.complete)} already complete, {len(result.failed)} failed; "
            f"{result.n_errors} errors, {n_warnings} warnings")


def _run_kitti_object(args: argparse.Namespace) -> int:
    from avdata.exporters.kitti import export_kitti_object

    result = export_kitti_object(args.dataset, args.dst, lidar=args.lidar, camera=args.camera, scenes=args.scenes,
                                 config=_config(args))
    for problem in result.problems:
        print(problem, file=sys.stderr)
    tilted = f", {result.tilted_boxes} tilted boxes written with their heading only" if result.tilted_boxes else ""
    print(f"kitti-object: {result.training} training and {result.testing} testing samples, "
          f"{result.skipped_frames} frames skipped (no lidar or camera message){tilted}; {_scenes_line(result)} -> {args.dst}")
    return 1 if result.n_errors or result.failed or not result.training + result.testing else 0


def _run_nuscenes(args: argparse.Namespace) -> int:
    from avdata.exporters.nuscenes import export_nuscenes

    if any("=" not in item for item in args.channel):
        raise AvdataError(f"--channel: expected SENSOR=CHANNEL, got {[i for i in args.channel if '=' not in i][0]!r}")
    pairs = [item.split("=", 1) for item in args.channel]
    channels = dict(pairs)
    twice = sorted({sensor for sensor, channel in pairs if channels[sensor] != channel})
    if twice:  # the last one would win without a word
        raise AvdataError(f"--channel: expected one channel per sensor, got {twice[0]} mapped to "
                          f"{[channel for sensor, channel in pairs if sensor == twice[0]]}")
    result = export_nuscenes(args.dataset, args.dst, version=args.version, scenes=args.scenes, channels=channels,
                             config=_config(args))
    for problem in result.problems:
        print(problem, file=sys.stderr)
    rounded = f"; {result.rounded_timestamps} times rounded to whole microseconds" if result.rounded_timestamps else ""
    skipped = f"; {result.skipped_frames} frames skipped (no LIDAR_TOP message)" if result.skipped_frames else ""
    print(f"nuscenes: {result.scenes} scenes, {result.samples} samples, {result.sample_data} sample_data, "
          f"{result.annotations} annotations{rounded}{skipped}; {_scenes_line(result)} -> {args.dst}")
    return 1 if result.n_errors or result.failed or not result.samples else 0
