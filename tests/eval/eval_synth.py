"""Randomised tracking sequences for the oracle tests and hand checks (fixed seeds)."""

from __future__ import annotations

import numpy as np


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
