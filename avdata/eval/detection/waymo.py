"""Waymo Open Dataset 3D detection metrics: AP and APH per object type at LEVEL_1 and LEVEL_2.

The same numbers as Waymo's ``metrics/ops`` ``detection_metrics`` op (``detection_metrics.cc``,
``metrics_utils.cc``, ``matcher``, ``iou.cc``) with the standard configuration (``OBJECT_TYPE``
breakdown, LEVEL_1 and LEVEL_2, Hungarian matching, upright 3D boxes, IoU thresholds 0.7 vehicle,
0.5 pedestrian / sign / cyclist, score cutoffs 0, 0.01, ..., 0.99, 1.0, recall step 0.05):

* per frame and type, for each score cutoff c, the predictions with ``score >= c`` are matched to the
  ground truths by the Hungarian algorithm on ``round(IoU * 1e6)``, pairs with IoU below the type's
  threshold excluded; IoU is 0 for a box with a side <= 0.01 m;
* a match is a TP whatever the ground truth's difficulty (heading accuracy ``1 - |dheading| / pi``
  summed for APH); an unmatched prediction is an FP unless it overlaps a no-label zone; an unmatched
  ground truth is an FN at level L if its difficulty <= L (UNKNOWN = 0 counts at both levels);
* counts are summed over frames; precision = TP / (TP + FP) (1 when recall is 0), recall =
  TP / (TP + FN); APH uses sum(heading accuracy) in place of TP in the precision only;
* AP integrates the precision envelope over recall with extra points every 0.05 of recall
  (``ComputeMeanAveragePrecision``).

Waymo computes in float32 (``float`` in C++) and accumulates AP in double steps stored to float; this
module does the same operations in the same order (``numpy.float32``), so results agree to float
rounding. Boxes are ``(center_x, center_y, center_z, length, width, height, heading)`` in the vehicle
frame of each frame.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path

import numpy as np
import pyarrow as pa
from scipy.optimize import linear_sum_assignment

from avdata.errors import InputError
from avdata.eval.geometry import box3d_iou
from avdata.eval.problems import check_ground_truth
from avdata.eval.unified import read_table, warn_unknown_classes
from avdata.schema import UNIFIED_CLASSES

__all__ = [
    "WaymoBoxes",
    "WaymoDetectionConfig",
    "WaymoDetectionMetrics",
    "WaymoType",
    "evaluate_waymo_detection",
    "ground_truth_difficulty",
    "load_waymo_detection",
    "mean_average_precision",
    "read_predictions",
    "summary",
]

_F32 = np.float32
#: ``kMaxIoU`` of Waymo's ``iou.cc``: IoUs are quantised to integers of 1e-6 for matching.
MAX_IOU = 1_000_000
#: Box sides at or below this (metres) give IoU 0 (``kMinBoxDim``).
MIN_BOX_DIM_M = 1e-2


class WaymoType(IntEnum):
    """``label.proto`` ``Label.Type`` (``TYPE_*``)."""

    VEHICLE = 1
    PEDESTRIAN = 2
    SIGN = 3
    CYCLIST = 4


#: Unified class -> Waymo type, for predictions that carry no Waymo type of their own.
UNIFIED_TO_WAYMO: dict[str, WaymoType] = {
    "car": WaymoType.VEHICLE,
    "truck": WaymoType.VEHICLE,
    "bus": WaymoType.VEHICLE,
    "trailer": WaymoType.VEHICLE,
    "construction_vehicle": WaymoType.VEHICLE,
    "pedestrian": WaymoType.PEDESTRIAN,
    "cyclist": WaymoType.CYCLIST,
}


@dataclass(frozen=True, slots=True, kw_only=True)
class WaymoDetectionConfig:
    """The detection metrics configuration (Waymo's ``metrics.proto`` ``Config``).

    Attributes:
        iou_thresholds: IoU threshold per type value 0..4 (UNKNOWN, VEHICLE, PEDESTRIAN, SIGN, CYCLIST).
        score_cutoffs: prediction score cutoffs, one PR point each.
        desired_recall_delta: recall step of the AP integration.
        min_precision: precisions below this count as 0.
        min_heading_accuracy: TPs with heading accuracy at or below this are dropped (Waymo's default -1: none).
        types: the types reported.
        levels: the difficulty levels reported.
    """

    iou_thresholds: tuple[float, ...] = (0.0, 0.7, 0.5, 0.5, 0.5)
    score_cutoffs: tuple[float, ...] = tuple(i * 0.01 for i in range(100)) + (1.0,)
    desired_recall_delta: float = 0.05
    min_precision: float = 0.0
    min_heading_accuracy: float = -1.0
    types: tuple[WaymoType, ...] = (WaymoType.VEHICLE, WaymoType.PEDESTRIAN, WaymoType.SIGN, WaymoType.CYCLIST)
    levels: tuple[int, ...] = (1, 2)


@dataclass(frozen=True, slots=True, kw_only=True)
class WaymoBoxes:
    """Ground truths or predictions of many frames, as arrays.

    Attributes:
        frame_id: (N,) int64 frame of each box.
        box: (N, 7) center x, y, z, length, width, height (m), heading (rad), vehicle frame.
        type: (N,) Waymo type values (1..4).
        score: (N,) prediction scores (predictions only).
        difficulty: (N,) detection difficulty level 0..2 (ground truths only).
        overlap_nlz: (N,) whether a prediction overlaps a no-label zone (predictions only).
    """

    frame_id: np.ndarray
    box: np.ndarray
    type: np.ndarray
    score: np.ndarray | None = None
    difficulty: np.ndarray | None = None
    overlap_nlz: np.ndarray | None = None

    def __post_init__(self) -> None:
        """Checks that every column has one row per box."""
        n = len(np.asarray(self.frame_id))
        box = np.asarray(self.box, dtype=np.float32).reshape(-1, 7)
        if box.shape[0] != n:
            raise InputError(f"expected {n} boxes of 7 values, got {box.shape[0]}")
        if not np.all(np.isfinite(box)):
            raise InputError(f"expected finite boxes, got NaN or inf in row {int(np.flatnonzero(~np.isfinite(box).all(1))[0])}")
        object.__setattr__(self, "frame_id", np.asarray(self.frame_id, dtype=np.int64))
        object.__setattr__(self, "box", box)
        object.__setattr__(self, "type", np.asarray(self.type, dtype=np.int64))
        for name, dtype in (("score", np.float32), ("difficulty", np.int64), ("overlap_nlz", bool)):
            value = getattr(self, name)
            if value is not None:
                value = np.asarray(value, dtype=dtype).reshape(-1)
                if value.shape[0] != n:
                    raise InputError(f"expected {n} values of {name}, got {value.shape[0]}")
                object.__setattr__(self, name, value)


@dataclass(frozen=True, slots=True, kw_only=True)
class WaymoDetectionMetrics:
    """One (type, level) breakdown: AP, APH and the curve behind them.

    Attributes:
        ap: average precision.
        aph: heading-weighted average precision.
        precision: (C,) per score cutoff.
        recall: (C,) per score cutoff.
        precision_ha: (C,) heading-weighted precision per score cutoff.
        tp: (C,) true positives per score cutoff.
        fp: (C,) false positives.
        fn: (C,) false negatives.
    """

    ap: float
    aph: float
    precision: np.ndarray
    recall: np.ndarray
    precision_ha: np.ndarray
    tp: np.ndarray
    fp: np.ndarray
    fn: np.ndarray


def _normalize_angle(rad: float) -> float:
    """``NormalizeAngle``: wraps to [-pi, pi) in double, as ``WrapToRange(-M_PI, M_PI, rad)``."""
    x = rad + math.pi
    y = 2.0 * math.pi
    modulo = x - math.trunc(x * (1.0 / y)) * y
    shifted = y + modulo
    wrapped = modulo if modulo >= 0 else (0.0 if shifted >= y else shifted)
    return wrapped - math.pi


def heading_accuracy(pd_heading: float, gt_heading: float) -> np.float32:
    """``ComputeHeadingAccuracy``: 1 - |heading difference| / pi, headings as float32 inputs."""
    pd = _F32(_normalize_angle(float(pd_heading)))
    gt = _F32(_normalize_angle(float(gt_heading)))
    diff = _F32(abs(pd - gt))
    if float(diff) > math.pi:
        diff = _F32(2.0 * math.pi - float(diff))
    accuracy: np.float32 = _F32(min(1.0, max(0.0, 1.0 - float(diff) / math.pi)))
    return accuracy


def _iou(pd_box: np.ndarray, gt_box: np.ndarray) -> np.ndarray:
    """(P, G) float32 IoU as ``ComputeIoU3d`` gives it (inputs float32 boxes, computed in double)."""
    if not len(pd_box) or not len(gt_box):
        return np.zeros((len(pd_box), len(gt_box)), dtype=np.float32)
    iou = box3d_iou(pd_box.astype(np.float64), gt_box.astype(np.float64))
    tiny_pd = np.any(pd_box[:, 3:6].astype(np.float64) <= MIN_BOX_DIM_M, axis=1)
    tiny_gt = np.any(gt_box[:, 3:6].astype(np.float64) <= MIN_BOX_DIM_M, axis=1)
    iou[tiny_pd, :] = 0.0
    iou[:, tiny_gt] = 0.0
    result: np.ndarray = np.clip(iou, 0.0, 1.0).astype(np.float32)
    return result


def _frame_measurements(pd_box: np.ndarray, scores: np.ndarray, nlz: np.ndarray, gt_box: np.ndarray, difficulty: np.ndarray,
                        threshold: np.float32, config: WaymoDetectionConfig) -> np.ndarray:
    """(cutoffs, levels, 4) [TP, FP, FN, sum_ha] of one frame and type (predictions and ground truths of it)."""
    cutoffs = np.asarray(config.score_cutoffs, dtype=np.float32)
    out = np.zeros((len(cutoffs), len(config.levels), 4), dtype=np.float64)
    iou = _iou(pd_box, gt_box)
    can_match = iou >= threshold
    weight = np.where(can_match, np.floor(iou * _F32(MAX_IOU) + _F32(0.5)), 0.0)
    for c, cutoff in enumerate(cutoffs):
        subset = np.flatnonzero(scores >= cutoff)
        pd_match = np.full(len(subset), -1)
        gt_matched = np.zeros(len(gt_box), dtype=bool)
        if len(subset) and len(gt_box):
            rows, cols = linear_sum_assignment(weight[subset], maximize=True)
            good = weight[subset][rows, cols] > 0
            pd_match[rows[good]] = cols[good]
            gt_matched[cols[good]] = True
        sum_ha = _F32(0.0)
        tp = 0
        for i, g in enumerate(pd_match.tolist()):
            if g >= 0:
                accuracy = heading_accuracy(pd_box[subset[i], 6], gt_box[g, 6])
                if accuracy <= config.min_heading_accuracy:
                    continue
                sum_ha = _F32(sum_ha + accuracy)
                tp += 1
        fp = int(np.sum((pd_match < 0) & ~nlz[subset]))
        for k, level in enumerate(config.levels):
            fn = int(np.sum(~gt_matched & (difficulty <= level)))
            out[c, k] = (tp, fp, fn, sum_ha)
    return out


def mean_average_precision(precisions: np.ndarray, recalls: np.ndarray, max_recall_delta: float) -> float:
    """``ComputeMeanAveragePrecision`` in float32, operation for operation."""
    if not len(precisions):
        return 0.0
    table: dict[np.float32, np.float32] = {_F32(0.0): _F32(1.0)}
    for p, r in zip(np.asarray(precisions, np.float32), np.asarray(recalls, np.float32), strict=True):
        table[r] = max(table.get(r, _F32(0.0)), p)
    delta = _F32(max_recall_delta)
    limit = _F32(delta + _F32(1e-6))
    keys = sorted(table)
    last_recall = keys[0]
    max_precision = _F32(0.0)
    curve: list[list[np.float32]] = []
    for r in reversed(keys):
        while _F32(last_recall - r) > limit:
            last_recall = _F32(last_recall - delta)
            curve.append([max_precision, last_recall])
        max_precision = max(table[r], max_precision)
        curve.append([max_precision, r])
        last_recall = r
    if len(curve) >= 2:
        curve[-1][0] = curve[-2][0]
    ap = _F32(0.0)
    for i in range(1, len(curve)):
        step = 0.5 * float(_F32(curve[i - 1][1] - curve[i][1])) * float(_F32(curve[i - 1][0] + curve[i][0]))
        ap = _F32(float(ap) + step)
    return float(ap)


def evaluate_waymo_detection(gt: WaymoBoxes, pred: WaymoBoxes,
                             config: WaymoDetectionConfig | None = None) -> dict[tuple[WaymoType, int], WaymoDetectionMetrics]:
    """AP and APH of every (type, level) of ``config``.

    Args:
        gt: ground truths with ``difficulty``.
        pred: predictions with ``score`` (and optionally ``overlap_nlz``).
        config: the metrics configuration (Waymo's standard one by default).

    Returns:
        (type, level) -> metrics.
    """
    config = config or WaymoDetectionConfig()
    if gt.difficulty is None or pred.score is None:
        raise InputError("expected ground truths with difficulty levels and predictions with scores")
    check_ground_truth("ground truth", [t.name for t in config.types],
                       [t.name for t in config.types if not np.any(gt.type == int(t))], "their AP and APH are 0")
    nlz = pred.overlap_nlz if pred.overlap_nlz is not None else np.zeros(len(pred.frame_id), dtype=bool)
    frames = np.union1d(gt.frame_id, pred.frame_id)
    n_cut, n_lev = len(config.score_cutoffs), len(config.levels)
    result = {}
    for waymo_type in config.types:
        threshold = _F32(config.iou_thresholds[int(waymo_type)])
        total = np.zeros((n_cut, n_lev, 4), dtype=np.float64)
        sum_ha = np.zeros((n_cut, n_lev), dtype=np.float32)
        for frame in frames.tolist():
            pd_rows = np.flatnonzero((pred.frame_id == frame) & (pred.type == int(waymo_type)))
            gt_rows = np.flatnonzero((gt.frame_id == frame) & (gt.type == int(waymo_type)))
            m = _frame_measurements(pred.box[pd_rows], pred.score[pd_rows], nlz[pd_rows], gt.box[gt_rows],
                                    gt.difficulty[gt_rows], threshold, config)
            total[..., :3] += m[..., :3]
            sum_ha = (sum_ha + m[..., 3].astype(np.float32)).astype(np.float32)
        for k, level in enumerate(config.levels):
            tp, fp, fn = (total[:, k, j].astype(np.int64) for j in range(3))
            precision = np.zeros(n_cut, dtype=np.float32)
            precision_ha = np.zeros(n_cut, dtype=np.float32)
            recall = np.zeros(n_cut, dtype=np.float32)
            for c in range(n_cut):
                tp_fp, tp_fn = int(tp[c] + fp[c]), int(tp[c] + fn[c])
                if tp_fp > 0:
                    p = _F32(_F32(tp[c]) / _F32(tp_fp))
                    p_ha = _F32(sum_ha[c, k] / _F32(tp_fp))
                    precision[c] = 0.0 if p < config.min_precision else p
                    precision_ha[c] = 0.0 if p_ha < config.min_precision else p_ha
                if tp_fn > 0:
                    recall[c] = _F32(_F32(tp[c]) / _F32(tp_fn))
                if recall[c] == 0.0:
                    precision[c] = 1.0
                    precision_ha[c] = 1.0
            result[(waymo_type, level)] = WaymoDetectionMetrics(
                ap=mean_average_precision(precision, recall, config.desired_recall_delta),
                aph=mean_average_precision(precision_ha, recall, config.desired_recall_delta),
                precision=precision, recall=recall, precision_ha=precision_ha, tp=tp, fp=fp, fn=fn,
            )
    return result


def summary(metrics: dict[tuple[WaymoType, int], WaymoDetectionMetrics]) -> dict[str, dict[str, float]]:
    """``{"VEHICLE": {"AP/L1": .., "APH/L1": .., "AP/L2": .., "APH/L2": ..}, ...}`` for reports."""
    table: dict[str, dict[str, float]] = {}
    for (waymo_type, level), m in metrics.items():
        row = table.setdefault(waymo_type.name, {})
        row[f"AP/L{level}"] = m.ap
        row[f"APH/L{level}"] = m.aph
    return table


_PRED_BOX = ["x_ego_m", "y_ego_m", "z_ego_m", "length_m", "width_m", "height_m", "yaw_ego_rad"]
#: Columns every prediction table has (plus ``source_class`` or ``class``).
PREDICTION_COLUMNS = ("scene", "frame_index", "score", *_PRED_BOX)


def read_predictions(path: str | Path) -> pa.Table:
    """A Parquet or JSON prediction table with :data:`PREDICTION_COLUMNS` (see :func:`load_waymo_detection`)."""
    return read_table(path, PREDICTION_COLUMNS)


#: Ground truths with at most this many lidar points and no labelled difficulty are LEVEL_2
#: (``kDetectionLevel2NumPointsThreshold`` of Waymo's ``compute_detection_metrics_main.cc``).
LEVEL_2_MAX_POINTS = 5


def ground_truth_difficulty(labelled: np.ndarray, num_lidar_points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Waymo's ground-truth preparation (``compute_detection_metrics_main.cc``): which boxes count, at which level.

    Boxes without lidar points are dropped; a box without a labelled difficulty (UNKNOWN, 0) is LEVEL_2
    with at most :data:`LEVEL_2_MAX_POINTS` points, else LEVEL_1; labelled levels are kept.

    Args:
        labelled: (N,) labelled detection difficulty (0 unknown, 1, 2).
        num_lidar_points: (N,) ``num_lidar_points_in_box``.

    Returns:
        ((N,) bool kept, (N,) difficulty level).
    """
    labelled = np.asarray(labelled, dtype=np.int64)
    points = np.asarray(num_lidar_points, dtype=np.float64)
    by_points = np.where(points <= LEVEL_2_MAX_POINTS, 2, 1)
    return points > 0, np.where(labelled == 0, by_points, labelled)


def load_waymo_detection(objects: pa.Table, predictions: pa.Table, source: str | Path) -> tuple[WaymoBoxes, WaymoBoxes]:
    """Ground truth from a converted Waymo dataset's object table and predictions in its ego frames.

    Predictions: ``scene``, ``frame_index``, ``score``, ``x_ego_m`` ... ``yaw_ego_rad`` (the vehicle frame at
    the frame time, as Waymo evaluates) and either ``source_class`` (``TYPE_VEHICLE`` ...) or ``class``
    (unified; car/truck/bus/trailer/construction_vehicle -> VEHICLE); predictions of other classes are not
    evaluated; with both, ``source_class`` is scored and a ``class`` naming another Waymo type is an error. An
    optional boolean ``overlap_nlz`` marks predictions overlapping a no-label zone (never FPs).
    Ground truths are prepared as Waymo's own evaluation tool does (:func:`ground_truth_difficulty` on the
    converted ``detection_difficulty_level`` and ``num_lidar_points_in_box``).

    The object table knows only frames with boxes, so predictions are not checked against the dataset's frames
    here: check them with :func:`avdata.eval.unified.check_frames` and ``index/frames.parquet`` first, as the
    command line does (a prediction of an unknown scene or frame would count as a false positive).

    Args:
        objects: ``index/objects.parquet`` of the converted dataset.
        predictions: the prediction table.
        source: the predictions' file, for error messages.
    """
    keys: dict[tuple[str, int], int] = {}

    def frame_ids(table: pa.Table) -> np.ndarray:
        scenes = table.column("scene").to_pylist()
        index = table.column("frame_index").to_pylist()
        return np.asarray([keys.setdefault((s, int(i)), len(keys)) for s, i in zip(scenes, index, strict=True)], dtype=np.int64)

    by_name = {f"TYPE_{t.name}": int(t) for t in WaymoType}
    gt_type = np.asarray([by_name.get(s, 0) for s in objects.column("source_class").to_pylist()], dtype=np.int64)
    extras = [json.loads(e) if e else {} for e in objects.column("extras_json").to_pylist()]
    levels = np.asarray([e.get("detection_difficulty_level", 0.0) for e in extras], dtype=np.float64)
    points = np.asarray([e.get("num_lidar_points_in_box", np.nan) for e in extras], dtype=np.float64)
    if np.any(np.isnan(points)):
        raise InputError(f"ground truth row {int(np.flatnonzero(np.isnan(points))[0])}: expected num_lidar_points_in_box "
                         "in extras (a converted Waymo dataset), got none")
    kept, difficulty = ground_truth_difficulty(np.nan_to_num(levels).astype(np.int64), points)
    gt_box = np.stack([objects.column(c).to_numpy(zero_copy_only=False) for c in _PRED_BOX], axis=1)
    frames = frame_ids(objects)
    gt = WaymoBoxes(frame_id=frames[kept], box=gt_box[kept], type=gt_type[kept], difficulty=difficulty[kept])
    missing = [c for c in PREDICTION_COLUMNS if c not in predictions.column_names]
    if missing:
        raise InputError(f"{source}: expected prediction columns {missing}, got none of them")
    if "source_class" in predictions.column_names:
        names = predictions.column("source_class").to_pylist()
        unknown = sorted({n for n in names if n not in by_name})
        if unknown:
            raise InputError(f"{source}: source_class: expected one of {sorted(by_name)}, got {unknown[0]!r}")
        pd_type = np.asarray([by_name[n] for n in names], dtype=np.int64)
        if "class" in predictions.column_names:  # both: source_class is scored, so a class naming another type is damage
            for row, (name, unified) in enumerate(zip(names, predictions.column("class").to_pylist(), strict=True)):
                if unified in UNIFIED_TO_WAYMO and int(UNIFIED_TO_WAYMO[unified]) != by_name[name]:
                    raise InputError(f"{source}: row {row}: class {unified!r} is Waymo's TYPE_"
                                     f"{UNIFIED_TO_WAYMO[unified].name}, but source_class says {name!r}")
    elif "class" in predictions.column_names:
        warn_unknown_classes(source, predictions, UNIFIED_CLASSES, "they are not evaluated")
        pd_type = np.asarray([int(UNIFIED_TO_WAYMO.get(c, 0)) for c in predictions.column("class").to_pylist()], dtype=np.int64)
    else:
        raise InputError(f"{source}: expected a source_class or class column, got neither")
    pd_box = np.stack([np.asarray(predictions.column(c).to_numpy(zero_copy_only=False), dtype=np.float64)
                       for c in _PRED_BOX], axis=1)
    if not np.all(np.isfinite(pd_box)):
        row = int(np.flatnonzero(~np.isfinite(pd_box).all(axis=1))[0])
        raise InputError(f"{source}: row {row}: expected finite box values, got {pd_box[row].tolist()}")
    known = frame_ids(predictions)
    nlz = (np.asarray(predictions.column("overlap_nlz").to_pylist(), dtype=bool)
           if "overlap_nlz" in predictions.column_names else None)
    pred = WaymoBoxes(frame_id=known, box=pd_box, type=pd_type, overlap_nlz=nlz,
                      score=np.asarray(predictions.column("score").to_numpy(zero_copy_only=False), dtype=np.float32))
    return gt, pred
