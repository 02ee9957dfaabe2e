"""``avdata export FORMAT DATASET DST``: one sub-command per exporter, holding DST's writer lock."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_export_subparser(subparsers: argparse._SubParsersAction) -> None:
    """Registers ``export`` with its formats (``kitti-object``)."""
    export = subparsers.add_parser("export", help="write a unified dataset in another dataset's file layout")
    formats = export.add_subparsers(title="formats", metavar="FORMAT", dest="format")
    kitti = formats.add_parser("kitti-object", help="KITTI 3D object files (calib, label_2, velodyne, image_2, ImageSets)")
    kitti.add_argument("dataset", type=Path, help="unified dataset folder")
    kitti.add_argument("dst", type=Path, help="KITTI folder to write")
    kitti.add_argument("--lidar", default=None, help="lidar sensor frame (default <agent>/velodyne or the first lidar)")
    kitti.add_argument("--camera", default=None, help="camera for image_2 (default <agent>/cam2 or the first camera)")
    kitti.add_argument("--scenes", nargs="+", default=None, help="export only these scenes")
    kitti.set_defaults(run=_run_kitti_object)
    nusc = formats.add_parser("nuscenes", help="nuScenes tables and files (13 tables, samples/, sweeps/, maps/)")
    nusc.add_argument("dataset", type=Path, help="unified dataset folder")
    nusc.add_argument("dst", type=Path, help="nuScenes dataroot to write")
    nusc.add_argument("--version", default="v1.0-avdata", help="table folder name (default v1.0-avdata)")
    nusc.add_argument("--scenes", nargs="+", default=None, help="export only these scenes")
    nusc.set_defaults(run=_run_nuscenes)


def _run_kitti_object(args: argparse.Namespace) -> int:
    from avdata.executors import dataset_lock
    from avdata.exporters.kitti import export_kitti_object
    from avdata.schema import DatasetReader

    DatasetReader(args.dataset)  # a missing or broken dataset fails before DST is created
    with dataset_lock(args.dst):
        result = export_kitti_object(args.dataset, args.dst, lidar=args.lidar, camera=args.camera, scenes=args.scenes)
    for reason in result.skipped:
        print(f"skipped: {reason}", file=sys.stderr)
    tilted = f", {result.tilted_boxes} tilted boxes written with their heading only" if result.tilted_boxes else ""
    print(f"kitti-object: {result.training} training and {result.testing} testing samples written, "
          f"{result.skipped_frames} frames skipped (no lidar or camera message){tilted} -> {args.dst}")
    return 0 if result.training + result.testing else 1


def _run_nuscenes(args: argparse.Namespace) -> int:
    from avdata.exporters.nuscenes import export_nuscenes

    result = export_nuscenes(args.dataset, args.dst, version=args.version, scenes=args.scenes)
    rounded = f"; {result.rounded_timestamps} times rounded to whole microseconds" if result.rounded_timestamps else ""
    print(f"nuscenes: {result.scenes} scenes, {result.samples} samples, {result.sample_data} sample_data, "
          f"{result.annotations} annotations{rounded} -> {args.dst}")
    return 0 if result.samples else 1
