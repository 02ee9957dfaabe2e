"""Optimal one-to-one assignments where they are unique, without the solver wherever possible.

The parts of :func:`avdata.eval.matching.max_weight_matching` that need no frame order:

* :func:`unique_optimum`: each frame's heaviest matching of positive pairs where it is unique, by dominant
  pairs (heavier than their row and column together), then certified rows' or columns' best pairs, then
  ``linear_sum_assignment`` on each frame's competing part, checked unique by solving once more;
* :func:`solve_dense`: one small dense part solved;
* :func:`renumber`: compact numbers for the rows or columns of the pairs;
* :func:`max_assignment_total`: the largest summed weight of a one-to-one matching of sparse cells.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = ["max_assignment_total", "renumber", "solve_dense", "unique_optimum"]


def renumber(index: np.ndarray, n: int) -> tuple[np.ndarray, int]:
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


def unique_optimum(
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


def solve_dense(r: np.ndarray, c: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(K,) bool, the cells (r, c) with positive weight w that ``linear_sum_assignment`` matches (others 0)."""
    dense = np.zeros((int(r.max()) + 1, int(c.max()) + 1))
    dense[r, c] = w
    rr, cc = linear_sum_assignment(dense, maximize=True)
    partner = np.full(dense.shape[0], -1)
    partner[rr] = cc
    matched: np.ndarray = (np.take(partner, r) == c) & (w > 0)
    return matched


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
    rows, n_r = renumber(rows, int(rows.max()) + 1)
    cols, _ = renumber(cols, int(cols.max()) + 1)
    cell, offsets, n_rows, n_cols, row_base, col_base = _part_layout(frame, rows, cols)
    # Every frame's dense matrix lives in one buffer, filled at once; the loop only solves.
    buffer = np.zeros(int(offsets[-1]))
    buffer[cell] = w
    o_list, nr_list, nc_list = offsets.tolist(), n_rows.tolist(), n_cols.tolist()
    solved_r: list[np.ndarray] = []
    solved_c: list[np.ndarray] = []
    for k in range(len(nr_list)):
        rr, cc = linear_sum_assignment(buffer[o_list[k]:o_list[k + 1]].reshape(nr_list[k], nc_list[k]), maximize=True)
        solved_r.append(rr)
        solved_c.append(cc)
    # A cell the solver had to assign but that is not heavier than "unmatched" is no match.
    return _assigned(rows, cols, n_r, solved_r, solved_c, n_rows, n_cols, row_base, col_base) & (w > 0)


def _assigned(
    rows: np.ndarray, cols: np.ndarray, n_r: int, solved_r: list[np.ndarray], solved_c: list[np.ndarray], n_rows: np.ndarray,
    n_cols: np.ndarray, row_base: np.ndarray, col_base: np.ndarray,
) -> np.ndarray:
    """(K,) bool, the pairs whose (row, column) the parts' local solutions assign."""
    n_solved = np.minimum(n_rows, n_cols)
    solved_rows = np.concatenate(solved_r) + np.repeat(row_base, n_solved)
    solved_cols = np.concatenate(solved_c) + np.repeat(col_base, n_solved)
    partner = np.full(n_r, -1)
    partner[solved_rows] = solved_cols
    assigned: np.ndarray = np.take(partner, rows) == cols
    return assigned


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
