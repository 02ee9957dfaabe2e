"""HOTA, CLEAR and Identity equal TrackEval 1.3.0 field by field where matchings tie.

Identical duplicate boxes, equal IoUs and equal HOTA scores leave a frame with several optimal assignments;
TrackEval keeps the one ``linear_sum_assignment`` picks on the frame's full matrix, and so must avdata (which
solves such frames on the same matrix; the shortcuts only take frames whose best assignment is unique).
"""

import numpy as np
import pytest
from eval_oracle_env import run_oracle
from eval_synth import assert_equal_to_trackeval, save_npz, tracking_sequences

from avdata.eval.tracking import Similarity, TrackingMetric, evaluate_tracking

FAMILIES = [TrackingMetric.HOTA, TrackingMetric.CLEAR, TrackingMetric.IDENTITY]
# Few distinct boxes on an integer grid: many detections share a box, many IoUs are equal.
PALETTE = np.array([[0, 0, 4, 4], [0, 0, 4, 4], [2, 0, 6, 4], [1, 1, 5, 5], [0, 2, 4, 6], [8, 8, 12, 12],
                    [9, 8, 13, 12], [8, 9, 12, 13]], dtype=float)


def _palette_sequence(rng: np.random.Generator, num_frames: int) -> dict:
    """Random subsets of a few gt and tracker ids per frame, each on a box drawn from ``PALETTE``."""
    out: dict = {"num_frames": num_frames}
    for side, n_ids, first_id in (("gt", int(rng.integers(2, 8)), 0), ("tr", int(rng.integers(2, 8)), 100)):
        count = rng.integers(0, n_ids + 1, num_frames)
        ids = [np.sort(rng.choice(n_ids, k, replace=False)) + first_id for k in count]
        out[f"{side}_frame"] = np.repeat(np.arange(num_frames), count)
        out[f"{side}_id"] = np.concatenate(ids)
        out[f"{side}_box"] = PALETTE[rng.integers(0, len(PALETTE), int(count.sum()))]
    return out


def _twins_sequence(rng: np.random.Generator, num_frames: int) -> dict:
    """Gt ids 0 and 1 always share one box (equal HOTA scores); tracker ids from a pool of 4 sit on it, other
    objects add rows and columns around them, in shuffled order within each frame."""
    rows: dict = {"gt": ([], [], []), "tr": ([], [], [])}
    for f in range(num_frames):
        box = np.array([10.0 * f % 50, 0, 10.0 * f % 50 + 4, 4])
        gid = [0, 1, *rng.choice(np.arange(2, 8), rng.integers(0, 4), replace=False)]
        gbox = [box, box] + [np.array([20.0 + 6 * k, 20, 24.0 + 6 * k, 24]) for k in gid[2:]]
        tid = list(rng.choice(np.arange(100, 104), rng.integers(1, 3), replace=False))
        tbox = [box + rng.choice([0.0, 1.0]) * np.array([1, 0, 1, 0]) for _ in tid]
        extra = list(rng.choice(np.arange(200, 206), rng.integers(0, 4), replace=False))
        tid += extra
        tbox += [np.array([6.0 * k - 1168, 20, 6.0 * k - 1164, 24]) + rng.choice([0.0, 1.0]) for k in extra]
        for side, ids, boxes in (("gt", gid, gbox), ("tr", tid, tbox)):
            order = rng.permutation(len(ids))
            rows[side][0].append(np.full(len(ids), f))
            rows[side][1].append(np.array(ids)[order])
            rows[side][2].append(np.array(boxes)[order])
    out: dict = {"num_frames": num_frames}
    for side, (frame, ids, boxes) in rows.items():
        out[f"{side}_frame"], out[f"{side}_id"], out[f"{side}_box"] = (np.concatenate(x) for x in (frame, ids, boxes))
    return out


def _compare(tmp_path, seqs: dict) -> int:
    save_npz(tmp_path / "seqs.npz", seqs)
    oracle = run_oracle("trackeval", "eval_trackeval.py", str(tmp_path / "seqs.npz"), "iou", "--metrics", "HOTA",
                        "CLEAR", "Identity")
    return assert_equal_to_trackeval(evaluate_tracking(tracking_sequences(seqs, Similarity.IOU_2D), FAMILIES),
                                     oracle["results"])


@pytest.mark.oracle
@pytest.mark.parametrize("seed", [0, 1])
def test_palette_ties_equal_trackeval(tmp_path, seed):
    rng = np.random.default_rng(seed)
    assert _compare(tmp_path, {f"s{i}": _palette_sequence(rng, 30) for i in range(8)}) == 9 * 43


@pytest.mark.oracle
@pytest.mark.parametrize("seed", [0, 1])
def test_duplicate_gt_boxes_equal_trackeval(tmp_path, seed):
    rng = np.random.default_rng(seed)
    assert _compare(tmp_path, {f"s{i}": _twins_sequence(rng, 12) for i in range(8)}) == 9 * 43


@pytest.mark.oracle
def test_two_by_two_tie_equals_trackeval(tmp_path):
    # Frame 0: gt 0 and 1 share a box, trackers 100 and 101 share it too (four equal IoUs, two optimal
    # assignments); frame 1 separates them (0 with 100, 1 with 101). Which frame-0 assignment TrackEval keeps
    # decides IDSW (0 or 2) and the HOTA association. A far matched pair and a lone gt and tracker box add rows
    # and columns: on the 2 x 2 tied block alone the solver breaks the tie the other way.
    box, far, lone_g, lone_t = [0.0, 0, 4, 4], [50.0, 50, 54, 54], [90.0, 0, 94, 4], [0.0, 90, 4, 94]
    seq = {
        "num_frames": 2,
        "gt_frame": np.array([0, 0, 0, 0, 1, 1]), "gt_id": np.array([7, 9, 0, 1, 0, 1]),
        "gt_box": np.array([far, lone_g, box, box, box, [20.0, 0, 24, 4]]),
        "tr_frame": np.array([0, 0, 0, 0, 1, 1]), "tr_id": np.array([107, 100, 101, 109, 100, 101]),
        "tr_box": np.array([far, box, box, lone_t, box, [20.0, 0, 24, 4]]),
    }
    assert _compare(tmp_path, {"s": seq}) == 2 * 43
