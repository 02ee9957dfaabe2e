"""Matching: candidate pairs by a sorted sweep, per-frame optimal assignment, greedy nearest-centre matching.

The public matching API every metric uses:

* :func:`overlapping_pairs`: same-frame candidate pairs whose axis-aligned bounds touch (no dense grid);
* :func:`max_weight_matching`: per-frame optimal assignment (Hungarian, as ``linear_sum_assignment`` per frame),
  split into independent parts so that only frames with competing pairs reach the solver;
* :func:`max_assignment_total`: the largest summed weight of a one-to-one matching of sparse cells;
* :func:`greedy_match`: detections in a given order take the nearest free ground truth of their frame
  (nuScenes' and the avdata protocol's matching), all frames advancing together.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import csr_array
from scipy.sparse.csgraph import connected_components

__all__ = ["Continuation", "greedy_match", "max_assignment_total", "max_weight_matching", "overlapping_pairs"]

def overlapping_pairs(
    g_frame: np.ndarray, g_box: np.ndarray, d_frame: np.ndarray, d_box: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate same-frame pairs by a sorted sweep (no dense grid).

    Every pair whose axis-aligned boxes touch or overlap, plus possibly pairs apart by less than 1e-6 of the x
    extent (callers drop pairs that do not overlap by their exact similarity).

    Args:
        g_frame: (Ng,) frame of each gt box, non-decreasing.
        g_box: (Ng, 4) ``(x0, y0, x1, y1)`` bounds of the gt boxes.
        d_frame: (Nd,) frame of each tracker box, non-decreasing.
        d_box: (Nd, 4) bounds of the tracker boxes.

    Returns:
        (K,) gt indices (non-decreasing) and (K,) tracker indices of the candidate pairs.
    """
    if len(g_frame) == 0 or len(d_frame) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    lo_x = min(g_box[:, 0].min(), d_box[:, 0].min())
    span = max(g_box[:, 2].max(), d_box[:, 2].max()) - lo_x + 1.0
    slack = 1e-6 * span
    n_frames = max(int(g_frame[-1]), int(d_frame[-1])) + 1
    # Tracker boxes sorted by (frame, x0) and counted into x buckets per frame (two buckets per tracker box of
    # an average frame); a gt box's partners have x0 in [gt x0 - widest tracker box of its frame, gt x1], so they lie in
    # the buckets from the one of that lower bound to the one of gt x1 (bucket numbers are monotone in x).
    # Bucket bounds replace a binary search per gt box; the exact interval tests below drop the surplus.
    d_order = np.argsort(d_frame * (4.0 * span) + (d_box[:, 0] - lo_x), kind="stable")
    d_sorted = np.take(d_box, d_order, axis=0)
    n_buckets = 2 * -(-len(d_frame) // n_frames)
    per_x = n_buckets / span

    def bucket(frame: np.ndarray, x: np.ndarray) -> np.ndarray:
        # fmin / fmax: a NaN coordinate lands in bucket 0 (its pairs then fail the exact tests).
        return frame * n_buckets + np.fmin(np.fmax(np.floor((x - lo_x) * per_x), 0), n_buckets - 1).astype(np.int64)

    start = np.zeros(n_frames * n_buckets + 1, dtype=np.int64)
    np.cumsum(np.bincount(bucket(np.take(d_frame, d_order), d_sorted[:, 0]), minlength=n_frames * n_buckets),
              out=start[1:])
    first = np.flatnonzero(np.r_[True, d_frame[1:] != d_frame[:-1]])
    widest = np.zeros(n_frames)
    widest[np.take(d_frame, first)] = np.maximum.reduceat(d_box[:, 2] - d_box[:, 0], first)
    lo = np.take(start, bucket(g_frame, g_box[:, 0] - np.take(widest, g_frame) - slack))
    hi = np.take(start, bucket(g_frame, g_box[:, 2] + slack) + 1)
    counts = np.maximum(hi - lo, 0)
    # Candidates gt by gt: pg the gt box, j the position among the sorted tracker boxes (np.take and
    # np.compress rather than np.repeat, fancy or boolean indexing: same values, several times faster here).
    pg = np.repeat(np.arange(len(g_frame)), counts)
    j = np.arange(len(pg)) + np.take(lo - (np.cumsum(counts) - counts), pg)
    keep = np.ones(len(j), dtype=bool)
    for g_col, d_col, below in ((0, 2, False), (2, 0, True), (3, 1, True), (1, 3, False)):
        g_values = np.take(g_box[:, g_col], pg)
        d_values = np.take(d_sorted[:, d_col], j)
        keep &= (d_values <= g_values) if below else (d_values >= g_values)
    return np.compress(keep, pg), np.take(d_order, np.compress(keep, j))


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
    lookup = np.cumsum(present)
    return np.take(lookup, index) - 1, int(lookup[-1])


def _first_best(rows: np.ndarray, order: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """The first heaviest pair of each row.

    Args:
        rows: (K,) row of each pair.
        order: (K,) the pairs stably sorted by row.
        weight: (K,) weight of each pair.

    Returns:
        (R,) pair index of each present row's first heaviest pair.
    """
    r_sorted = np.take(rows, order)
    w_sorted = np.take(weight, order)
    starts = np.r_[0, np.flatnonzero(r_sorted[1:] != r_sorted[:-1]) + 1]
    row_max = np.maximum.reduceat(w_sorted, starts)
    at_max = np.flatnonzero(w_sorted == np.repeat(row_max, np.diff(np.r_[starts, len(order)])))
    max_rows = r_sorted[at_max]
    return order[at_max[np.r_[True, max_rows[1:] != max_rows[:-1]]]]


def _certified(rows: np.ndarray, cols: np.ndarray, n_r: int, n_c: int, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solves every connected component whose rows' best columns, or whose columns' best rows, are all different.

    Giving each row its heaviest pair reaches the upper bound sum(row maxima), so where that choice is
    one-to-one it is the optimal assignment of the component (unique unless weights tie); likewise by columns.
    Components never span frames, so this splits off the frames' independent parts without a solver.

    Args:
        rows: (K,) compact row of each pair, in [0, n_r).
        cols: (K,) compact column of each pair, in [0, n_c).
        n_r: number of rows.
        n_c: number of columns.
        weight: (K,) positive weights.

    Returns:
        (M,) indices of the pairs certified as matched, and (K,) bool, the pairs of the components left to solve.
    """
    by_row = np.argsort(rows, kind="stable")
    # Bipartite graph row -> n_r + column, given directly as CSR (pairs sorted by row).
    indptr = np.zeros(n_r + n_c + 1, dtype=np.int32)
    np.cumsum(np.bincount(rows, minlength=n_r), out=indptr[1 : n_r + 1])
    indptr[n_r + 1 :] = indptr[n_r]
    indices = (np.take(cols, by_row) + n_r).astype(np.int32)
    graph = csr_array((np.ones(len(rows)), indices, indptr), shape=(n_r + n_c, n_r + n_c))
    _, label = connected_components(graph, directed=False)
    pair_label = np.take(label, rows)
    # Rows' best columns first, then, in the components where two rows want one column, columns' best rows.
    row_best = _first_best(rows, by_row, weight)
    bad = np.zeros(label.max() + 1, dtype=bool)
    bad[label[n_r + np.flatnonzero(np.bincount(cols[row_best], minlength=n_c) > 1)]] = True
    chosen = row_best[~bad[pair_label[row_best]]]
    rest = np.flatnonzero(np.take(bad, pair_label))
    if len(rest) == 0:
        return chosen, np.zeros(len(rows), dtype=bool)
    rest_cols = np.take(cols, rest)
    col_best = np.take(rest, _first_best(rest_cols, np.argsort(rest_cols, kind="stable"), np.take(weight, rest)))
    still_bad = np.zeros_like(bad)
    still_bad[label[np.flatnonzero(np.bincount(rows[col_best], minlength=n_r) > 1)]] = True
    chosen = np.r_[chosen, col_best[~still_bad[pair_label[col_best]]]]
    return chosen, np.take(still_bad, pair_label)


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
    frame: np.ndarray, g: np.ndarray, d: np.ndarray, weight: np.ndarray, n_g: int, n_d: int,
    continuation: Continuation | None = None,
) -> np.ndarray:
    """Per-frame optimal assignment maximising the summed weight, as ``linear_sum_assignment(-W)`` per frame.

    Args:
        frame: (P,) frame of each pair, non-decreasing.
        g: (P,) global gt detection index (detections are frame-ordered, so frames never share one).
        d: (P,) global tracker detection index.
        weight: (P,) non-negative weights; only positive entries can be matched.
        n_g: number of gt detections.
        n_d: number of tracker detections.
        continuation: optional bonus for the competing pairs of a frame that repeat a match of its previous
            frame; frames are then solved in order, each with the final matches of the frames before it.

    Returns:
        (P,) bool, the pairs with positive weight that the assignment matches.
    """
    # np.take / np.compress rather than fancy / boolean indexing: same values, faster on these sizes.
    positive = weight > 0
    row_count = np.bincount(np.compress(positive, g), minlength=n_g)
    col_count = np.bincount(np.compress(positive, d), minlength=n_d)
    matched = positive & (np.take(row_count, g) == 1) & (np.take(col_count, d) == 1)
    competing = np.flatnonzero(positive & ~matched)
    if len(competing) == 0:
        return matched
    # Compact row / column numbers; detections are frame-ordered, so each frame's rows (columns) are a
    # contiguous run of them.
    rows, n_r = _renumber(np.take(g, competing), n_g)
    cols, n_c = _renumber(np.take(d, competing), n_d)
    if continuation is None:
        chosen, left = _certified(rows, cols, n_r, n_c, np.take(weight, competing))
        matched[np.take(competing, chosen)] = True
        if not left.any():
            return matched
        competing = np.compress(left, competing)
        rows, n_r = _renumber(np.compress(left, rows), n_r)
        cols, n_c = _renumber(np.compress(left, cols), n_c)
    bounds = np.r_[0, np.flatnonzero(np.diff(frame[competing])) + 1, len(competing)]
    starts = bounds[:-1]
    row_base = np.minimum.reduceat(rows, starts)
    col_base = np.minimum.reduceat(cols, starts)
    n_rows = np.maximum.reduceat(rows, starts) - row_base + 1
    n_cols = np.maximum.reduceat(cols, starts) - col_base + 1
    part_of = np.repeat(np.arange(len(starts)), np.diff(bounds))
    flat = (rows - row_base[part_of]) * n_cols[part_of] + (cols - col_base[part_of])
    # Every frame's dense matrix lives in one buffer, filled at once; the loop only solves.
    offsets = np.r_[0, np.cumsum(n_rows * n_cols)]
    cell = offsets[part_of] + flat
    buffer = np.zeros(int(offsets[-1]))
    buffer[cell] = weight[competing]
    # Plain Python scalars in the loop: it runs once per frame with competing pairs.
    o_list, nr_list, nc_list = offsets.tolist(), n_rows.tolist(), n_cols.tolist()
    solved_r, solved_c = [], []
    if continuation is None:
        for k in range(len(starts)):
            rr, cc = linear_sum_assignment(
                buffer[o_list[k]:o_list[k + 1]].reshape(nr_list[k], nc_list[k]), maximize=True
            )
            solved_r.append(rr)
            solved_c.append(cc)
    else:
        _continue_in_order(continuation, frame, competing, matched, cell, buffer, bounds, o_list, nr_list, nc_list,
                           solved_r, solved_c)
    # Local solutions back to compact rows / columns (each part's solution has min(rows, cols) entries).
    n_solved = np.minimum(n_rows, n_cols)
    solved_rows = np.concatenate(solved_r) + np.repeat(row_base, n_solved)
    solved_cols = np.concatenate(solved_c) + np.repeat(col_base, n_solved)
    # An assigned (row, column) is a match only where a competing pair (positive weight) exists.
    partner = np.full(n_r, -1)
    partner[solved_rows] = solved_cols
    matched[competing] = partner[rows] == cols
    return matched


def _continue_in_order(
    continuation: Continuation, frame: np.ndarray, competing: np.ndarray, matched: np.ndarray, cell: np.ndarray,
    buffer: np.ndarray, bounds: np.ndarray, o_list: list, nr_list: list, nc_list: list, solved_r: list,
    solved_c: list,
) -> None:
    """Solves the frames' parts in frame order, adding the continuation bonus to ``buffer`` first.

    A competing pair continues either a pair matched before any solving (its previous frame had no competition
    for it: known now, added to every part at once) or a pair the solver matched in the previous frame, which
    is then the part solved just before (its previous frame holds both kinds of detections, so it is active).
    """
    key = continuation.pair_key.astype(np.int64)
    n_keys = int(key.max()) + 1 if len(key) else 1
    prev = continuation.previous_frame[frame[competing]]
    # Bonus from the matches known before solving: (frame, key) of the already matched pairs of the frames
    # that some competing pair continues.
    continued = np.zeros(len(continuation.previous_frame), dtype=bool)
    continued[prev[prev >= 0]] = True
    source = np.flatnonzero(matched & np.take(continued, frame))
    known = np.sort(np.take(frame, source) * n_keys + np.take(key, source))
    want = prev * n_keys + key[competing]
    pos = np.clip(np.searchsorted(known, want), 0, max(len(known) - 1, 0))
    hit = (prev >= 0) & (known[pos] == want) if len(known) else np.zeros(len(want), dtype=bool)
    buffer[cell[hit]] += continuation.bonus
    # The solver's own matches of the previous part: keys of its matched cells, from a dense key buffer.
    key_buffer = np.full(len(buffer), -1, dtype=np.int64)
    key_buffer[cell] = key[competing]
    cell_key = key_buffer.tolist()
    part_frame = frame[competing[bounds[:-1]]].tolist()
    prev_of_part = continuation.previous_frame[frame[competing[bounds[:-1]]]].tolist()
    part_keys = key[competing].tolist()
    part_cells = cell.tolist()
    b_list = bounds.tolist()
    last_frame, last_keys = -1, set[int]()
    for k in range(len(b_list) - 1):
        o0, o1 = o_list[k], o_list[k + 1]
        if prev_of_part[k] == last_frame and last_keys:
            for i in range(b_list[k], b_list[k + 1]):
                if part_keys[i] in last_keys:
                    buffer[part_cells[i]] += continuation.bonus
        n_c = nc_list[k]
        rr, cc = linear_sum_assignment(buffer[o0:o1].reshape(nr_list[k], n_c), maximize=True)
        solved_r.append(rr)
        solved_c.append(cc)
        chosen = {cell_key[o0 + r * n_c + c] for r, c in zip(rr.tolist(), cc.tolist(), strict=True)}
        chosen.discard(-1)
        last_frame, last_keys = part_frame[k], chosen


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
