"""OpenCOOD's detection evaluation (OPV2V, V2XSet, V2V4Real, DAIR-V2X cooperative): BEV AP at IoU 0.3/0.5/0.7.

Implemented from OpenCOOD's public ``opencood/utils/eval_utils.py`` (``caluclate_tp_fp``, ``calculate_ap``,
``voc_ap``) and ``opencood/utils/box_utils.py`` / ``common_utils.py`` (box corners, polygon IoU), not
imported from them:

* per frame, in the ego frame, class-agnostic: ground truth and predictions whose four BEV corners all lie
  inside the evaluation range ``(x_min, y_min, x_max, y_max)`` are kept (``mask_boxes_outside_range_numpy``
  with ``min_num_corners=8`` for the ground truth; the post-processor's range mask for predictions);
* IoU is the area-exact IoU of the two rotated BEV rectangles (OpenCOOD: shapely polygons of the corners);
* detections are taken by descending score; each is a TP at threshold τ when its best IoU with the ground
  truths still unmatched in its frame is >= τ (that ground truth is then removed), else an FP;
* the TP/FP lists are concatenated frame after frame (OpenCOOD's default; ``global_sort=True`` sorts all
  detections by score, its ``--global_sort_detections``), cumulated; recall = TP / #GT, precision =
  TP / (TP + FP);
* AP is ``voc_ap``: recall padded with 0 and 1, precision with 0 and 0, precision made monotone from the
  right, AP = Σ (r_i - r_{i-1}) p_i over the indices where recall changes. This is the list-based form of
  the OPV2V-era code; one later revision in the index writes ``np.dot(Δr, r_i)`` on numpy arrays (it
  would fail on ``list.insert``), which is not followed.

Ranges (:data:`EVAL_RANGES_M`): OPV2V / V2XSet [-140.8, 140.8] x [-40, 40] m (OpenCOOD's
``cav_lidar_range``); V2V4Real [-140.8, 140.8] x [-38.4, 38.4] (the ``cav_lidar_range`` of V2V4Real's own
intermediate-fusion configs, ``opencood/hypes_yaml/point_pillar_fax.yaml``; its late-fusion config uses each car's own
[-70.4, 70.4] x [-40, 40]); DAIR-V2X [-102.4, 102.4] x [-38.4, 38.4] (the range of the DAIR-V2X configs of the OpenCOOD
family, e.g. CoAlign's); pass ``range_m`` for your own.

Ties (equal scores) are taken in input order (a stable sort); OpenCOOD's ``np.argsort(-score)`` leaves
their order to numpy's quicksort.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from avdata.errors import InputError
from avdata.eval.geometry import bev_corners, bev_iou
from avdata.eval.unified import read_table

__all__ = ["EVAL_RANGES_M", "IOU_THRESHOLDS", "PREDICTION_COLUMNS", "Opv2vDetectionResult", "evaluate_opv2v",
           "frame_tp_fp", "in_range", "load_opv2v", "voc_ap"]

#: IoU thresholds OpenCOOD reports.
IOU_THRESHOLDS = (0.3, 0.5, 0.7)
#: Ego-frame BEV evaluation ranges (x_min, y_min, x_max, y_max) in metres.
EVAL_RANGES_M = {
    "opv2v": (-140.8, -40.0, 140.8, 40.0),
    "v2xset": (-140.8, -40.0, 140.8, 40.0),
    "v2v4real": (-140.8, -38.4, 140.8, 38.4),
    "dair_v2x": (-102.4, -38.4, 102.4, 38.4),
}
_BOX = ("x_ego_m", "y_ego_m", "z_ego_m", "length_m", "width_m", "height_m", "yaw_ego_rad")
#: Columns of a prediction table (the unified one, boxes in the ego frame of their frame); ``class`` optional.
PREDICTION_COLUMNS = ("scene", "frame_index", "score", *_BOX)


def voc_ap(recall: np.ndarray, precision: np.ndarray) -> float:
    """VOC 2010 AP of OpenCOOD's ``voc_ap``.

    Args:
        recall: (K,) cumulative recall, non-decreasing.
        precision: (K,) cumulative precision.

    Returns:
        Σ (r_i - r_{i-1}) p_i over the recall changes of ``[0, recall, 1]``, with ``[0, precision, 0]`` made
        monotone from the right.
    """
    mrec = np.concatenate([[0.0], np.asarray(recall, dtype=np.float64), [1.0]])
    mpre = np.concatenate([[0.0], np.asarray(precision, dtype=np.float64), [0.0]])
    mpre = np.maximum.accumulate(mpre[::-1])[::-1]
    changes = np.flatnonzero(mrec[1:] != mrec[:-1]) + 1
    return float(np.sum((mrec[changes] - mrec[changes - 1]) * mpre[changes]))


def in_range(boxes: np.ndarray, range_m: Sequence[float]) -> np.ndarray:
    """(N,) whether all four BEV corners of each box (N, 7) lie inside ``(x_min, y_min, x_max, y_max)``."""
    corners = bev_corners(np.asarray(boxes, dtype=np.float64).reshape(-1, 7)[:, [0, 1, 3, 4, 6]])
    x_min, y_min, x_max, y_max = range_m
    inside = (corners[..., 0] >= x_min) & (corners[..., 0] <= x_max) & (corners[..., 1] >= y_min) & (corners[..., 1] <= y_max)
    return np.asarray(inside.all(axis=1))


def frame_tp_fp(pred: np.ndarray, scores: np.ndarray, gt: np.ndarray, iou_threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """TP flags and scores of one frame's detections, in descending score order (``caluclate_tp_fp``).

    Args:
        pred: (N, 7) detections.
        scores: (N,) their scores.
        gt: (M, 7) ground truths.
        iou_threshold: the IoU a TP needs.

    Returns:
        ((N,) bool TP, (N,) scores), both in descending score order.
    """
    order = np.argsort(-np.asarray(scores, dtype=np.float64), kind="stable")
    iou = bev_iou(np.asarray(pred, dtype=np.float64)[order], gt) if len(gt) else np.zeros((len(order), 0))
    unmatched = np.ones(len(gt), dtype=bool)
    tp = np.zeros(len(order), dtype=bool)
    for i in range(len(order)):  # greedy by score: each detection sees what the better ones left
        candidates = np.where(unmatched, iou[i], -np.inf)
        if len(gt) and candidates.max() >= iou_threshold:
            tp[i] = True
            unmatched[int(np.argmax(candidates))] = False
    return tp, np.asarray(scores, dtype=np.float64)[order]


@dataclass(frozen=True, slots=True, kw_only=True)
class Opv2vDetectionResult:
    """AP per IoU threshold, with the PR curves and counts behind it.

    Attributes:
        ap: threshold -> AP.
        recall: threshold -> (K,) cumulative recall.
        precision: threshold -> (K,) cumulative precision.
        n_gt: ground truths inside the range.
        n_pred: predictions inside the range.
    """

    ap: dict[float, float]
    recall: dict[float, np.ndarray]
    precision: dict[float, np.ndarray]
    n_gt: int
    n_pred: int

    def summary(self) -> dict[str, dict[str, float]]:
        """``{"all": {"AP@0.3": ..., "AP@0.5": ..., "AP@0.7": ..., "GT": ..., "detections": ...}}``."""
        row: dict[str, float] = {f"AP@{t:g}": v for t, v in self.ap.items()}
        row.update(GT=self.n_gt, detections=self.n_pred)
        return {"all": row}


def evaluate_opv2v(
    gt: dict[tuple[str, int], np.ndarray],
    pred: dict[tuple[str, int], tuple[np.ndarray, np.ndarray]],
    *,
    range_m: Sequence[float] = EVAL_RANGES_M["opv2v"],
    iou_thresholds: Sequence[float] = IOU_THRESHOLDS,
    global_sort: bool = False,
    source: str | Path = "predictions",
) -> Opv2vDetectionResult:
    """OpenCOOD's AP over frames.

    Args:
        gt: (scene, frame_index) -> (M, 7) ground-truth boxes in the ego frame; every evaluated frame.
        pred: (scene, frame_index) -> ((N, 7) boxes in the ego frame, (N,) scores); a missing frame has none.
        range_m: (x_min, y_min, x_max, y_max) ego-frame evaluation range.
        iou_thresholds: thresholds to report.
        global_sort: sort all detections by score before cumulating (else frame after frame).
        source: the predictions file, named by the message about its frames.

    Raises:
        InputError: predictions of a frame without ground truth entry, or no ground truth at all.
    """
    unknown = sorted(set(pred) - set(gt))
    if unknown:
        raise InputError(f"{source}: expected frames of the ground truth, got scene {unknown[0][0]!r} "
                         f"frame {unknown[0][1]}")
    kept_gt = {key: boxes[in_range(boxes, range_m)] for key, boxes in gt.items()}
    kept_pred = {}
    for key, (boxes, scores) in pred.items():
        inside = in_range(boxes, range_m)
        kept_pred[key] = (boxes[inside], np.asarray(scores)[inside])
    n_gt = sum(len(b) for b in kept_gt.values())
    if n_gt == 0:
        raise InputError(f"ground truth: expected boxes inside the range {list(range_m)}, got none")
    ap, recall, precision = {}, {}, {}
    empty = (np.zeros((0, 7)), np.zeros(0))
    for threshold in iou_thresholds:
        parts = [frame_tp_fp(*kept_pred.get(key, empty), kept_gt[key], threshold) for key in sorted(kept_gt)]
        tp = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, dtype=bool)
        if global_sort:
            tp = tp[np.argsort(-np.concatenate([p[1] for p in parts]), kind="stable")]
        cum_tp, cum_fp = np.cumsum(tp), np.cumsum(~tp)
        recall[threshold] = cum_tp / n_gt
        precision[threshold] = cum_tp / np.maximum(cum_tp + cum_fp, 1)
        ap[threshold] = voc_ap(recall[threshold], precision[threshold])
    return Opv2vDetectionResult(ap=ap, recall=recall, precision=precision, n_gt=n_gt,
                                n_pred=sum(len(b) for b, _ in kept_pred.values()))


def load_opv2v(objects: pa.Table, predictions_path: str | Path, classes: Sequence[str] | None = None,
               ) -> tuple[dict[tuple[str, int], np.ndarray], dict[tuple[str, int], tuple[np.ndarray, np.ndarray]]]:
    """Ground truth from a unified dataset's ``index/objects.parquet`` and predictions from a table.

    Every frame that has objects is evaluated. Agents' own boxes are ground truth as in OpenCOOD (an
    other CAV is an object to detect). ``classes`` restricts both sides (a prediction without a
    ``class`` column is class-agnostic, as OpenCOOD's detectors are).

    Args:
        objects: the objects index (``x_ego_m`` ... ``yaw_ego_rad``).
        predictions_path: Parquet or JSON with :data:`PREDICTION_COLUMNS` (boxes in each frame's ego frame).
        classes: unified classes to evaluate, or None for all.
    """
    table = read_table(predictions_path, PREDICTION_COLUMNS)
    if classes is not None:
        objects = objects.filter(pc.is_in(objects["class"], pa.array(list(classes))))
        if "class" in table.column_names:
            table = table.filter(pc.is_in(table["class"], pa.array(list(classes))))
    gt = _by_frame(objects)
    pred_boxes = _by_frame(table)
    scores = _by_frame(table, ("score",))
    return gt, {k: (v, scores[k][:, 0]) for k, v in pred_boxes.items()}


def _by_frame(table: pa.Table, columns: Sequence[str] = _BOX) -> dict[tuple[str, int], np.ndarray]:
    if not len(table):
        return {}
    scene = np.asarray(table["scene"].to_pylist(), dtype=str)
    frame = table["frame_index"].to_numpy(zero_copy_only=False).astype(np.int64)
    values = np.stack([table[c].to_numpy(zero_copy_only=False).astype(np.float64) for c in columns], axis=1)
    order = np.lexsort((frame, scene))
    starts = np.flatnonzero(np.r_[True, (scene[order][1:] != scene[order][:-1]) | (frame[order][1:] != frame[order][:-1])])
    return {(str(scene[order[a]]), int(frame[order[a]])): values[rows]
            for a, rows in zip(starts, np.split(order, starts[1:]), strict=True)}
