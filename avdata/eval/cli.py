"""``avdata eval detection|tracking|prediction GT PRED --protocol ...``: argument parsing and the protocol registry.

The lead's ``avdata/cli.py`` calls :func:`add_eval_subparser` on its subparsers; each subcommand stores its
runner in ``run``; a runner returns the exit status and raises :class:`~avdata.errors.AvdataError` for bad
input. Every run prints a Markdown table and optionally writes ``--json`` (class -> metric -> value),
``--markdown`` and PNG plots into ``--plots``; warnings of the evaluation (:class:`~avdata.eval.problems.EvalWarning`)
are printed as ``avdata: warning:`` lines on stderr.

A protocol is one :class:`Protocol` entry in :data:`DETECTION_PROTOCOLS`, :data:`TRACKING_PROTOCOLS` or
:data:`PREDICTION_PROTOCOLS`: what GT and PRED are (shown by ``--help``), whether it draws plots, and a runner
``run(args) -> (table, columns)`` that calls the protocol's ``evaluate_<protocol>`` and writes its plots.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from avdata.errors import InputError, one_line
from avdata.eval import report
from avdata.eval.names import Similarity, TrackingMetric
from avdata.eval.problems import EvalWarning, check_ground_truth
from avdata.outputs import checked_name, refuse_output_in_input, write_atomically
from avdata.storage import Location, path_or_location

if TYPE_CHECKING:  # pyarrow and the dataset reader load lazily, inside the commands that read a dataset
    import pyarrow as pa

    from avdata.schema.dataset import DatasetReader

__all__ = [
    "DETECTION_PROTOCOLS",
    "PREDICTION_PROTOCOLS",
    "TRACKING_PROTOCOLS",
    "Protocol",
    "add_eval_subparser",
    "run_detection",
    "run_prediction",
    "run_safety",
    "run_tracking",
]

Table = dict[str, dict[str, Any]]
_TRACKING_COLUMNS = ["HOTA", "DetA", "AssA", "LocA", "MOTA", "MOTP", "IDF1", "IDSW", "CLR_FP", "CLR_FN", "MT", "ML", "Frag"]


@dataclass(frozen=True, slots=True, kw_only=True)
class Protocol:
    """One evaluation protocol of the command line.

    Attributes:
        gt: what the GT argument is.
        pred: what the PRED argument is.
        plots: whether ``--plots`` draws anything (otherwise it is refused).
        unified_gt: GT is a unified dataset, read through ``DatasetReader``: a local folder or its ``s3://``/``gs://``
            URI (the other protocols read their publisher's files from a local folder).
        run: ``run(args) -> (table, columns)``: the table ``{row: {metric: value}}`` and the columns to print
            (None for all); writes the plots when ``args.plots`` is set.
    """

    gt: str
    pred: str
    plots: bool
    run: Callable[[argparse.Namespace], tuple[Table, list[str] | None]]
    unified_gt: bool = False


def _unified_tables(root: Path | Location) -> tuple[DatasetReader, pa.Table, pa.Table]:
    from avdata.schema.dataset import DatasetReader

    reader = DatasetReader(root, verify=True)
    return reader, reader.objects(), reader.visibility()


def _plot_path(args: argparse.Namespace, curve: str, cls: str) -> Path:
    """``--plots``/<curve>_<class>.png: the class comes from the input (a tracker's class column), so it is checked."""
    plots: Path = args.plots
    return plots / checked_name(f"{curve}_{cls}.png", "plot file name")


# --- detection -------------------------------------------------------------------------------------------------


def _detection_kitti(args: argparse.Namespace) -> tuple[Table, list[str] | None]:
    from avdata.eval.detection import kitti as kd

    gt_dir = args.gt / "label_2" if (args.gt / "label_2").is_dir() else args.gt
    if not any(gt_dir.glob("*.txt")):
        raise InputError(f"{args.gt}: expected KITTI label files (label_2/*.txt or *.txt), got none")
    gt = kd.load_kitti_objects(gt_dir)
    images = sorted(set(gt.image.tolist()))
    # A result file of an image without a label file would be passed over without a word (the devkit reads
    # the label folder's images only): the wrong folder or split, refused as every protocol refuses unknown frames.
    unknown = sorted({p.stem for p in args.pred.glob("*.txt")} - set(images)) if args.pred.is_dir() else []
    if unknown:
        raise InputError(f"{args.pred}: expected result files of the images of {gt_dir}, got {len(unknown)} other(s): "
                         f"{', '.join(u + '.txt' for u in unknown[:3])}{' ...' if len(unknown) > 3 else ''}")
    dt = kd.load_kitti_objects(args.pred, image_ids=images, results=True)
    res = kd.evaluate_kitti_detection(gt, dt, classes=args.classes or ("Car", "Pedestrian", "Cyclist"))
    table = res.summary()
    if args.plots is not None:
        recall = np.linspace(0, 1, 41)
        for cls in res.ap11:
            curves = {f"{box} {diff}": res.precision[(cls, box, diff)]
                      for box in res.ap11[cls] for diff in ("easy", "moderate", "hard")}
            report.plot_curves(_plot_path(args, "pr", cls), recall, curves, title=f"KITTI precision: {cls}",
                               xlabel="recall", ylabel="precision")
    return table, [c for c in next(iter(table.values())) if "moderate" in c]


def _detection_nuscenes(args: argparse.Namespace) -> tuple[Table, list[str] | None]:
    from avdata.eval.detection import nuscenes as nd
    from avdata.eval.nuscenes_gt import load_nuscenes_bike_racks

    scenes = set(args.scenes) if args.scenes else None
    nus_gt, ego, samples = nd.load_nuscenes_gt(args.gt, scenes)
    nus = nd.evaluate_nuscenes_detection(nus_gt, nd.load_nuscenes_submission(args.pred, ego, samples),
                                         bike_racks=load_nuscenes_bike_racks(args.gt, scenes))
    if args.plots is not None:
        for cls in nd.NUSCENES_CLASSES:
            curves = {f"{th:g} m": nus.curves[(cls, th)].precision for th in nus.label_aps[cls]}
            report.plot_curves(_plot_path(args, "pr", cls), np.linspace(0, 1, 101), curves,
                               title=f"nuScenes PR: {cls}", xlabel="recall", ylabel="precision")
    return nus.summary(), ["AP", "trans_err", "scale_err", "orient_err", "vel_err", "attr_err", "mAP", "NDS"]


def _detection_avdata(args: argparse.Namespace) -> tuple[Table, list[str] | None]:
    import pyarrow as pa
    import pyarrow.compute as pc

    from avdata.eval import unified

    reader, objects, visibility = _unified_tables(args.gt)
    dets = unified.read_table(args.pred, (*unified.DETECTION_COLUMNS, "score"))
    frames = reader.frames()
    unified.check_frames(args.pred, dets, frames)
    unified.warn_unknown_classes(args.pred, dets, _unified_class_names(), "they can only be false positives")
    if args.classes:
        _check_unified_classes(args.classes)
        objects = objects.filter(pc.is_in(objects["class"], pa.array(args.classes)))
        dets = dets.filter(pc.is_in(dets["class"], pa.array(args.classes)))
    visible = unified.visible_mask(objects, visibility)
    if not visible.any():
        raise InputError(f"{args.gt}: expected ground truth seen by a sensor (index/visibility.parquet) of the "
                         f"evaluated classes, got none of {len(visible)} object rows")
    seen = set(np.asarray(objects["class"].to_pylist(), dtype=object)[visible].tolist())
    evaluated = args.classes or sorted(seen | (set(dets["class"].to_pylist()) & set(_unified_class_names())))
    check_ground_truth(str(args.gt), evaluated, [c for c in evaluated if c not in seen],
                       "their detections count only as false positives")
    table = unified.detection_breakdown(
        objects, visibility, dets,
        unified.UnifiedDetectionConfig(match_distance_m=args.match_distance_m, score_threshold=args.score_threshold),
        frames=frames,
    )
    return table, ["precision", "recall", "FPR", "FNR", "TP", "FP", "FN"]


def _unified_class_names() -> tuple[str, ...]:
    from avdata.schema import UNIFIED_CLASSES

    return tuple(UNIFIED_CLASSES)


def _check_unified_classes(classes: list[str]) -> None:
    unknown = sorted(set(classes) - set(_unified_class_names()))
    if unknown:
        raise InputError(f"--classes: expected classes of the unified taxonomy {', '.join(_unified_class_names())}, "
                         f"got {unknown}")


def _detection_av2(args: argparse.Namespace) -> tuple[Table, list[str] | None]:
    from avdata.eval.detection import av2

    config = av2.Av2DetectionConfig(eval_only_roi_instances=not args.no_roi)
    result = av2.evaluate_av2_detection(av2.read_detections(args.pred), av2.read_ground_truth(args.gt), config,
                                        split_dir=args.gt, source=args.pred)
    return result.metrics, list(av2.METRICS)


def _detection_waymo(args: argparse.Namespace) -> tuple[Table, list[str] | None]:
    from avdata.eval import unified
    from avdata.eval.detection import waymo

    reader, objects, _ = _unified_tables(args.gt)
    predictions = waymo.read_predictions(args.pred)
    unified.check_frames(args.pred, predictions, reader.frames())
    waymo_gt, waymo_pred = waymo.load_waymo_detection(objects, predictions, args.pred)
    return waymo.summary(waymo.evaluate_waymo_detection(waymo_gt, waymo_pred)), None


def _detection_opv2v(args: argparse.Namespace) -> tuple[Table, list[str] | None]:
    from avdata.eval.detection import opv2v

    if args.classes:
        _check_unified_classes(args.classes)
    gt, pred = opv2v.load_opv2v(_unified_tables(args.gt)[1], args.pred, args.classes)
    range_m = args.range_m if args.range_m is not None else opv2v.EVAL_RANGES_M[args.eval_range]
    return opv2v.evaluate_opv2v(gt, pred, range_m=range_m, global_sort=args.global_sort,
                                source=args.pred).summary(), None


DETECTION_PROTOCOLS: Mapping[str, Protocol] = {
    "kitti": Protocol(
        gt="a KITTI object folder holding label_2/*.txt (or the label folder itself)",
        pred="a folder of KITTI result files <image>.txt (16 columns, score last); a missing file is an image "
             "without detections",
        plots=True, run=_detection_kitti),
    "nuscenes": Protocol(
        gt="the nuScenes table folder (e.g. <dataroot>/v1.0-trainval)",
        pred="a detection submission JSON {'meta', 'results': {sample_token: [box]}} covering exactly the samples "
             "of the evaluated scenes (--scenes)",
        plots=True, run=_detection_nuscenes),
    "avdata": Protocol(
        gt="a unified avdata dataset root",
        pred="a Parquet or JSON table with scene, frame_index, object_id, class, score, x/y/z_world_m, "
             "length/width/height_m, yaw_world_rad",
        unified_gt=True, plots=False, run=_detection_avdata),
    "av2": Protocol(
        gt="an Argoverse 2 split folder of <log>/annotations.feather (with the logs' maps for the region of interest)",
        pred="one feather or Parquet table with log_id, timestamp_ns, category, tx_m, ty_m, tz_m, length_m, "
             "width_m, height_m, qw, qx, qy, qz, score (egovehicle frame)",
        plots=False, run=_detection_av2),
    "waymo": Protocol(
        gt="a unified dataset converted from Waymo (its index/objects.parquet)",
        pred="a Parquet or JSON table with scene, frame_index, score, x/y/z_ego_m, length/width/height_m, "
             "yaw_ego_rad and source_class (TYPE_VEHICLE ...) or class; optional overlap_nlz",
        unified_gt=True, plots=False, run=_detection_waymo),
    "opv2v": Protocol(
        gt="a unified dataset converted from OPV2V / V2XSet / V2V4Real / DAIR-V2X (its index/objects.parquet)",
        pred="a Parquet or JSON table with scene, frame_index, score, x/y/z_ego_m, length/width/height_m, "
             "yaw_ego_rad (the ego frame of each frame); optional class",
        unified_gt=True, plots=False, run=_detection_opv2v),
}


# --- tracking --------------------------------------------------------------------------------------------------


def _tracking_table(args: argparse.Namespace, per_class: Mapping[str, Mapping[str, Any]]) -> tuple[Table, list[str] | None]:
    from avdata.eval.tracking import COMBINED, HOTA_ALPHAS, evaluate_tracking, summary

    metrics = [TrackingMetric(m) for m in args.metrics]
    gt_counts = {cls: sum(seq.num_gt_dets for seq in seqs.values()) for cls, seqs in per_class.items()}
    check_ground_truth(str(args.gt), list(per_class), [cls for cls, n in gt_counts.items() if n == 0],
                       "their scores count only false positives")
    table: Table = {}
    for cls, seqs in per_class.items():
        if not seqs:
            raise InputError(f"{args.gt}: expected sequences to evaluate for class {cls}, got none")
        combined = evaluate_tracking(seqs, metrics)[COMBINED]
        table[cls] = summary(combined)
        if args.plots is not None and TrackingMetric.HOTA in combined:
            hota = combined[TrackingMetric.HOTA]
            report.plot_curves(
                _plot_path(args, "hota", cls), HOTA_ALPHAS,
                {k: np.asarray(hota[k]) for k in ("HOTA", "DetA", "AssA", "DetRe", "DetPr", "AssRe", "AssPr", "LocA")},
                title=f"HOTA vs alpha: {cls}", xlabel="alpha",
            )
    columns = [c for c in _TRACKING_COLUMNS if c in next(iter(table.values()))]
    return table, columns or None


def _tracking_kitti(args: argparse.Namespace) -> tuple[Table, list[str] | None]:
    from avdata.eval.tracking.kitti import KITTI_TRACKING_CLASSES, kitti_tracking_sequences

    classes = tuple(c.lower() for c in (args.classes or KITTI_TRACKING_CLASSES))
    return _tracking_table(args, kitti_tracking_sequences(args.gt, args.pred, classes, split=args.split))


def _tracking_kitti_3dmot(args: argparse.Namespace) -> tuple[Table, list[str] | None]:
    from avdata.eval.tracking.kitti import read_kitti_seqmap
    from avdata.eval.tracking.kitti_3dmot import CLASSES, evaluate_kitti_3dmot

    dimension, _, value = args.iou.partition("@")
    if dimension not in ("2d", "3d") or not value:
        raise InputError(f"--iou: expected 2d@T or 3d@T (e.g. 2d@0.5, 3d@0.25), got {args.iou!r}")
    try:
        min_similarity = float(value)
    except ValueError:
        raise InputError(f"--iou: expected a number after '@', got {value!r}") from None
    sequences = read_kitti_seqmap(args.gt, args.split)
    classes = tuple(c.lower() for c in (args.classes or CLASSES))
    result = evaluate_kitti_3dmot(args.gt, args.pred, sequences, classes, dimension, min_similarity)
    return result.table, ["sAMOTA", "AMOTA", "AMOTP", "MOTA", "MOTP", "IDS", "FRAG", "FP", "FN", "threshold",
                          "script_MOTA", "script_threshold"]


def _tracking_mot(args: argparse.Namespace) -> tuple[Table, list[str] | None]:
    from avdata.eval.tracking.mot import mot_sequences

    return _tracking_table(args, {"pedestrian": mot_sequences(args.gt, args.pred)})


def _tracking_nuscenes(args: argparse.Namespace) -> tuple[Table, list[str] | None]:
    from avdata.eval.nuscenes_gt import load_nuscenes_bike_racks
    from avdata.eval.tracking import nuscenes as nt

    scenes = set(args.scenes) if args.scenes else None
    gt, pred, order = nt.load_nuscenes_tracking(args.gt, args.pred, scenes)
    racks = load_nuscenes_bike_racks(args.gt, scenes)
    return nt.evaluate_nuscenes_tracking(gt, pred, order, bike_racks=racks), ["AMOTA", "AMOTP"]


def _tracking_avdata(args: argparse.Namespace) -> tuple[Table, list[str] | None]:
    from avdata.eval import unified

    if Similarity(args.similarity) is Similarity.IOU_2D:  # it failed later on "gt boxes: expected (N, 4)"
        raise InputError(f"--similarity: expected {', '.join(s.value for s in Similarity if s is not Similarity.IOU_2D)} "
                         f"for --protocol avdata (its boxes are 3D, without image boxes), got {args.similarity}")
    reader, objects, visibility = _unified_tables(args.gt)
    tracks = unified.read_table(args.pred, unified.DETECTION_COLUMNS)
    unified.check_frames(args.pred, tracks, reader.frames())
    unified.check_unique_track_ids(args.pred, tracks)
    unified.warn_unknown_classes(args.pred, tracks, _unified_class_names(), "they match no ground truth")
    if args.classes:
        _check_unified_classes(args.classes)
    classes = args.classes or sorted(set(tracks["class"].to_pylist()))
    if not classes:  # the classes come from the tracks: none was a StopIteration traceback
        raise InputError(f"{args.pred}: expected tracks to take the classes from, got none (name the classes with "
                         f"--classes to score a tracker that found nothing)")
    per_class = unified.tracking_sequences(objects, visibility, tracks, classes, Similarity(args.similarity))
    return _tracking_table(args, per_class)


TRACKING_PROTOCOLS: Mapping[str, Protocol] = {
    "kitti": Protocol(
        gt="a KITTI tracking folder holding label_02/<seq>.txt and evaluate_tracking.seqmap.<split> (--split)",
        pred="a folder of tracker files <seq>.txt (KITTI tracking layout), one for every sequence of the seqmap",
        plots=True, run=_tracking_kitti),
    "kitti-3dmot": Protocol(
        gt="a KITTI tracking folder holding label_02/<seq>.txt and evaluate_tracking.seqmap.<split> (--split)",
        pred="a folder of KITTI tracking result files <seq>.txt with scores (AB3DMOT's protocol, --iou 2d@0.5)",
        plots=False, run=_tracking_kitti_3dmot),
    "mot": Protocol(
        gt="a MOTChallenge folder of <seq>/gt/gt.txt with <seq>/seqinfo.ini",
        pred="a folder of tracker files <seq>.txt (MOTChallenge CSV), one for every sequence",
        plots=True, run=_tracking_mot),
    "nuscenes": Protocol(
        gt="the nuScenes table folder (e.g. <dataroot>/v1.0-trainval)",
        pred="a tracking submission JSON {'meta', 'results': {sample_token: [box]}} covering exactly the samples of "
             "the evaluated scenes (--scenes)",
        plots=False, run=_tracking_nuscenes),
    "avdata": Protocol(
        gt="a unified avdata dataset root",
        pred="a Parquet or JSON table with scene, frame_index, object_id (the track id), class, x/y/z_world_m, "
             "length/width/height_m, yaw_world_rad",
        unified_gt=True, plots=True, run=_tracking_avdata),
}


# --- prediction ------------------------------------------------------------------------------------------------


def _prediction_avdata(args: argparse.Namespace) -> tuple[Table, list[str] | None]:
    from avdata.eval import unified
    from avdata.eval.prediction import PredictionConfig

    reader, objects, _ = _unified_tables(args.gt)
    preds = unified.read_table(args.pred, unified.TRAJECTORY_COLUMNS)
    unified.check_frames(args.pred, preds, reader.frames())
    ks = None if args.ks is None else tuple(args.ks)
    metrics = unified.prediction_metrics(objects, preds, PredictionConfig(ks=ks, miss_threshold_m=args.miss_threshold_m),
                                         source=args.pred)
    return {"all": metrics}, None


PREDICTION_PROTOCOLS: Mapping[str, Protocol] = {
    "avdata": Protocol(
        gt="a unified avdata dataset root",
        pred="a Parquet or JSON table with scene, frame_index, object_id, mode, probability, step (frames ahead), "
             "x_world_m, y_world_m; every prediction with the same modes and steps",
        unified_gt=True, plots=False, run=_prediction_avdata),
}


# --- parser ----------------------------------------------------------------------------------------------------


def _epilog(protocols: Mapping[str, Protocol]) -> str:
    lines = ["protocols (GT / PRED):"]
    for name, p in protocols.items():
        lines += [f"  {name}:", f"    GT   {p.gt}", f"    PRED {p.pred}"]
    return "\n".join(lines)


def add_eval_subparser(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    """Registers ``eval`` with ``detection``, ``tracking`` and ``prediction`` subcommands.

    Args:
        subparsers: the ``add_subparsers()`` object of the top-level parser.

    Returns:
        The ``eval`` parser.
    """
    parser = subparsers.add_parser("eval", help="evaluate detections, tracks or trajectory predictions")
    sub = parser.add_subparsers(dest="eval_task", required=True)

    def task(name: str, help_text: str, protocols: Mapping[str, Protocol]) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help_text, epilog=_epilog(protocols),
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        p.add_argument("gt", type=path_or_location, help="ground truth (per protocol: see below)")
        p.add_argument("pred", type=Path, help="predictions (per protocol: see below)")
        p.add_argument("--protocol", choices=list(protocols), default=next(iter(protocols)),
                       help=f"whose rules and file formats GT and PRED follow, see the list below "
                            f"(default: {next(iter(protocols))})")
        p.add_argument("--json", type=Path, help="write class -> metric -> value JSON here")
        p.add_argument("--markdown", type=Path, help="write the Markdown table here")
        with_curves = ", ".join(n for n, v in protocols.items() if v.plots)
        p.add_argument("--plots", type=Path, help=f"write PNG plots into this folder (protocols with curves: {with_curves})"
                       if with_curves else f"refused: no {name} protocol draws curves")
        return p

    det = task("detection", "KITTI AP, nuScenes mAP/NDS, or precision/recall breakdowns", DETECTION_PROTOCOLS)
    det.add_argument("--classes", nargs="+", help="classes to evaluate (KITTI spelling for kitti)")
    det.add_argument("--scenes", nargs="+", help="nuscenes: scene names to evaluate (default: all)")
    det.add_argument("--score-threshold", type=float, default=None,
                     help="avdata: minimum detection score (default: none, every detection counts; scores may be logits)")
    det.add_argument("--match-distance-m", type=float, default=2.0, help="avdata: BEV centre match distance, m (default: 2)")
    det.add_argument("--no-roi", action="store_true", help="av2: evaluate outside the map's region of interest too")
    det.add_argument("--eval-range", choices=["opv2v", "v2xset", "v2v4real", "dair_v2x"], default="opv2v",
                     help="opv2v: the dataset whose ego-frame evaluation range to use "
                     "(default: opv2v, [-140.8, 140.8] x [-40, 40] m)")
    det.add_argument("--range-m", type=float, nargs=4, metavar=("X_MIN", "Y_MIN", "X_MAX", "Y_MAX"),
                     help="opv2v: an ego-frame evaluation range of your own, m (default: none, --eval-range's)")
    det.add_argument("--global-sort", action="store_true", help="opv2v: sort all detections by score (OpenCOOD's "
                     "--global_sort_detections) instead of frame after frame")
    det.set_defaults(run=run_detection)

    trk = task("tracking", "HOTA, CLEAR, Identity (and VACE, IDEucl, track rates)", TRACKING_PROTOCOLS)
    trk.add_argument("--classes", nargs="+", help="kitti: car / pedestrian; avdata: unified classes")
    trk.add_argument("--split", default="training", help="kitti: seqmap suffix, seqmap.<split> (default: training)")
    trk.add_argument("--scenes", nargs="+", help="nuscenes: scene names to evaluate (default: all)")
    trk.add_argument("--iou", default="2d@0.5", help="kitti-3dmot: 2d@T or 3d@T (3D at 0.25, 0.5 or 0.7; default: 2d@0.5)")
    trk.add_argument("--similarity", choices=[s.value for s in Similarity], default=Similarity.IOU_BEV.value,
                     help=f"avdata: box similarity (default: {Similarity.IOU_BEV.value})")
    trk.add_argument("--metrics", nargs="+", choices=[m.value for m in TrackingMetric],
                     default=[TrackingMetric.HOTA.value, TrackingMetric.CLEAR.value, TrackingMetric.IDENTITY.value],
                     help="metric families to compute (default: HOTA CLEAR Identity)")
    trk.set_defaults(run=run_tracking)

    pre = task("prediction", "ADE, FDE, minADE/minFDE (both definitions), miss rate", PREDICTION_PROTOCOLS)
    pre.add_argument("--ks", nargs="+", type=int,
                     help="numbers of modes for the min-metrics, each at most the number of modes "
                          "(default: those of 1 5 10 that are)")
    pre.add_argument("--miss-threshold-m", type=float, default=2.0,
                     help="final displacement in metres above which a prediction is a miss (default: 2)")
    pre.set_defaults(run=run_prediction)

    saf = sub.add_parser("safety", help="RSS safe-distance violations of the ego, on ground truth and on tracks")
    saf.add_argument("gt", type=path_or_location,
                     help="a unified dataset (ego poses from index/frames.parquet, objects from index)")
    saf.add_argument("--tracks", type=Path, help="tracker output (avdata protocol columns + vx_world_mps, vy_world_mps)")
    saf.add_argument("--scenes", nargs="+", help="scenes to evaluate (default: all)")
    saf.add_argument("--json", type=Path, help="write the result JSON here")
    saf.add_argument("--markdown", type=Path, help="write the Markdown table here")
    saf.set_defaults(run=run_safety)
    return parser


#: Number options -> their least value (NaN and infinities are refused for each).
_NUMBER_OPTIONS = {"score_threshold": -np.inf, "match_distance_m": 0.0, "miss_threshold_m": 0.0, "range_m": -np.inf}
#: Options that only some protocols use: given to another, they are refused rather than ignored.
_OPTION_PROTOCOLS = {"classes": ("kitti", "kitti-3dmot", "avdata"), "scenes": ("nuscenes",)}


def _run(args: argparse.Namespace, protocols: Mapping[str, Protocol], task: str) -> int:
    protocol = protocols[args.protocol]
    if isinstance(args.gt, Location) and not protocol.unified_gt:
        stores = [name for name, p in protocols.items() if p.unified_gt]
        raise InputError(f"{args.gt}: expected a local folder for --protocol {args.protocol} (it reads its publisher's "
                         f"files from disk); a unified dataset in a store is evaluated with --protocol "
                         f"{' or '.join(stores)}")
    for option, allowed in _OPTION_PROTOCOLS.items():
        if getattr(args, option, None) and args.protocol not in allowed:
            here = [name for name in allowed if name in protocols]  # only the protocols of this task
            raise InputError(f"--{option}: expected --protocol {' or '.join(here)} (the others do not use it), "
                             f"got --protocol {args.protocol}")
    for option, least in _NUMBER_OPTIONS.items():
        value = getattr(args, option, None)
        if value is not None and not all(np.isfinite(v) and v >= least for v in np.atleast_1d(value)):
            # NaN compares false: --miss-threshold-m nan made no prediction a miss, --score-threshold nan dropped all
            raise InputError(f"--{option.replace('_', '-')}: expected finite numbers"
                             f"{f' >= {least:g}' if least > -np.inf else ''}, got {value}")
    if args.plots is not None and not protocol.plots:
        raise InputError(f"--plots: expected a protocol with curves to plot "
                         f"({', '.join(n for n, p in protocols.items() if p.plots) or 'none'} for {task}), "
                         f"got --protocol {args.protocol}")
    _check_outputs(args, protocol.unified_gt)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", EvalWarning)
        try:
            table, columns = protocol.run(args)
        finally:
            for w in caught:
                if issubclass(w.category, EvalWarning):
                    print(f"avdata: warning: {one_line(str(w.message))}", file=sys.stderr)
    return _emit(args, table, columns)


def _check_outputs(args: argparse.Namespace, unified_gt: bool) -> None:
    """Refuses --json, --markdown and --plots paths that would replace an input or each other, before the run.

    ``--json GT/avdata.json`` overwrote the dataset's manifest, and ``--json X --markdown X`` kept only the table.
    A publisher's GT folder (KITTI's root) may take new files beside its own; a unified dataset takes none.
    """
    outputs = {option: path for option in ("json", "markdown", "plots")
               if (path := getattr(args, option, None)) is not None}
    inputs = {name: path for name, option in (("GT", "gt"), ("PRED", "pred"), ("--tracks", "tracks"))
              if (path := getattr(args, option, None)) is not None}
    for path in outputs.values():
        for name, source in inputs.items():
            if name != "GT" or unified_gt or os.path.lexists(path):
                refuse_output_in_input(path, [source], name)
    if len({os.path.realpath(path) for path in outputs.values()}) < len(outputs):  # Path.resolve raises on a link loop
        raise InputError(f"--json, --markdown, --plots: expected a different path for each, got "
                         f"{' '.join(f'--{option} {path}' for option, path in outputs.items())}")


def _emit(args: argparse.Namespace, table: Table, columns: list[str] | None) -> int:
    markdown = report.to_markdown(table, columns)
    sys.stdout.write(markdown)
    if args.json is not None:
        report.write_json(args.json, table)
    if args.markdown is not None:
        write_atomically(args.markdown, markdown)
    return 0


def run_tracking(args: argparse.Namespace) -> int:
    """Runs ``avdata eval tracking``; returns the exit status."""
    return _run(args, TRACKING_PROTOCOLS, "tracking")


def run_detection(args: argparse.Namespace) -> int:
    """Runs ``avdata eval detection``; returns the exit status."""
    return _run(args, DETECTION_PROTOCOLS, "detection")


def run_prediction(args: argparse.Namespace) -> int:
    """Runs ``avdata eval prediction``; returns the exit status."""
    return _run(args, PREDICTION_PROTOCOLS, "prediction")


def run_safety(args: argparse.Namespace) -> int:
    """Runs ``avdata eval safety``: RSS violations of each dataset's ego (see :mod:`avdata.eval.safety`)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    from avdata.eval.safety import evaluate_safety
    from avdata.eval.unified import check_frames, check_unique_track_ids, read_table
    from avdata.schema import DatasetReader

    _check_outputs(args, unified_gt=True)
    ds = DatasetReader(args.gt, verify=True)
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
        check_frames(args.tracks, tracks, ds.frames())  # every row a frame of the dataset, before --scenes picks
        check_unique_track_ids(args.tracks, tracks)
        tracks = tracks.filter(pc.is_in(tracks["scene"], keep))
    result = evaluate_safety(frames, objects, tracks, exclude_ids=own).as_dict()
    return _emit(args, {"all": result}, None)
