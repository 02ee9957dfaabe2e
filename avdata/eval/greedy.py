"""Greedy nearest-centre matching (nuScenes' and the avdata protocol's detection matching)."""

from __future__ import annotations

import numpy as np

__all__ = ["greedy_match"]


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
