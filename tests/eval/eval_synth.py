"""Randomised tracking sequences for the oracle tests and hand checks (fixed seeds)."""

from __future__ import annotations

import numpy as np

from avdata.eval.tracking import Similarity, TrackingMetric, TrackingSequence


def random_sequence(rng: np.random.Generator, num_frames: int, num_objects: int, extent: float) -> dict:
    """A ground-truth / tracker pair of flat tables with overlaps, misses, false positives and id switches.

    Boxes are (x0, y0, x1, y1); objects random-walk inside ``[0, extent]^2`` so boxes often overlap.
    """
    start = rng.integers(0, num_frames // 2, num_objects)
    stop = np.minimum(num_frames, start + rng.integers(2, num_frames, num_objects))
    gt_frame, gt_id, gt_box = [], [], []
    tr_frame, tr_id, tr_box = [], [], []
    next_tracker_id = 1000
    for obj in range(num_objects):
        n = stop[obj] - start[obj]
        centre = rng.uniform(0, extent, 2) + np.cumsum(rng.normal(0, extent / 40, (n, 2)), axis=0)
        size = rng.uniform(extent / 12, extent / 5, 2)
        boxes = np.c_[centre - size / 2, centre + size / 2]
        frames = np.arange(start[obj], stop[obj])
        gt_frame.append(frames)
        gt_id.append(np.full(n, obj))
        gt_box.append(boxes)
        keep = rng.random(n) > 0.15
        ids = np.full(n, next_tracker_id)
        switch = rng.integers(0, n)
        if rng.random() < 0.4:
            ids[switch:] = next_tracker_id + 1
        next_tracker_id += 2
        noise = rng.normal(0, extent / 60, (n, 4))
        tr_frame.append(frames[keep])
        tr_id.append(ids[keep])
        tr_box.append((boxes + noise)[keep])
    n_fp = num_frames * num_objects // 10
    fp_frame = rng.integers(0, num_frames, n_fp)
    fp_centre = rng.uniform(0, extent, (n_fp, 2))
    fp_size = rng.uniform(extent / 12, extent / 5, (n_fp, 2))
    tr_frame.append(fp_frame)
    tr_id.append(next_tracker_id + np.arange(n_fp) // 3)
    tr_box.append(np.c_[fp_centre - fp_size / 2, fp_centre + fp_size / 2])
    gt = (np.concatenate(gt_frame), np.concatenate(gt_id), np.concatenate(gt_box))
    tr = (np.concatenate(tr_frame), np.concatenate(tr_id), np.concatenate(tr_box))
    # Tracker ids must be unique per frame: the false positives share ids in triples across frames, so drop
    # repeats of (frame, id).
    key = tr[0] * 10**6 + tr[1]
    _, first = np.unique(key, return_index=True)
    first = np.sort(first)
    tr = tuple(a[first] for a in tr)
    return {
        "num_frames": num_frames,
        "gt_frame": gt[0], "gt_id": gt[1], "gt_box": gt[2],
        "tr_frame": tr[0], "tr_id": tr[1], "tr_box": tr[2],
    }


def save_npz(path, sequences: dict[str, dict]) -> None:
    np.savez(path, **{f"{name}/{k}": np.asarray(v) for name, seq in sequences.items() for k, v in seq.items()})


def tracking_sequences(seqs: dict[str, dict], similarity: Similarity) -> dict[str, TrackingSequence]:
    """The sequences of :func:`random_sequence` tables (Euclidean: the boxes' centres)."""
    built = {}
    for name, s in seqs.items():
        gb, tb = s["gt_box"], s["tr_box"]
        if similarity is Similarity.EUCLIDEAN:
            gb, tb = (gb[:, :2] + gb[:, 2:]) / 2, (tb[:, :2] + tb[:, 2:]) / 2
        built[name] = TrackingSequence.from_boxes(
            num_frames=s["num_frames"], gt_frame=s["gt_frame"], gt_id=s["gt_id"], gt_boxes=gb,
            tracker_frame=s["tr_frame"], tracker_id=s["tr_id"], tracker_boxes=tb, similarity=similarity,
        )
    return built


def assert_equal_to_trackeval(ours: dict, trackeval_results: dict) -> int:
    """Asserts every field TrackEval reported equals ours to 1e-9; returns how many fields were compared."""
    compared = 0
    for seq_name, per_metric in trackeval_results.items():
        for metric, fields in per_metric.items():
            for field, ref in fields.items():
                got = np.asarray(ours[seq_name][TrackingMetric(metric)][field], dtype=float)
                np.testing.assert_allclose(got, np.asarray(ref, dtype=float), rtol=0, atol=1e-9,
                                           err_msg=f"{seq_name} {metric} {field}")
                compared += 1
    return compared
