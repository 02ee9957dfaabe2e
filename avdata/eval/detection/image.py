"""Class-agnostic 2D detection counts of one frame: image boxes matched by 2D IoU (the studies' 2D precision/recall).

A detection and a ground-truth box are a candidate pair when their 2D IoU (:func:`avdata.eval.geometry.box2d_iou`)
is at least the threshold; the frame's one-to-one matching maximises the summed IoU over the candidates
(:func:`avdata.eval.matching.max_weight_matching`, the Hungarian assignment every metric uses). The threshold is
0.5 for every class: the study is class-agnostic, 0.5 is the PASCAL VOC / COCO AP50 convention and what
AB3DMOT's KITTI 2D evaluation uses; KITTI's object benchmark asks 0.7 of cars only.

Ground truth outside the evaluated set (too far, too occluded) is *ignored*: a detection matched to it is
neither a hit nor a false positive, as in the 3D counts of a study.
"""

from __future__ import annotations

import numpy as np

from avdata.eval.geometry import box2d_iou
from avdata.eval.matching import max_weight_matching

__all__ = ["IOU_THRESHOLD_2D", "frame_counts_2d"]

#: The 2D IoU a detection needs with a ground-truth box to match it.
IOU_THRESHOLD_2D = 0.5


def frame_counts_2d(detections_xyxy: np.ndarray, evaluated_xyxy: np.ndarray, ignored_xyxy: np.ndarray,
                    iou_threshold: float = IOU_THRESHOLD_2D) -> tuple[int, int, int]:
    """(TP, FP, FN) of one frame's 2D detections against its evaluated ground-truth boxes.

    Args:
        detections_xyxy: (D, 4) detected ``(x0, y0, x1, y1)`` pixel boxes.
        evaluated_xyxy: (E, 4) ground-truth boxes to be found.
        ignored_xyxy: (K, 4) ground-truth boxes neither to be found nor to count against a detection.
        iou_threshold: the IoU a match needs.

    Returns:
        True positives (matches to evaluated boxes), false positives (unmatched detections), false negatives
        (unmatched evaluated boxes).
    """
    detections = np.asarray(detections_xyxy, dtype=np.float64).reshape(-1, 4)
    evaluated = np.asarray(evaluated_xyxy, dtype=np.float64).reshape(-1, 4)
    truth = np.concatenate([evaluated, np.asarray(ignored_xyxy, dtype=np.float64).reshape(-1, 4)])
    n_det, n_gt = len(detections), len(truth)
    if not n_det or not n_gt:
        return 0, n_det, len(evaluated)
    iou = box2d_iou(truth, detections)  # (G, D)
    g, d = np.nonzero(iou >= iou_threshold)
    matched = max_weight_matching(np.zeros(len(g), np.int64), g, d, iou[g, d], np.array([0, n_gt]),
                                  np.array([0, n_det]))
    matched_gt = g[matched]
    tp = int(np.count_nonzero(matched_gt < len(evaluated)))
    return tp, n_det - len(matched_gt), len(evaluated) - tp
