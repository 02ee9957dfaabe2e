"""Matching: candidate pairs by a sorted sweep, per-frame optimal assignment, greedy nearest-centre matching.

The public matching API every metric uses:

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

__all__ = ["Continuation", "greedy_match", "max_assignment_total", "max_weight_matching", "overlapping_pairs"]

# Two matchings of a frame whose summed weights differ by at most this fraction of the largest weight count as
# tied (float rounding of the weights and in the solver is far below it): the frame is then solved on its full
# matrix, where the solver breaks the tie as it does for the reference.
_TIE_RTOL = 1e-9


def overlapping_pairs(
    g_frame: np.ndarray, g_box: np.ndarray, d_frame: np.ndarray, d_box: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate same-frame pairs by a sorted sweep (no dense grid).

    Every pair whose axis-aligned boxes touch or overlap, plus possibly pairs apart by less than 1e-6 of the x
    extent (callers drop pairs that do not overlap by their exact similarity).

    Args:
        g_frame: (Ng,) frame of each gt box, non-decreasing.
        g_box: (Ng, 4) ``(x0, y0, x1, y1)`` finite bounds of the gt boxes.
        d_frame: (Nd,) frame of each tracker box, non-decreasing.
        d_box: (Nd, 4) finite bounds of the tracker boxes.

    Returns:
        (K,) gt indices (non-decreasing) and (K,) tracker indices of the candidate pairs.
    """
    if len(g_frame) == 0 or len(d_frame) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    lo_x = min(g_box[:, 0].min(), d_box[:, 0].min())
    span = max(g_box[:, 2].max(), d_box[:, 2].max()) - lo_x + 1.0
    slack = 1e-6 * span
    n_frames = max(int(g_frame[-1]), int(d_frame[-1])) + 1
    # Tracker boxes grouped by x bucket within their frame (two buckets per tracker box of an average frame); a
    # gt box's partners have x0 in [gt x0 - widest tracker box of its frame, gt x1], so they lie in the buckets
    # from the one of that lower bound to the one of gt x1 (bucket numbers are monotone in x). Bucket bounds
    # replace a binary search per gt box; the exact interval tests below drop the surplus.
    n_buckets = 2 * -(-len(d_frame) // n_frames)
    per_x = n_buckets / span

    def local_bucket(x: np.ndarray) -> np.ndarray:
        # fmin / fmax: a NaN coordinate lands in bucket 0 (its pairs then fail the exact tests).
        return np.fmin(np.fmax(np.floor((x - lo_x) * per_x), 0), n_buckets - 1).astype(np.int64)

    d_local = local_bucket(d_box[:, 0])
    d_order = _order_by_frame_and_bucket(d_frame, d_local, n_frames, n_buckets)
    # Bounds column by column, each contiguous: np.take from a strided column view is several times slower.
    d_columns = np.take(np.ascontiguousarray(d_box.T), d_order, axis=1)
    g_columns = np.ascontiguousarray(g_box.T)
    start = np.zeros(n_frames * n_buckets + 1, dtype=np.int64)
    np.cumsum(np.bincount(np.take(d_frame * n_buckets + d_local, d_order), minlength=n_frames * n_buckets),
              out=start[1:])
    first = np.flatnonzero(np.concatenate(([True], d_frame[1:] != d_frame[:-1])))
    widest = np.zeros(n_frames)
    widest[np.take(d_frame, first)] = np.maximum.reduceat(d_box[:, 2] - d_box[:, 0], first)
    g_bucket_0 = g_frame * n_buckets
    lo = np.take(start, g_bucket_0 + local_bucket(g_box[:, 0] - np.take(widest, g_frame) - slack))
    hi = np.take(start, g_bucket_0 + local_bucket(g_box[:, 2] + slack) + 1)
    counts = np.maximum(hi - lo, 0)
    # Candidates gt by gt: pg the gt box, j the position among the sorted tracker boxes (np.take and
    # np.compress rather than np.repeat, fancy or boolean indexing: same values, several times faster here).
    # pg counts the gt boxes whose candidates end at or before each candidate (a cumulative sum over where
    # they end, in place: half the cost of np.repeat with varying counts).
    ends = np.cumsum(counts)
    n_candidates = int(ends[-1])
    pg = np.bincount(ends[:-1], minlength=n_candidates + 1)[:n_candidates]
    np.cumsum(pg, out=pg)
    j = np.arange(n_candidates) + np.take(lo - (ends - counts), pg)
    # The y tests first: the x range already bounds the candidates, so most of them fail in y; the x tests then
    # read only the survivors.
    for lower, upper in ((1, 3), (0, 2)):  # y, then x: tracker lower <= gt upper and tracker upper >= gt lower
        keep = np.less_equal(np.take(d_columns[lower], j), np.take(g_columns[upper], pg))
        keep &= np.greater_equal(np.take(d_columns[upper], j), np.take(g_columns[lower], pg))
        pg, j = np.compress(keep, pg), np.compress(keep, j)
    return pg, np.take(d_order, j)


def stable_int_order(keys: np.ndarray, bound: int) -> np.ndarray:
    """``np.argsort(keys, kind="stable")`` for integer keys in [0, bound).

    Keys that fit 16 bits are sorted as ``uint16``, which numpy radix-sorts: several times faster than its
    stable sort of wider integers (0.06 against 0.41 ms for 27k keys here).
    """
    if bound <= 1 << 16:
        return np.argsort(keys.astype(np.uint16), kind="stable")
    return np.argsort(keys, kind="stable")


def _order_by_frame_and_bucket(
    frame: np.ndarray, bucket: np.ndarray, n_frames: int, n_buckets: int
) -> np.ndarray:
    """The stable order of boxes by (frame, bucket): two 16-bit radix sorts when both fit, else one wide sort."""
    if n_frames <= 1 << 16 and n_buckets <= 1 << 16:
        by_bucket = stable_int_order(bucket, n_buckets)
        return np.take(by_bucket, stable_int_order(np.take(frame, by_bucket), n_frames))
    return np.argsort(frame * n_buckets + bucket, kind="stable")


def _renumber(index: np.ndarray, n: int) -> tuple[np.ndarray, int]:
    """Renumbers indices in [0, n) to 0..m-1 keeping their order (``np.unique``'s inverse, by a table).

    Args:
        index: (K,) non-empty, values in [0, n).
        n: bound of the values.

    Returns:
        (K,) the new numbers and m, the number of distinct values.
    """
    present = np.zeros(n, dtype=bool)
    present[index] = True
    cells = np.flatnonzero(present)
    # Each present value's rank, written where it is (cheaper than np.cumsum of the bool table, whose cast
    # runs through a slow buffered loop); only those entries are read.
    lookup = np.empty(n, dtype=np.int64)
    lookup[cells] = np.arange(len(cells))
    return np.take(lookup, index), len(cells)


def _unique_best(
    rows: np.ndarray, order: np.ndarray | None, weight: np.ndarray, tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """The heaviest pair of each row, and whether it beats every other choice of the row by more than ``tol``.

    Args:
        rows: (K,) row of each pair.
        order: (K,) the pairs stably sorted by row, or None when ``rows`` is non-decreasing.
        weight: (K,) positive weight of each pair.
        tol: margin below which two weights count as tied.

    Returns:
        (R,) pair index of each present row's heaviest pair where unique (else of one of its near-heaviest),
        and (R,) bool: that pair's weight exceeds the row's other weights and leaving the row unmatched
        (weight 0) by more than ``tol``.
    """
    r_sorted = rows if order is None else np.take(rows, order)
    w_sorted = weight if order is None else np.take(weight, order)
    starts = np.concatenate(([0], np.flatnonzero(r_sorted[1:] != r_sorted[:-1]) + 1))
    row_max = np.maximum.reduceat(w_sorted, starts)
    near = np.flatnonzero(w_sorted >= np.repeat(row_max - tol, np.diff(np.concatenate((starts, [len(r_sorted)])))))
    # Every row has a near-heaviest pair (its heaviest); it is unique where the next near pair is another row's.
    near_rows = np.take(r_sorted, near)
    lead = np.concatenate(([True], near_rows[1:] != near_rows[:-1]))
    unique = np.compress(lead, np.concatenate((lead[1:], [True])))
    best = np.compress(lead, near)
    return (best if order is None else np.take(order, best)), unique & (row_max > tol)


def _certified(
    rows: np.ndarray, cols: np.ndarray, label: np.ndarray, n_labels: int, weight: np.ndarray, tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """Solves every group whose rows' best columns, or whose columns' best rows, are unique and all different.

    Giving each row its heaviest pair reaches the upper bound sum(row maxima); where every row's maximum beats
    its alternatives by more than ``tol`` and the choice is one-to-one, every other matching of the group
    is lighter by more than ``tol``, so any solver picks this one, whatever its tie-breaking. Likewise by columns.
    A group is a union of connected components (e.g. a frame).

    Args:
        rows: (K,) row of each pair (e.g. its gt detection).
        cols: (K,) column of each pair (e.g. its tracker detection).
        label: (K,) group of each pair, in [0, n_labels).
        n_labels: number of groups.
        weight: (K,) positive weights.
        tol: margin below which two matchings' summed weights count as tied.

    Returns:
        (M,) indices of the pairs certified as matched, and (K,) bool, the pairs of the groups left.
    """
    # Rows' best columns first, then, in the groups where that fails, columns' best rows.
    by_row = None if bool(np.all(rows[1:] >= rows[:-1])) else np.argsort(rows, kind="stable")
    row_best, row_unique = _unique_best(rows, by_row, weight, tol)
    best_cols = np.take(cols, row_best)
    best_label = np.take(label, row_best)
    bad = np.zeros(n_labels, dtype=bool)
    bad[best_label[~row_unique | (np.take(np.bincount(best_cols), best_cols) > 1)]] = True
    chosen = row_best[~bad[best_label]]
    rest = np.flatnonzero(np.take(bad, label))
    if len(rest) == 0:
        return chosen, np.zeros(len(rows), dtype=bool)
    rest_cols = np.take(cols, rest)
    col_best, col_unique = _unique_best(rest_cols, np.argsort(rest_cols, kind="stable"), np.take(weight, rest), tol)
    col_best = np.take(rest, col_best)
    best_rows = np.take(rows, col_best)
    best_label = np.take(label, col_best)
    still_bad = np.zeros_like(bad)
    still_bad[best_label[~col_unique | (np.take(np.bincount(best_rows), best_rows) > 1)]] = True
    chosen = np.concatenate((chosen, col_best[~still_bad[best_label]]))
    return chosen, np.take(still_bad, label)


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
    # np.take / np.compress rather than fancy / boolean indexing: same values, faster on these sizes.
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
        best, tied = _unique_optimum(frame_p, g_p, d_p, w_p, tol)
        matched = np.zeros(len(frame), dtype=bool)
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
    rows, _ = _renumber(np.take(g, competing), n_g)
    cols, _ = _renumber(np.take(d, competing), n_d)
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
    best, tied = _unique_optimum(frame_c, rows, cols, w, tol)
    result = matched.copy()
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
        solved = _solve_dense(r_t, c_t, w_t)
        # Unique by more than tol: see _unique_solution.
        if not np.array_equal(_solve_dense(r_t, c_t, w_t - tol * solved), solved):
            return None
        if not np.array_equal(solved, result[sel]):
            result[sel] = solved
            u = int(next_frame[t])
            if u >= 0 and starts[u + 1] > starts[u]:
                heapq.heappush(dirty, u)
    return result


def _dominant(rows: np.ndarray, cols: np.ndarray, w: np.ndarray, tol: float) -> np.ndarray:
    """The pairs heavier by more than ``tol`` than all other pairs of their row and of their column together.

    Such a pair is in every matching within ``tol`` of the heaviest: a matching without it gains more than
    ``tol`` by swapping it in for its row's and its column's partners (each lighter than those sums). So it is
    matched whatever a solver's tie-breaking, and the other pairs of its row and column are not; two of them
    never share a row or a column. Sums (one ``bincount`` each) rather than each row's and column's runner-up:
    no sort, and in tracking frames they catch nearly every pair the runner-ups would.

    Args:
        rows: (K,) row of each pair (e.g. its gt detection).
        cols: (K,) column of each pair (e.g. its tracker detection).
        w: (K,) positive weights.
        tol: margin below which two matchings count as tied.

    Returns:
        (K,) bool, the dominant pairs.
    """
    row_sum = np.bincount(rows, weights=w)
    col_sum = np.bincount(cols, weights=w)
    return 3.0 * w - np.take(row_sum, rows) - np.take(col_sum, cols) > tol


def _unique_optimum(
    frame: np.ndarray, rows: np.ndarray, cols: np.ndarray, w: np.ndarray, tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """The heaviest matching of the pairs, frame by frame, where it is unique.

    Dominant pairs (see :func:`_dominant`) are matched first and their rows and columns leave; the frames of the
    pairs left (few, with few pairs each) are certified by their rows' or columns' best pairs, else solved on
    their part and kept where verified unique.

    Args:
        frame: (K,) frame of each pair, non-decreasing.
        rows: (K,) row of each pair (no two frames share one).
        cols: (K,) column of each pair (no two frames share one).
        w: (K,) positive weights.
        tol: margin below which two matchings count as tied.

    Returns:
        (K,) bool, the matched pairs; (K,) bool, the pairs of frames whose heaviest matching may not be unique
        (their entries in the first array are then one of the optimal matchings).
    """
    best = _dominant(rows, cols, w, tol)
    tied = np.zeros(len(rows), dtype=bool)
    row_free = np.bincount(np.compress(best, rows), minlength=int(rows.max()) + 1) == 0
    col_free = np.bincount(np.compress(best, cols), minlength=int(cols.max()) + 1) == 0
    rest = np.flatnonzero(np.take(row_free, rows) & np.take(col_free, cols))
    if len(rest) == 0:
        return best, tied
    r_frame, r_rows, r_cols, r_w = (np.take(x, rest) for x in (frame, rows, cols, w))
    # Frames as the groups to certify: after the dominance pass their pairs left mostly form one component,
    # which spares finding the components.
    frame_index = np.cumsum(r_frame[1:] != r_frame[:-1])
    label = np.concatenate((np.zeros(1, dtype=frame_index.dtype), frame_index))
    chosen, left = _certified(r_rows, r_cols, label, int(label[-1]) + 1, r_w, tol)
    best[np.take(rest, chosen)] = True
    if not left.any():
        return best, tied
    sub = np.compress(left, rest)
    s_frame, s_rows, s_cols, s_w = frame[sub], rows[sub], cols[sub], w[sub]
    solved = _solve_parts(s_frame, s_rows, s_cols, s_w)
    best[sub] = solved
    tied[sub] = ~_unique_solution(s_frame, s_rows, s_cols, s_w, solved, tol)
    return best, tied


def _solve_dense(r: np.ndarray, c: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(K,) bool, the cells (r, c) with positive weight w that ``linear_sum_assignment`` matches (others 0)."""
    dense = np.zeros((int(r.max()) + 1, int(c.max()) + 1))
    dense[r, c] = w
    rr, cc = linear_sum_assignment(dense, maximize=True)
    partner = np.full(dense.shape[0], -1)
    partner[rr] = cc
    return (np.take(partner, r) == c) & (w > 0)


def _part_layout(frame: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, ...]:
    """Each frame's part as a dense matrix in one flat buffer.

    Args:
        frame: (K,) frame of each pair, non-decreasing.
        rows: (K,) compact row of each pair (a contiguous run per frame).
        cols: (K,) compact column of each pair (a contiguous run per frame).

    Returns:
        cell (K,) of each pair in the buffer, offsets (F + 1,) of the parts in the buffer, n_rows (F,),
        n_cols (F,), row_base (F,), col_base (F,).
    """
    bounds = np.concatenate(([0], np.flatnonzero(np.diff(frame)) + 1, [len(frame)]))
    starts = bounds[:-1]
    row_base = np.minimum.reduceat(rows, starts)
    col_base = np.minimum.reduceat(cols, starts)
    n_rows = np.maximum.reduceat(rows, starts) - row_base + 1
    n_cols = np.maximum.reduceat(cols, starts) - col_base + 1
    part_of = np.repeat(np.arange(len(starts)), np.diff(bounds))
    flat = (rows - row_base[part_of]) * n_cols[part_of] + (cols - col_base[part_of])
    offsets = np.concatenate(([0], np.cumsum(n_rows * n_cols)))
    return offsets[part_of] + flat, offsets, n_rows, n_cols, row_base, col_base


def _solve_parts(frame: np.ndarray, rows: np.ndarray, cols: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Solves each frame's part (its pairs' rows x columns, zero elsewhere) with ``linear_sum_assignment``.

    Args:
        frame: (K,) frame of each pair, non-decreasing.
        rows: (K,) row of each pair (e.g. its gt detection).
        cols: (K,) column of each pair (e.g. its tracker detection).
        w: (K,) positive weights.

    Returns:
        (K,) bool, the matched pairs.
    """
    rows, n_r = _renumber(rows, int(rows.max()) + 1)
    cols, _ = _renumber(cols, int(cols.max()) + 1)
    cell, offsets, n_rows, n_cols, row_base, col_base = _part_layout(frame, rows, cols)
    # Every frame's dense matrix lives in one buffer, filled at once; the loop only solves.
    buffer = np.zeros(int(offsets[-1]))
    buffer[cell] = w
    o_list, nr_list, nc_list = offsets.tolist(), n_rows.tolist(), n_cols.tolist()
    solved_r, solved_c = [], []
    for k in range(len(nr_list)):
        rr, cc = linear_sum_assignment(buffer[o_list[k]:o_list[k + 1]].reshape(nr_list[k], nc_list[k]), maximize=True)
        solved_r.append(rr)
        solved_c.append(cc)
    # A cell the solver had to assign but that is not heavier than "unmatched" is no match.
    return _assigned(rows, cols, n_r, solved_r, solved_c, n_rows, n_cols, row_base, col_base) & (w > 0)


def _assigned(
    rows: np.ndarray, cols: np.ndarray, n_r: int, solved_r: list, solved_c: list, n_rows: np.ndarray,
    n_cols: np.ndarray, row_base: np.ndarray, col_base: np.ndarray,
) -> np.ndarray:
    """(K,) bool, the pairs whose (row, column) the parts' local solutions assign."""
    n_solved = np.minimum(n_rows, n_cols)
    solved_rows = np.concatenate(solved_r) + np.repeat(row_base, n_solved)
    solved_cols = np.concatenate(solved_c) + np.repeat(col_base, n_solved)
    partner = np.full(n_r, -1)
    partner[solved_rows] = solved_cols
    return np.take(partner, rows) == cols


def _unique_solution(
    frame: np.ndarray, rows: np.ndarray, cols: np.ndarray, w: np.ndarray, solution: np.ndarray, tol: float
) -> np.ndarray:
    """Whether each frame part's optimal ``solution`` beats every other matching of the part by more than ``tol``.

    Solving again with the solution's pairs ``tol`` lighter returns the same matching exactly then: another
    matching N must leave out a pair of the solution M (else it would be heavier), so it gains at most
    ``tol * |M & N|`` from the change while M loses ``tol * |M|``; if N still does not win, it was lighter by
    more than ``tol``; if it wins, the two were within ``tol * |M|`` (counted as tied).

    Args:
        frame: (K,) frame of each pair, non-decreasing.
        rows: (K,) row of each pair (e.g. its gt detection).
        cols: (K,) column of each pair (e.g. its tracker detection).
        w: (K,) positive weights.
        solution: (K,) bool, an optimal matching of each part.
        tol: margin below which two matchings count as tied.

    Returns:
        (K,) bool, per pair: its frame's part has the unique solution ``solution``.
    """
    again = _solve_parts(frame, rows, cols, w - tol * solution)
    bounds = np.concatenate(([0], np.flatnonzero(np.diff(frame)) + 1, [len(frame)]))
    same = np.minimum.reduceat((again == solution).astype(np.int64), bounds[:-1]).astype(bool)
    return np.repeat(same, np.diff(bounds))


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
    return positive & (partner[r] == c)


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


def max_assignment_total(rows: np.ndarray, cols: np.ndarray, values: np.ndarray) -> float:
    """Largest sum of ``values`` over a one-to-one matching of the given (row, col) cells (others are 0)."""
    if len(values) == 0:
        return 0.0
    u_r, r_idx = np.unique(rows, return_inverse=True)
    u_c, c_idx = np.unique(cols, return_inverse=True)
    dense = np.zeros((len(u_r), len(u_c)))
    dense[r_idx, c_idx] = values
    rr, cc = linear_sum_assignment(dense, maximize=True)
    return float(dense[rr, cc].sum())


def greedy_match(
    gt_key: np.ndarray,
    gt_xy: np.ndarray,
    det_key: np.ndarray,
    det_xy: np.ndarray,
    order: np.ndarray,
    max_distance_m: float,
    *,
    inclusive: bool,
) -> np.ndarray:
    """Greedy nearest-centre matching: detections in ``order`` take the nearest free ground truth of their frame.

    Matches in different frames never interact, so all frames advance together: round r handles the r-th
    detection (in ``order``) of every frame at once. Ties in distance go to the first ground truth in index
    order.

    Args:
        gt_key: (G,) frame key of each ground truth (any sortable values).
        gt_xy: (G, 2) ground-truth centres.
        det_key: (D,) frame key of each detection.
        det_xy: (D, 2) detection centres.
        order: (K,) detection indices in processing order (e.g. descending score); others never match.
        max_distance_m: match distance limit.
        inclusive: a match needs distance <= the limit (True) or < the limit (False, nuScenes).

    Returns:
        (D,) index of the matched ground truth, -1 for none.
    """
    match = np.full(len(det_xy), -1)
    if len(gt_xy) == 0 or len(det_xy) == 0:
        return match
    frames, g_f = np.unique(gt_key, return_inverse=True)
    d_f = np.searchsorted(frames, det_key)
    d_f = np.where((d_f < len(frames)) & (frames[np.minimum(d_f, len(frames) - 1)] == det_key), d_f, -1)
    # Padded per-frame ground truth, in index order.
    g_order = np.argsort(g_f, kind="stable")
    counts = np.bincount(g_f, minlength=len(frames))
    slot = np.arange(len(g_f)) - np.repeat(np.cumsum(counts) - counts, counts)
    pad_xy = np.full((len(frames), counts.max(), 2), np.nan)
    pad_xy[g_f[g_order], slot] = gt_xy[g_order]
    pad_index = np.full((len(frames), counts.max()), -1)
    pad_index[g_f[g_order], slot] = g_order
    free = pad_index >= 0
    # Rank of each detection within its frame, in processing order.
    ordered = order[d_f[order] >= 0]
    by_frame = ordered[np.argsort(d_f[ordered], kind="stable")]
    f_sorted = d_f[by_frame]
    rank = np.arange(len(by_frame)) - np.searchsorted(f_sorted, f_sorted, side="left")
    for r in range(int(rank.max()) + 1 if len(rank) else 0):
        p = by_frame[rank == r]
        f = d_f[p]
        dist = np.linalg.norm(pad_xy[f] - det_xy[p, None], axis=-1)
        dist = np.where(free[f], dist, np.inf)
        best = np.argmin(dist, axis=1)
        closest = dist[np.arange(len(p)), best]
        hit = closest <= max_distance_m if inclusive else closest < max_distance_m
        free[f[hit], best[hit]] = False
        match[p[hit]] = pad_index[f[hit], best[hit]]
    return match
