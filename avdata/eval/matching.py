"""Matching: candidate pairs by a sorted sweep, per-frame optimal assignment, greedy nearest-centre matching.

The public matching API every metric uses (this module, and the modules its parts live in: candidate pairs in
:mod:`avdata.eval.candidate_pairs`, the frame-order-free search for unique optima in :mod:`avdata.eval.assignment`,
greedy matching in :mod:`avdata.eval.greedy`):

* :func:`overlapping_pairs`: same-frame candidate pairs whose axis-aligned bounds touch (no dense grid);
* :func:`max_weight_matching`: per-frame optimal assignment (Hungarian, as ``linear_sum_assignment`` per frame),
  split into independent parts so that only frames with competing pairs reach the solver, and only frames with
  tied optima its full per-frame matrix (where its tie-breaking decides, as for the reference);
* :func:`max_assignment_total`: the largest summed weight of a one-to-one matching of sparse cells;
* :func:`greedy_match`: detections in a given order take the nearest free ground truth of their frame
  (nuScenes' and the avdata protocol's matching), all frames advancing together.
"""

from __future__ import annotations

import heapq
import itertools
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from avdata.eval.assignment import max_assignment_total, renumber, solve_dense, unique_optimum
from avdata.eval.candidate_pairs import overlapping_pairs, stable_int_order
from avdata.eval.greedy import greedy_match

__all__ = [
    "Continuation",
    "greedy_match",
    "max_assignment_total",
    "max_weight_matching",
    "overlapping_pairs",
    "stable_int_order",
]

# Two matchings of a frame whose summed weights differ by at most this fraction of the largest weight count as
# tied (float rounding of the weights and in the solver is far below it): the frame is then solved on its full
# matrix, where the solver breaks the tie as it does for the reference.
_TIE_RTOL = 1e-9


@dataclass(frozen=True, slots=True, kw_only=True)
class Continuation:
    """Extra weight for pairs that repeat a match of an earlier frame (CLEAR's identity continuation).

    Attributes:
        previous_frame: (T,) the frame whose matches frame t continues (-1: none).
        pair_key: (P,) identity of each pair across frames (e.g. gt id * number of tracker ids + tracker id).
        bonus: weight added to a pair whose key was matched in ``previous_frame`` of its frame.
    """

    previous_frame: np.ndarray
    pair_key: np.ndarray
    bonus: float


def max_weight_matching(
    frame: np.ndarray, g: np.ndarray, d: np.ndarray, weight: np.ndarray, gt_offsets: np.ndarray,
    tracker_offsets: np.ndarray, continuation: Continuation | None = None,
) -> np.ndarray:
    """Per-frame optimal assignment maximising the summed weight, as ``linear_sum_assignment(-W)`` per frame.

    ``W`` is a frame's full (gt detections x tracker detections) matrix, zero outside the pairs. Where a frame's
    heaviest matching is unique (every other one lighter by more than 1e-9 of the largest weight), it is found
    without the solver or on the frame's competing part only; where two are tied or about to, the frame is solved
    on its full matrix, so that the solver's tie-breaking picks what it picks for the reference.

    Args:
        frame: (P,) frame of each pair, non-decreasing.
        g: (P,) global gt detection index (detections are frame-ordered, so frames never share one).
        d: (P,) global tracker detection index.
        weight: (P,) non-negative weights; only positive entries can be matched.
        gt_offsets: (T + 1,) first gt detection of each frame, then the number of gt detections.
        tracker_offsets: (T + 1,) the same for the tracker detections.
        continuation: optional bonus for the pairs of a frame that repeat a match of its previous frame; frames
            are then solved in order, each with the final matches of the frames before it.

    Returns:
        (P,) bool, the pairs with positive weight that the assignment matches.
    """
    n_g, n_d = int(gt_offsets[-1]), int(tracker_offsets[-1])
    # np.take / np.compress rather than fancy / boolean indexing: the same values without the general indexing
    # machinery's per-call set-up, which is most of the cost on arrays of a frame's size.
    positive = weight > 0
    if continuation is None:
        # Every positive pair straight to the search for the unique optimum: its dominance pass matches the
        # isolated pairs too, on the detections' own numbers (no renumbering of the many pairs it settles).
        if not positive.any():
            return positive
        tol = _TIE_RTOL * float(weight.max())
        if positive.all():  # HOTA's weights: no copies
            frame_p, g_p, d_p, w_p = frame, g, d, weight
        else:
            frame_p, g_p, d_p, w_p = (np.compress(positive, x) for x in (frame, g, d, weight))
        best, tied = unique_optimum(frame_p, g_p, d_p, w_p, tol)
        matched: np.ndarray = np.zeros(len(frame), dtype=bool)
        matched[positive] = best
        if tied.any():
            _solve_full_frames(np.unique(np.compress(tied, frame_p)), frame, g, d, weight, gt_offsets,
                               tracker_offsets, matched)
        return matched
    # With the bonus a pair's weight depends on the previous frame's answer, so only isolated pairs are settled
    # up front; the others are solved without the bonus first and checked against it (_continue_from_unique).
    row_count = np.bincount(np.compress(positive, g), minlength=n_g)
    col_count = np.bincount(np.compress(positive, d), minlength=n_d)
    matched = positive & (np.take(row_count, g) == 1) & (np.take(col_count, d) == 1)
    competing = np.flatnonzero(positive & ~matched)
    if len(competing) == 0:
        return matched
    tol = _TIE_RTOL * (float(weight.max()) + continuation.bonus)
    # Compact row / column numbers; detections are frame-ordered, so each frame's rows (columns) are a
    # contiguous run of them.
    rows, _ = renumber(np.take(g, competing), n_g)
    cols, _ = renumber(np.take(d, competing), n_d)
    continued = _continue_from_unique(continuation, frame, competing, rows, cols, weight, matched, tol)
    if continued is not None:
        return continued
    return _continue_full_frames(continuation, frame, g, d, weight, gt_offsets, tracker_offsets, positive)


def _continue_from_unique(
    continuation: Continuation, frame: np.ndarray, competing: np.ndarray, rows: np.ndarray, cols: np.ndarray,
    weight: np.ndarray, matched: np.ndarray, tol: float,
) -> np.ndarray | None:
    """The continued assignment from each frame's unique heaviest matching without the bonus, or None on ties.

    Where a frame's heaviest matching without the bonus is unique and holds every pair that continues its
    previous frame's matches, it is also the unique heaviest with the bonus (no matching gains more bonus, and
    every other one is lighter without it). Only the other frames, and the frames after one whose answer
    changed, are solved again with their bonus, in frame order, and kept where verified unique.

    Args:
        continuation: the bonus.
        frame: (P,) frame of each pair, non-decreasing.
        competing: (K,) the pairs with positive weight that share a row or column with another such pair.
        rows: (K,) compact row of each competing pair.
        cols: (K,) compact column of each competing pair.
        weight: (P,) the weights.
        matched: (P,) bool, the isolated matches.
        tol: margin below which two matchings count as tied.

    Returns:
        (P,) bool, the matched pairs; None where some frame's optimal assignment is not unique.
    """
    frame_c = np.take(frame, competing)
    w = np.take(weight, competing)
    best, tied = unique_optimum(frame_c, rows, cols, w, tol)
    result: np.ndarray = matched.copy()
    result[competing] = best
    key = np.asarray(continuation.pair_key, dtype=np.int64)
    n_keys = int(key.max()) + 1
    prev = np.take(continuation.previous_frame, frame_c)
    # (frame, key) of every match of the bonus-free answers; a competing pair continues if its previous frame
    # has its key among them. They come frame-ordered, so a stable sort (timsort: merges the frames' short runs)
    # costs a fraction of the default one here.
    known = np.sort(np.compress(result, frame) * n_keys + np.compress(result, key), kind="stable")
    want = prev * n_keys + np.take(key, competing)
    pos = np.minimum(np.searchsorted(known, want), max(len(known) - 1, 0))
    continues = (prev >= 0) & (np.take(known, pos) == want) if len(known) else np.zeros(len(want), dtype=bool)
    dirty = np.unique(np.compress(tied | (continues & ~best), frame_c)).tolist()
    if not dirty:
        return result
    # Frames solved again with their bonus, in frame order; a changed answer makes its successor dirty.
    starts = np.searchsorted(frame_c, np.arange(len(continuation.previous_frame) + 1))
    next_frame = np.full(len(continuation.previous_frame), -1)
    has_prev = np.flatnonzero(continuation.previous_frame >= 0)
    next_frame[continuation.previous_frame[has_prev]] = has_prev
    pair_starts = np.searchsorted(frame, np.arange(len(continuation.previous_frame) + 1))
    heapq.heapify(dirty)
    done = -1
    while dirty:
        t = heapq.heappop(dirty)
        if t == done:
            continue
        done = t
        a, b = int(starts[t]), int(starts[t + 1])
        p = int(continuation.previous_frame[t])
        prev_keys = key[pair_starts[p]:pair_starts[p + 1]][result[pair_starts[p]:pair_starts[p + 1]]] if p >= 0 else key[:0]
        sel = competing[a:b]
        # Broadcast comparison: both key sets are a few entries (np.isin costs more here).
        w_t = w[a:b] + continuation.bonus * (key[sel][:, None] == prev_keys[None, :]).any(axis=1)
        # A frame's compact rows (columns) are a contiguous run.
        r_t, c_t = rows[a:b] - rows[a], cols[a:b] - cols[a:b].min()
        solved = solve_dense(r_t, c_t, w_t)
        # Unique by more than tol: the check of avdata.eval.assignment's _unique_solution.
        if not np.array_equal(solve_dense(r_t, c_t, w_t - tol * solved), solved):
            return None
        if not np.array_equal(solved, result[sel]):
            result[sel] = solved
            u = int(next_frame[t])
            if u >= 0 and starts[u + 1] > starts[u]:
                heapq.heappush(dirty, u)
    return result


def _solve_full_frames(
    frames: np.ndarray, frame: np.ndarray, g: np.ndarray, d: np.ndarray, weight: np.ndarray,
    gt_offsets: np.ndarray, tracker_offsets: np.ndarray, matched: np.ndarray,
) -> None:
    """Solves the given frames on their full matrices, ``linear_sum_assignment(-W)``, updating ``matched``.

    Args:
        frames: (F,) frames to solve.
        frame: (P,) frame of each pair, non-decreasing.
        g: (P,) global gt detection index.
        d: (P,) global tracker detection index.
        weight: (P,) the weights of the pairs (the frame's other cells are 0).
        gt_offsets: (T + 1,) first gt detection of each frame.
        tracker_offsets: (T + 1,) first tracker detection of each frame.
        matched: (P,) bool, updated in the frames' pairs.
    """
    pair_start = np.searchsorted(frame, frames, side="left").tolist()
    pair_stop = np.searchsorted(frame, frames, side="right").tolist()
    for f, a, b in zip(frames.tolist(), pair_start, pair_stop, strict=True):
        matched[a:b] = _solve_full_frame(g[a:b] - gt_offsets[f], d[a:b] - tracker_offsets[f], weight[a:b],
                                         int(gt_offsets[f + 1] - gt_offsets[f]),
                                         int(tracker_offsets[f + 1] - tracker_offsets[f]))


def _solve_full_frame(r: np.ndarray, c: np.ndarray, w: np.ndarray, n_rows: int, n_cols: int) -> np.ndarray:
    """(K,) bool, the positive cells (r, c, w) that ``linear_sum_assignment(-W)`` of the n_rows x n_cols W matches."""
    dense = np.zeros((n_rows, n_cols))
    positive = w > 0
    dense[r[positive], c[positive]] = w[positive]
    rr, cc = linear_sum_assignment(-dense)
    partner = np.full(n_rows, -1)
    partner[rr] = cc
    matched: np.ndarray = positive & (partner[r] == c)
    return matched


def _continue_full_frames(
    continuation: Continuation, frame: np.ndarray, g: np.ndarray, d: np.ndarray, weight: np.ndarray,
    gt_offsets: np.ndarray, tracker_offsets: np.ndarray, positive: np.ndarray,
) -> np.ndarray:
    """Solves every frame with pairs in order on its full matrix, with the continuation bonus (the reference's way).

    Args:
        continuation: the bonus.
        frame: (P,) frame of each pair, non-decreasing.
        g: (P,) global gt detection index.
        d: (P,) global tracker detection index.
        weight: (P,) the weights of the pairs.
        gt_offsets: (T + 1,) first gt detection of each frame.
        tracker_offsets: (T + 1,) first tracker detection of each frame.
        positive: (P,) bool, weight > 0.

    Returns:
        (P,) bool, the matched pairs.
    """
    matched = np.zeros(len(frame), dtype=bool)
    key = continuation.pair_key
    bounds = np.concatenate(([0], np.flatnonzero(np.diff(frame)) + 1, [len(frame)])).tolist()
    last_frame, last_keys = -1, np.zeros(0, dtype=key.dtype)
    for a, b in itertools.pairwise(bounds):
        f = int(frame[a])
        w = weight[a:b].copy()
        if continuation.previous_frame[f] == last_frame and len(last_keys):
            w[positive[a:b] & np.isin(key[a:b], last_keys)] += continuation.bonus
        matched[a:b] = _solve_full_frame(g[a:b] - gt_offsets[f], d[a:b] - tracker_offsets[f], w,
                                         int(gt_offsets[f + 1] - gt_offsets[f]),
                                         int(tracker_offsets[f + 1] - tracker_offsets[f]))
        last_frame, last_keys = f, key[a:b][matched[a:b]]
    return matched
