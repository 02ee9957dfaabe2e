"""``max_weight_matching`` equals ``linear_sum_assignment(-W)`` on each frame's full matrix, ties included.

Weights drawn from a few small integers make most frames tied (several optimal matchings), so the result
depends on the solver's tie-breaking on the full matrix; every path of the matching (isolated pairs,
certified components, enumerated components, larger components, continuation) meets such frames.
"""

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from avdata.eval.matching import Continuation, max_weight_matching


def _random_frames(rng: np.random.Generator, n_frames: int, max_dets: int, density: float, levels: int):
    """Pairs (frame, g, d, weight) of random frames, weights in {1 .. levels} / levels (0: no pair)."""
    g_counts = rng.integers(0, max_dets + 1, n_frames)
    d_counts = rng.integers(0, max_dets + 1, n_frames)
    gt_offsets = np.r_[0, np.cumsum(g_counts)]
    tracker_offsets = np.r_[0, np.cumsum(d_counts)]
    frame, g, d, w = [], [], [], []
    for t in range(n_frames):
        rr, cc = np.nonzero(rng.random((g_counts[t], d_counts[t])) < density)
        frame.append(np.full(len(rr), t))
        g.append(gt_offsets[t] + rr)
        d.append(tracker_offsets[t] + cc)
        w.append(rng.integers(1, levels + 1, len(rr)) / levels)
    return (*(np.concatenate(x) for x in (frame, g, d)), np.concatenate(w).astype(float), gt_offsets,
            tracker_offsets)


def _reference(frame, g, d, w, gt_offsets, tracker_offsets, continuation=None):
    """TrackEval's loop: each frame's full matrix, the continuation bonus from the previous frame's matches."""
    matched = np.zeros(len(frame), dtype=bool)
    last_frame, last_keys = -1, set()
    for t in range(len(gt_offsets) - 1):
        sel = np.flatnonzero(frame == t)
        if len(sel) == 0:
            continue
        dense = np.zeros((gt_offsets[t + 1] - gt_offsets[t], tracker_offsets[t + 1] - tracker_offsets[t]))
        weight = w[sel].copy()
        if continuation is not None and continuation.previous_frame[t] == last_frame:
            weight[(weight > 0) & np.isin(continuation.pair_key[sel], list(last_keys))] += continuation.bonus
        dense[g[sel] - gt_offsets[t], d[sel] - tracker_offsets[t]] = weight
        rr, cc = linear_sum_assignment(-dense)
        chosen = {(r, c) for r, c in zip(rr.tolist(), cc.tolist(), strict=True) if dense[r, c] > 0}
        matched[sel] = [(a - gt_offsets[t], b - tracker_offsets[t]) in chosen for a, b in zip(g[sel], d[sel], strict=True)]
        if continuation is not None:
            last_frame, last_keys = t, set(continuation.pair_key[sel][matched[sel]].tolist())
    return matched


@pytest.mark.parametrize(("max_dets", "density", "levels"), [(4, 0.5, 2), (8, 0.4, 3), (14, 0.3, 4), (14, 0.15, 50)])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_equals_full_frame_solver_with_ties(seed, max_dets, density, levels):
    rng = np.random.default_rng(seed)
    frame, g, d, w, gt_offsets, tracker_offsets = _random_frames(rng, 150, max_dets, density, levels)
    got = max_weight_matching(frame, g, d, w, gt_offsets, tracker_offsets)
    want = _reference(frame, g, d, w, gt_offsets, tracker_offsets)
    assert want.sum() > 100  # plenty of matches, many of them among tied alternatives
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize(("max_dets", "density", "levels"), [(4, 0.5, 2), (8, 0.4, 3), (14, 0.2, 4)])
@pytest.mark.parametrize("seed", [0, 1])
def test_equals_full_frame_solver_with_ties_and_continuation(seed, max_dets, density, levels):
    rng = np.random.default_rng(seed + 10)
    frame, g, d, w, gt_offsets, tracker_offsets = _random_frames(rng, 150, max_dets, density, levels)
    # Ids from small pools, so pairs continue earlier matches often; frames lacking either side are skipped.
    g_id = rng.integers(0, 6, gt_offsets[-1])
    d_id = rng.integers(0, 6, tracker_offsets[-1])
    active = np.flatnonzero((np.diff(gt_offsets) > 0) & (np.diff(tracker_offsets) > 0))
    previous = np.full(len(gt_offsets) - 1, -1)
    previous[active[1:]] = active[:-1]
    continuation = Continuation(previous_frame=previous, pair_key=g_id[g] * 6 + d_id[d], bonus=1000.0)
    got = max_weight_matching(frame, g, d, w, gt_offsets, tracker_offsets, continuation=continuation)
    want = _reference(frame, g, d, w, gt_offsets, tracker_offsets, continuation)
    assert want.sum() > 100
    np.testing.assert_array_equal(got, want)


def test_distinct_weights_need_no_full_frame_solve(monkeypatch):
    # Without ties (continuous weights) the answer is the same, and no frame reaches the full-matrix solve.
    import avdata.eval.matching as matching

    calls = []
    monkeypatch.setattr(matching, "_solve_full_frame", lambda *a: calls.append(a) or None)
    rng = np.random.default_rng(5)
    frame, g, d, _, gt_offsets, tracker_offsets = _random_frames(rng, 150, 14, 0.3, 1)
    w = rng.uniform(0.1, 1.0, len(frame))
    got = max_weight_matching(frame, g, d, w, gt_offsets, tracker_offsets)
    assert calls == []
    monkeypatch.undo()
    np.testing.assert_array_equal(got, _reference(frame, g, d, w, gt_offsets, tracker_offsets))


def test_distinct_weights_with_continuation_stay_on_the_fast_path(monkeypatch):
    # Continuous weights: the frame-by-frame fast solve is verified unique everywhere, so the sequence is never
    # re-solved on full matrices, and it equals the reference loop.
    import avdata.eval.matching as matching

    calls = []
    monkeypatch.setattr(matching, "_continue_full_frames", lambda *a: calls.append(a) or None)
    rng = np.random.default_rng(6)
    frame, g, d, _, gt_offsets, tracker_offsets = _random_frames(rng, 150, 10, 0.3, 1)
    w = rng.uniform(0.1, 1.0, len(frame))
    g_id = rng.integers(0, 6, gt_offsets[-1])
    d_id = rng.integers(0, 6, tracker_offsets[-1])
    active = np.flatnonzero((np.diff(gt_offsets) > 0) & (np.diff(tracker_offsets) > 0))
    previous = np.full(len(gt_offsets) - 1, -1)
    previous[active[1:]] = active[:-1]
    continuation = Continuation(previous_frame=previous, pair_key=g_id[g] * 6 + d_id[d], bonus=1000.0)
    got = max_weight_matching(frame, g, d, w, gt_offsets, tracker_offsets, continuation=continuation)
    assert calls == []
    want = _reference(frame, g, d, w, gt_offsets, tracker_offsets, continuation)
    assert want.sum() > 100
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_equals_full_frame_solver_where_a_pair_only_just_dominates(seed):
    # Each frame: a heavy pair whose row partner and column partner weigh as much together (a tie: both of them
    # match instead as heavily), or a quarter less (the heavy pair wins by a margin), placed at random in a
    # 3 x 3 frame with a light pair elsewhere. Matching a pair because it outweighs its row's and column's
    # other pairs must demand more than equality, else tied frames miss the full-matrix solve's tie-breaking.
    rng = np.random.default_rng(seed + 20)
    frame, g, d, w, tie = [], [], [], [], []
    for t in range(200):
        b, c = rng.integers(1, 5, 2) / 4
        heavy = b + c + (0.25 if t % 3 == 0 else 0.0)
        r, k = rng.permutation(3), rng.permutation(3)
        cells = [(r[0], k[0], heavy), (r[0], k[1], b), (r[1], k[0], c), (r[2], k[2], 0.25)]
        for i, (row, col, weight) in enumerate(cells):
            frame.append(t)
            g.append(3 * t + row)
            d.append(3 * t + col)
            w.append(weight)
            tie.append(i == 0 and t % 3 != 0)
    frame, g, d, w, tie = (np.array(x) for x in (frame, g, d, w, tie))
    order = np.lexsort((d, g))
    frame, g, d, w, tie = frame[order], g[order], d[order], w[order], tie[order]
    offsets = np.arange(0, 601, 3)
    got = max_weight_matching(frame, g, d, w, offsets, offsets)
    want = _reference(frame, g, d, w, offsets, offsets)
    assert 0 < (want & tie).sum() < tie.sum()  # the reference takes both answers of the tied frames
    np.testing.assert_array_equal(got, want)
