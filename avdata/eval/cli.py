"""``avdata eval detection|tracking|prediction GT PRED --protocol ...``: argument parsing and the runners.

The lead's ``avdata/cli.py`` calls :func:`add_eval_subparser` on its subparsers; each subcommand stores its
runner in ``func``; a runner returns the exit status and raises :class:`~avdata.errors.AvdataError` for bad
input. Every run prints a Markdown table and optionally writes ``--json`` (class -> metric -> value),
``--markdown`` and PNG plots into ``--plots``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from avdata.errors import InputError
from avdata.eval import report
from avdata.eval.names import Similarity, TrackingMetric

__all__ = ["add_eval_subparser", "run_detection", "run_prediction", "run_tracking"]

_TRACKING_COLUMNS = ["HOTA", "DetA", "AssA", "LocA", "MOTA", "MOTP", "IDF1", "IDSW", "MT", "ML", "Frag"]


def add_eval_subparser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Registers ``eval`` with ``detection``, ``tracking`` and ``prediction`` subcommands.

    Args:
        subparsers: the ``add_subparsers()`` object of the top-level parser.

    Returns:
        The ``eval`` parser.
    """
    parser = subparsers.add_parser("eval", help="evaluate detections, tracks or trajectory predictions")
    sub = parser.add_subparsers(dest="eval_task", required=True)

    def common(p: argparse.ArgumentParser, protocols: list[str]) -> None:
        p.add_argument("gt", type=Path, help="ground truth (folder, table or dataset root; see --protocol)")
        p.add_argument("pred", type=Path, help="predictions (folder or file; see --protocol)")
        p.add_argument("--protocol", choices=protocols, default=protocols[0])
        p.add_argument("--json", type=Path, help="write class -> metric -> value JSON here")
        p.add_argument("--markdown", type=Path, help="write the Markdown table here")
        p.add_argument("--plots", type=Path, help="write PNG plots into this folder")

    det = sub.add_parser("detection", help="KITTI AP, nuScenes mAP/NDS, or precision/recall breakdowns")
    common(det, ["kitti", "nuscenes", "avdata", "av2", "waymo"])
    det.add_argument("--classes", nargs="+", help="classes to evaluate (KITTI spelling for kitti)")
    det.add_argument("--scenes", nargs="+", help="nuscenes: scene names to evaluate (default: all)")
    det.add_argument("--score-threshold", type=float, default=0.0, help="avdata: minimum detection score")
    det.add_argument("--match-distance-m", type=float, default=2.0, help="avdata: BEV centre match distance")
    det.add_argument("--no-roi", action="store_true", help="av2: evaluate outside the map's region of interest too")
    det.set_defaults(run=run_detection)

    trk = sub.add_parser("tracking", help="HOTA, CLEAR, Identity (and VACE, IDEucl, track rates)")
    common(trk, ["kitti", "mot", "nuscenes", "avdata"])
    trk.add_argument("--classes", nargs="+", help="kitti: car / pedestrian; avdata: unified classes")
    trk.add_argument("--split", default="training", help="kitti: seqmap suffix (evaluate_tracking.seqmap.<split>)")
    trk.add_argument("--scenes", nargs="+", help="nuscenes: scene names to evaluate (default: all)")
    trk.add_argument("--similarity", choices=[s.value for s in Similarity], default=Similarity.IOU_BEV.value,
                     help="avdata: box similarity")
    trk.add_argument("--metrics", nargs="+", choices=[m.value for m in TrackingMetric],
                     default=[TrackingMetric.HOTA.value, TrackingMetric.CLEAR.value, TrackingMetric.IDENTITY.value])
    trk.set_defaults(run=run_tracking)

    pre = sub.add_parser("prediction", help="ADE, FDE, minADE/minFDE (both definitions), miss rate")
    common(pre, ["avdata"])
    pre.add_argument("--ks", nargs="+", type=int, default=[1, 5, 10])
    pre.add_argument("--miss-threshold-m", type=float, default=2.0)
    pre.set_defaults(run=run_prediction)

    saf = sub.add_parser("safety", help="RSS safe-distance violations of the ego, on ground truth and on tracks")
    saf.add_argument("gt", type=Path, help="a unified dataset (ego poses from index/frames.parquet, objects from index)")
    saf.add_argument("--tracks", type=Path, help="tracker output (avdata protocol columns + vx_world_mps, vy_world_mps)")
    saf.add_argument("--scenes", nargs="+", help="scenes to evaluate (default: all)")
    saf.add_argument("--json", type=Path, help="write the result JSON here")
    saf.add_argument("--markdown", type=Path, help="write the Markdown table here")
    saf.set_defaults(run=run_safety)
    return parser


def _emit(args: argparse.Namespace, table: dict, columns: list[str] | None = None) -> int:
    markdown = report.to_markdown(table, columns)
    sys.stdout.write(markdown)
    if args.json is not None:
        report.write_json(args.json, table)
    if args.markdown is not None:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(markdown)
    return 0


def _unified_tables(root: Path):
    from avdata.schema.dataset import DatasetReader

    reader = DatasetReader(root)
    return reader.objects(), reader.visibility()


def run_tracking(args: argparse.Namespace) -> int:
    """Runs ``avdata eval tracking``; returns the exit status."""
    from avdata.eval import tracking_io, unified
    from avdata.eval.tracking import HOTA_ALPHAS, evaluate_tracking, summary

    metrics = [TrackingMetric(m) for m in args.metrics]
    if args.protocol == "nuscenes":
        from avdata.eval import nuscenes_detection as nd
        from avdata.eval import nuscenes_tracking as nt

        gt, pred, order = nt.load_nuscenes_tracking(args.gt, args.pred, set(args.scenes) if args.scenes else None)
        racks = nd.load_nuscenes_bike_racks(args.gt, set(args.scenes) if args.scenes else None)
        return _emit(args, nt.evaluate_nuscenes_tracking(gt, pred, order, bike_racks=racks), ["AMOTA", "AMOTP"])
    if args.protocol == "kitti":
        kitti_classes = tuple(c.lower() for c in (args.classes or tracking_io.KITTI_TRACKING_CLASSES))
        per_class = tracking_io.kitti_tracking_sequences(args.gt, args.pred, kitti_classes, split=args.split)
    elif args.protocol == "mot":
        per_class = {"pedestrian": tracking_io.mot_sequences(args.gt, args.pred)}
    else:
        objects, visibility = _unified_tables(args.gt)
        tracks = unified.read_table(args.pred, unified.DETECTION_COLUMNS)
        classes = args.classes or sorted(set(tracks["class"].to_pylist()))
        per_class = unified.tracking_sequences(objects, visibility, tracks, classes, Similarity(args.similarity))
    table = {}
    for cls, seqs in per_class.items():
        if not seqs:
            raise InputError(f"{args.gt}: expected sequences to evaluate for class {cls}, got none")
        combined = evaluate_tracking(seqs, metrics)["COMBINED_SEQ"]
        table[cls] = summary(combined)
        if args.plots is not None and TrackingMetric.HOTA in combined:
            hota = combined[TrackingMetric.HOTA]
            report.plot_curves(
                args.plots / f"hota_{cls}.png", HOTA_ALPHAS,
                {k: hota[k] for k in ("HOTA", "DetA", "AssA", "DetRe", "DetPr", "AssRe", "AssPr", "LocA")},
                title=f"HOTA vs alpha: {cls}", xlabel="alpha",
            )
    columns = [c for c in _TRACKING_COLUMNS if c in next(iter(table.values()))]
    return _emit(args, table, columns or None)


def run_detection(args: argparse.Namespace) -> int:
    """Runs ``avdata eval detection``; returns the exit status."""
    if args.protocol == "kitti":
        from avdata.eval import kitti_detection as kd

        gt_dir = args.gt / "label_2" if (args.gt / "label_2").is_dir() else args.gt
        gt = kd.load_kitti_objects(gt_dir)
        dt = kd.load_kitti_objects(args.pred, image_ids=sorted(set(gt.image.tolist())))
        res = kd.evaluate_kitti_detection(gt, dt, classes=args.classes or ("Car", "Pedestrian", "Cyclist"))
        table = res.summary()
        if args.plots is not None:
            recall = np.linspace(0, 1, 41)
            for cls in res.ap11:
                curves = {f"{box} {diff}": res.precision[(cls, box, diff)]
                          for box in res.ap11[cls] for diff in ("easy", "moderate", "hard")}
                report.plot_curves(args.plots / f"pr_{cls}.png", recall, curves, title=f"KITTI precision: {cls}",
                                   xlabel="recall", ylabel="precision")
        return _emit(args, table, [c for c in next(iter(table.values())) if "moderate" in c])
    if args.protocol == "nuscenes":
        from avdata.eval import nuscenes_detection as nd

        scenes = set(args.scenes) if args.scenes else None
        nus_gt, ego = nd.load_nuscenes_gt(args.gt, scenes)
        nus = nd.evaluate_nuscenes_detection(nus_gt, nd.load_nuscenes_submission(args.pred, ego),
                                             bike_racks=nd.load_nuscenes_bike_racks(args.gt, scenes))
        if args.plots is not None:
            for cls in nd.NUSCENES_CLASSES:
                curves = {f"{th:g} m": nus.curves[(cls, th)].precision for th in nus.label_aps[cls]}
                report.plot_curves(args.plots / f"pr_{cls}.png", np.linspace(0, 1, 101), curves,
                                   title=f"nuScenes PR: {cls}", xlabel="recall", ylabel="precision")
        table = nus.summary()
        return _emit(args, table, ["AP", "trans_err", "scale_err", "orient_err", "vel_err", "attr_err", "mAP", "NDS"])
    if args.protocol == "av2":
        from avdata.eval.detection import av2

        config = av2.Av2DetectionConfig(eval_only_roi_instances=not args.no_roi)
        result = av2.evaluate_av2_detection(av2.read_detections(args.pred), av2.read_ground_truth(args.gt), config,
                                            split_dir=args.gt)
        return _emit(args, result.metrics, list(av2.METRICS))
    if args.protocol == "waymo":
        from avdata.eval.detection import waymo

        objects, _ = _unified_tables(args.gt)
        waymo_gt, waymo_pred = waymo.load_waymo_detection(objects, waymo.read_predictions(args.pred), args.pred)
        return _emit(args, waymo.summary(waymo.evaluate_waymo_detection(waymo_gt, waymo_pred)))
    from avdata.eval import unified

    objects, visibility = _unified_tables(args.gt)
    dets = unified.read_table(args.pred, (*unified.DETECTION_COLUMNS, "score"))
    table = unified.detection_breakdown(
        objects, visibility, dets,
        unified.UnifiedDetectionConfig(match_distance_m=args.match_distance_m, score_threshold=args.score_threshold),
    )
    return _emit(args, table, ["precision", "recall", "FPR", "FNR", "TP", "FP", "FN"])


def run_prediction(args: argparse.Namespace) -> int:
    """Runs ``avdata eval prediction``; returns the exit status."""
    from avdata.eval import unified
    from avdata.eval.prediction import PredictionConfig

    objects, _ = _unified_tables(args.gt)
    preds = unified.read_table(args.pred, unified.TRAJECTORY_COLUMNS)
    metrics = unified.prediction_metrics(
        objects, preds, PredictionConfig(ks=tuple(args.ks), miss_threshold_m=args.miss_threshold_m)
    )
    return _emit(args, {"all": metrics})


def run_safety(args: argparse.Namespace) -> int:
    """Runs ``avdata eval safety``: RSS violations of each dataset's ego (see :mod:`avdata.eval.safety`)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    from avdata.eval.safety import evaluate_safety
    from avdata.eval.unified import read_table
    from avdata.schema import DatasetReader

    ds = DatasetReader(args.gt)
    scenes = list(args.scenes or ds.scenes)
    unknown = sorted(set(scenes) - set(ds.scenes))
    if unknown:
        raise InputError(f"{args.gt}: expected scenes of the dataset, got unknown {unknown}")
    keep = pa.array(scenes, pa.string())
    frames = ds.frames().filter(pc.is_in(ds.frames()["scene"], keep))
    objects = ds.objects().filter(pc.is_in(ds.objects()["scene"], keep))
    own = frozenset(str(a["object_id"]) for s in scenes for a in ds.scene(s).metadata.get("agents", {}).values()
                    if isinstance(a, dict) and "object_id" in a)
    tracks = None
    if args.tracks is not None:
        tracks = read_table(args.tracks, ("scene", "frame_index", "object_id", "x_world_m", "y_world_m", "length_m",
                                          "width_m", "yaw_world_rad", "vx_world_mps", "vy_world_mps"))
        tracks = tracks.filter(pc.is_in(tracks["scene"], keep))
    result = evaluate_safety(frames, objects, tracks, exclude_ids=own).as_dict()
    return _emit(args, {"all": result})
