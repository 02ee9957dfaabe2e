"""Waymo's own detection metrics op on boxes from npz files; prints JSON (run with the waymo oracle venv).

``waymo_detection.py INPUT.npz ...`` (one TensorFlow start for many inputs): each npz holds arrays
gt_frame, gt_box (N, 7), gt_type, gt_difficulty, pd_frame, pd_box, pd_type, pd_score, pd_nlz. The config
is Waymo's standard one (OBJECT_TYPE breakdown, LEVEL_1 and LEVEL_2, Hungarian matcher, TYPE_3D, IoU
0.7/0.5/0.5/0.5, score cutoffs 0..0.99 step 0.01 and 1.0). Output: per input, a list with one record per
breakdown: type (shard + 1), level, ap, aph, precision, recall, tp, fp, fn, precision_ha.
"""

import json
import sys

import numpy as np
import tensorflow as tf
from google.protobuf import text_format
from waymo_open_dataset.metrics.ops import py_metrics_ops
from waymo_open_dataset.protos import metrics_pb2


def config() -> metrics_pb2.Config:
    cfg = metrics_pb2.Config()
    text_format.Parse(
        """
        breakdown_generator_ids: OBJECT_TYPE
        difficulties { levels: 1 levels: 2 }
        matcher_type: TYPE_HUNGARIAN
        iou_thresholds: 0.0 iou_thresholds: 0.7 iou_thresholds: 0.5 iou_thresholds: 0.5 iou_thresholds: 0.5
        box_type: TYPE_3D
        """,
        cfg,
    )
    for i in range(100):
        cfg.score_cutoffs.append(i * 0.01)
    cfg.score_cutoffs.append(1.0)
    return cfg


def metrics(path: str) -> list[dict]:
    data = np.load(path)
    out = py_metrics_ops.detection_metrics(
        prediction_bbox=tf.constant(data["pd_box"], tf.float32),
        prediction_type=tf.constant(data["pd_type"], tf.uint8),
        prediction_score=tf.constant(data["pd_score"], tf.float32),
        prediction_frame_id=tf.constant(data["pd_frame"], tf.int64),
        prediction_overlap_nlz=tf.constant(data["pd_nlz"], tf.bool),
        ground_truth_bbox=tf.constant(data["gt_box"], tf.float32),
        ground_truth_type=tf.constant(data["gt_type"], tf.uint8),
        ground_truth_frame_id=tf.constant(data["gt_frame"], tf.int64),
        ground_truth_difficulty=tf.constant(data["gt_difficulty"], tf.uint8),
        config=config().SerializeToString(),
    )
    ap, aph, _, pr, pr_ha, _, breakdown = (t.numpy() for t in out)
    records = []
    for i, (_, shard, level) in enumerate(breakdown.tolist()):
        records.append({
            "type": shard + 1, "level": level, "ap": float(ap[i]), "aph": float(aph[i]),
            "precision": pr[i, :, 0].tolist(), "recall": pr[i, :, 1].tolist(), "tp": pr[i, :, 2].tolist(),
            "fp": pr[i, :, 3].tolist(), "fn": pr[i, :, 4].tolist(), "precision_ha": pr_ha[i, :, 0].tolist(),
        })
    return records


def main() -> None:
    print(json.dumps([metrics(path) for path in sys.argv[1:]]))


if __name__ == "__main__":
    main()
