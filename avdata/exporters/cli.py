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
          f"{len(result.skipped)} frames skipped (no lidar or camera message){tilted} -> {args.dst}")
    return 0 if result.training + result.testing else 1
