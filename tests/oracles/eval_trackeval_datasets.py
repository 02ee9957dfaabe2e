"""Oracle: TrackEval 1.3.0 datasets (Kitti2DBox, MotChallenge2DBox) + HOTA/CLEAR/Identity; prints JSON.

    eval_trackeval_datasets.py kitti GT_FOLDER TRACKERS_FOLDER TRACKER_NAME SPLIT
    eval_trackeval_datasets.py mot GT_FOLDER TRACKERS_FOLDER TRACKER_NAME SEQMAP_FILE
Trackers live in TRACKERS_FOLDER/TRACKER_NAME/data/<seq>.txt. Output: {class: {metric: {field: value}}}
for the combined sequences.
"""

import json
import sys

import numpy as np
import trackeval


def to_json(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating,)):
        return float(v)
    return v


def main():
    kind, gt, trackers, name, extra = sys.argv[1:6]
    common = {"GT_FOLDER": gt, "TRACKERS_FOLDER": trackers, "TRACKERS_TO_EVAL": [name], "OUTPUT_FOLDER": None,
              "TRACKER_SUB_FOLDER": "data", "PRINT_CONFIG": False}
    if kind == "kitti":
        dataset = trackeval.datasets.Kitti2DBox(common | {"SPLIT_TO_EVAL": extra, "CLASSES_TO_EVAL": ["car", "pedestrian"]})
        classes = ["car", "pedestrian"]
    else:
        dataset = trackeval.datasets.MotChallenge2DBox(common | {"SEQMAP_FILE": extra, "SKIP_SPLIT_FOL": True,
                                                                 "BENCHMARK": "MOT17", "SPLIT_TO_EVAL": "train"})
        classes = ["pedestrian"]
    metrics = {"HOTA": trackeval.metrics.HOTA(), "CLEAR": trackeval.metrics.CLEAR({"PRINT_CONFIG": False}),
               "Identity": trackeval.metrics.Identity({"PRINT_CONFIG": False})}
    out = {}
    for cls in classes:
        per_seq = {}
        for seq in dataset.seq_list:
            raw = dataset.get_raw_seq_data(name, seq)
            data = dataset.get_preprocessed_seq_data(raw, cls)
            per_seq[seq] = {m: metric.eval_sequence(data) for m, metric in metrics.items()}
        out[cls] = {m: {k: to_json(v) for k, v in metric.combine_sequences({s: per_seq[s][m] for s in per_seq}).items()}
                    for m, metric in metrics.items()}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
