"""Multi-object tracking metrics: HOTA, CLEAR, Identity, VACE, IDEucl, track-level rates.

Every definition follows TrackEval 1.3.0 (``trackeval.metrics``) line for line in what it computes, but is
evaluated over all frames at once:

* the per-frame similarities of a sequence are one flat array of (frame, gt det, tracker det) pairs;
* the per-frame optimal assignments (Hungarian) are split into independent parts: a pair that is the only
  positive entry of both its row and its column is matched in every optimal assignment, so only frames with
  competing pairs reach ``scipy.optimize.linear_sum_assignment``, and only on the competing rows/columns;
* CLEAR's identity-continuation bonus (prefer the previous frame's partner) only matters in those
  competing parts, so they are solved in frame order while everything else is vectorised.

Frame bookkeeping mirrors TrackEval: "previous timestep" for CLEAR continuation and fragmentation is the
previous frame that held both ground truth and tracker detections.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_array
from scipy.sparse.csgraph import connected_components

from avdata.errors import InputError
from avdata.eval import geometry
from avdata.eval.names import Similarity, TrackingMetric

__all__ = [
    "HOTA_ALPHAS",
    "Similarity",
    "TrackingConfig",
    "TrackingMetric",
    "TrackingSequence",
    "MotmetricsAccumulator",
    "clear",
    "clear_motmetrics",
    "combine_sequences",
    "evaluate_tracking",
    "hota",
    "identity",
    "ideucl",
    "summary",
    "track_rates",
    "vace",
]

_EPS = np.finfo(np.float64).eps
HOTA_ALPHAS = np.arange(0.05, 0.99, 0.05)


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackingConfig:
    """Thresholds of the tracking metrics (TrackEval's defaults).

    Attributes:
        clear_threshold: similarity a CLEAR match needs.
        identity_threshold: similarity an IDTP needs.
        vace_threshold: similarity VACE's per-frame overlap criterion needs.
        ideucl_threshold: similarity an IDEucl match needs.
        euclidean_zero_distance_m: distance at which the Euclidean similarity ``max(0, 1 - d / z)`` is 0.
        track_rate_threshold: fraction of its frames a track must be matched (CLEAR matches) to count as
            tracked; tracks matched for a smaller fraction are false tracks (tracker) or missed tracks (gt).
    """

    clear_threshold: float = 0.5
    identity_threshold: float = 0.5
    vace_threshold: float = 0.5
    ideucl_threshold: float = 0.4
    euclidean_zero_distance_m: float = 2.0
    track_rate_threshold: float = 0.5


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackingSequence:
    """One sequence's detections and the similarity of every same-frame (gt, tracker) pair that overlaps.

    Ids are relabelled to 0..n-1 in the order of ``np.unique`` of the original ids. Detections are stored
    frame by frame. Only pairs with positive similarity are stored (every metric threshold is positive, so
    a zero-similarity pair never counts), sorted by frame.

    Attributes:
        num_frames: T.
        gt_offsets: (T + 1,) start of each frame's ground-truth detections.
        gt_ids: (Ng,) contiguous ground-truth track ids.
        tracker_offsets: (T + 1,) start of each frame's tracker detections.
        tracker_ids: (Nd,) contiguous tracker track ids.
        pair_frame: (P,) frame of each positive pair, non-decreasing.
        pair_gt: (P,) ground-truth detection index of each pair.
        pair_tracker: (P,) tracker detection index of each pair.
        pair_similarity: (P,) similarity in (0, 1].
        gt_centroids: (Ng, 2) centres of the ground-truth boxes, used by IDEucl (None if not given).
        num_gt_ids: number of distinct ground-truth ids.
        num_tracker_ids: number of distinct tracker ids.
    """

    num_frames: int
    gt_offsets: np.ndarray
    gt_ids: np.ndarray
    tracker_offsets: np.ndarray
    tracker_ids: np.ndarray
    pair_frame: np.ndarray
    pair_gt: np.ndarray
    pair_tracker: np.ndarray
    pair_similarity: np.ndarray
    gt_centroids: np.ndarray | None
    num_gt_ids: int
    num_tracker_ids: int

    @classmethod
    def from_frames(
        cls,
        *,
        gt_ids: Sequence[np.ndarray],
        tracker_ids: Sequence[np.ndarray],
        similarity: Sequence[np.ndarray],
        gt_centroids: Sequence[np.ndarray] | None = None,
    ) -> TrackingSequence:
        """Builds a sequence from per-frame arrays, as TrackEval's ``data`` dict holds them.

        Args:
            gt_ids: T arrays (G_t,) of ground-truth ids (any integers, unique within a frame).
            tracker_ids: T arrays (D_t,) of tracker ids.
            similarity: T arrays (G_t, D_t) of similarities in [0, 1].
            gt_centroids: T arrays (G_t, 2) of ground-truth centres (for IDEucl), or None.

        Returns:
            The sequence.
        """
        if not (len(gt_ids) == len(tracker_ids) == len(similarity)):
            raise InputError(
                f"tracking sequence: expected as many frames of gt ids, tracker ids and similarities, got "
                f"{len(gt_ids)}, {len(tracker_ids)}, {len(similarity)}"
            )
        g_counts = np.array([len(g) for g in gt_ids], dtype=np.int64)
        d_counts = np.array([len(d) for d in tracker_ids], dtype=np.int64)
        g_start = np.concatenate([[0], np.cumsum(g_counts)])
        d_start = np.concatenate([[0], np.cumsum(d_counts)])
        frames, rows, cols, values = [], [], [], []
        for t, sim in enumerate(similarity):
            sim = np.asarray(sim, dtype=np.float64)
            if sim.shape != (g_counts[t], d_counts[t]):
                raise InputError(
                    f"tracking similarity frame {t}: expected shape ({g_counts[t]}, {d_counts[t]}), "
                    f"got {sim.shape}"
                )
            r, c = np.nonzero(sim > 0)
            frames.append(np.full(len(r), t))
            rows.append(g_start[t] + r)
            cols.append(d_start[t] + c)
            values.append(sim[r, c])
        centroids = None if gt_centroids is None else _concat_rows(gt_centroids, 2)
        return cls._build(
            g_counts=g_counts,
            d_counts=d_counts,
            raw_gt_ids=_concat_ids(gt_ids),
            raw_tracker_ids=_concat_ids(tracker_ids),
            pairs=tuple(_concat_ids(x) for x in (frames, rows, cols)) + (_concat_floats(values),),
            gt_centroids=centroids,
        )

    @classmethod
    def from_boxes(
        cls,
        *,
        num_frames: int,
        gt_frame: np.ndarray,
        gt_id: np.ndarray,
        gt_boxes: np.ndarray,
        tracker_frame: np.ndarray,
        tracker_id: np.ndarray,
        tracker_boxes: np.ndarray,
        similarity: Similarity,
        euclidean_zero_distance_m: float = 2.0,
    ) -> TrackingSequence:
        """Builds a sequence from flat detection tables, computing all same-frame similarities at once.

        Candidate pairs come from a padded (T, G_max, D_max) overlap test (exact for 2D boxes and distances,
        a circumscribed-circle bound for rotated boxes); the exact similarity is computed on those only.

        Args:
            num_frames: T; frames are 0..T-1.
            gt_frame: (Ng,) frame index of each ground-truth detection.
            gt_id: (Ng,) track id of each ground-truth detection.
            gt_boxes: (Ng, K) boxes: K = 4 ``(x0, y0, x1, y1)`` for 2D IoU; K = 7 unified 3D boxes for BEV /
                3D IoU; K = 2 or 3 points for Euclidean.
            tracker_frame: (Nd,) frame index of each tracker detection.
            tracker_id: (Nd,) track id of each tracker detection.
            tracker_boxes: (Nd, K) boxes, same layout as ``gt_boxes``.
            similarity: how boxes are compared.
            euclidean_zero_distance_m: distance at which the Euclidean similarity ``max(0, 1 - d / z)`` is 0.

        Returns:
            The sequence; IDEucl centroids are the 2D box centres (2D IoU) or the x, y of the boxes.
        """
        gt_frame = np.asarray(gt_frame, dtype=np.int64)
        tracker_frame = np.asarray(tracker_frame, dtype=np.int64)
        width = {Similarity.IOU_2D: 4, Similarity.IOU_BEV: 7, Similarity.IOU_3D: 7}.get(similarity)
        gt_boxes = np.asarray(gt_boxes, dtype=np.float64)
        tracker_boxes = np.asarray(tracker_boxes, dtype=np.float64)
        for name, frames, boxes in (("gt", gt_frame, gt_boxes), ("tracker", tracker_frame, tracker_boxes)):
            if len(frames) and (frames.min() < 0 or frames.max() >= num_frames):
                raise InputError(
                    f"{name} frame: expected frame indices in [0, {num_frames}), got {frames.min()}..{frames.max()}"
                )
            ok_width = boxes.ndim == 2 and (boxes.shape[1] == width if width else boxes.shape[1] in (2, 3))
            if not ok_width or len(boxes) != len(frames):
                raise InputError(
                    f"{name} boxes: expected ({len(frames)}, {width or '2 or 3'}) for {similarity.value}, "
                    f"got {boxes.shape}"
                )
        g_order = np.argsort(gt_frame, kind="stable")
        d_order = np.argsort(tracker_frame, kind="stable")
        gt_boxes, tracker_boxes = gt_boxes[g_order], tracker_boxes[d_order]
        g_counts = np.bincount(gt_frame, minlength=num_frames)
        d_counts = np.bincount(tracker_frame, minlength=num_frames)
        if similarity is Similarity.IOU_2D:
            g_box, d_box = gt_boxes, tracker_boxes
            centroids = (gt_boxes[:, 0:2] + gt_boxes[:, 2:4]) / 2
        elif similarity is Similarity.EUCLIDEAN:
            z = euclidean_zero_distance_m
            g_box = np.c_[gt_boxes[:, 0:2] - z, gt_boxes[:, 0:2] + z]
            d_box = np.c_[tracker_boxes[:, 0:2], tracker_boxes[:, 0:2]]
            centroids = gt_boxes[:, 0:2]
        else:
            # Circumscribed circles in BEV: boxes whose circles are apart cannot overlap.
            g_r = np.hypot(gt_boxes[:, 3], gt_boxes[:, 4])[:, None] / 2
            d_r = np.hypot(tracker_boxes[:, 3], tracker_boxes[:, 4])[:, None] / 2
            g_box = np.c_[gt_boxes[:, 0:2] - g_r, gt_boxes[:, 0:2] + g_r]
            d_box = np.c_[tracker_boxes[:, 0:2] - d_r, tracker_boxes[:, 0:2] + d_r]
            centroids = gt_boxes[:, 0:2]
        t_sorted = np.sort(tracker_frame)
        pg, pd = _overlapping_pairs(gt_frame[g_order], g_box, t_sorted, d_box)
        ga, tb = gt_boxes[pg], tracker_boxes[pd]
        if similarity is Similarity.IOU_2D:
            sim = geometry.box2d_iou(ga, tb, paired=True)
        elif similarity is Similarity.IOU_BEV:
            sim = geometry.bev_iou(ga, tb, paired=True)
        elif similarity is Similarity.IOU_3D:
            sim = geometry.box3d_iou(ga, tb, paired=True)
        else:
            sim = np.maximum(0, 1 - geometry.centre_distance(ga, tb, paired=True) / euclidean_zero_distance_m)
        t = gt_frame[g_order][pg]
        keep = sim > 0
        return cls._build(
            g_counts=g_counts,
            d_counts=d_counts,
            raw_gt_ids=np.asarray(gt_id)[g_order],
            raw_tracker_ids=np.asarray(tracker_id)[d_order],
            pairs=(t[keep], pg[keep], pd[keep], sim[keep]),
            gt_centroids=centroids,
        )

    @classmethod
    def _build(cls, *, g_counts, d_counts, raw_gt_ids, raw_tracker_ids, pairs, gt_centroids):
        gt_unique, gt_ids = np.unique(raw_gt_ids, return_inverse=True)
        tr_unique, tr_ids = np.unique(raw_tracker_ids, return_inverse=True)
        gt_offsets = np.concatenate([[0], np.cumsum(g_counts)]).astype(np.int64)
        tr_offsets = np.concatenate([[0], np.cumsum(d_counts)]).astype(np.int64)
        for name, ids, offsets in (("gt", gt_ids, gt_offsets), ("tracker", tr_ids, tr_offsets)):
            frame = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
            key = np.sort(frame * (ids.max() + 1 if len(ids) else 1) + ids)
            if np.any(key[1:] == key[:-1]):
                raise InputError(f"{name} ids: expected ids unique within each frame, got a repeated id")
        frame, g, d, sim = pairs
        return cls(
            num_frames=len(g_counts),
            gt_offsets=gt_offsets,
            gt_ids=gt_ids.astype(np.int64),
            tracker_offsets=tr_offsets,
            tracker_ids=tr_ids.astype(np.int64),
            pair_frame=np.asarray(frame, dtype=np.int64),
            pair_gt=np.asarray(g, dtype=np.int64),
            pair_tracker=np.asarray(d, dtype=np.int64),
            pair_similarity=np.asarray(sim, dtype=np.float64),
            gt_centroids=gt_centroids,
            num_gt_ids=len(gt_unique),
            num_tracker_ids=len(tr_unique),
        )

    @property
    def num_gt_dets(self) -> int:
        return int(self.gt_offsets[-1])

    @property
    def num_tracker_dets(self) -> int:
        return int(self.tracker_offsets[-1])


def _concat_ids(per_frame: Sequence[np.ndarray]) -> np.ndarray:
    if not len(per_frame):
        return np.zeros(0, dtype=np.int64)
    return np.concatenate([np.asarray(x).ravel() for x in per_frame])


def _concat_floats(per_frame: Sequence[np.ndarray]) -> np.ndarray:
    return np.concatenate(per_frame).astype(np.float64) if len(per_frame) else np.zeros(0)


def _concat_rows(per_frame: Sequence[np.ndarray], width: int) -> np.ndarray:
    rows = [np.asarray(x, dtype=np.float64).reshape(-1, width) for x in per_frame]
    return np.concatenate(rows) if rows else np.zeros((0, width))


def _overlapping_pairs(
    g_frame: np.ndarray, g_box: np.ndarray, d_frame: np.ndarray, d_box: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate same-frame pairs by a sorted sweep (no dense grid): every pair whose axis-aligned boxes touch
    or overlap, plus possibly pairs apart by less than 1e-6 of the x extent (callers drop pairs that do not
    overlap by their exact similarity).

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
    # Frame-major keys: tracker boxes sorted by (frame, x0); a gt box's partners have x0 in
    # [gt x0 - widest tracker box, gt x1] within its frame.
    d_key = d_frame * (4.0 * span) + (d_box[:, 0] - lo_x)
    d_order = np.argsort(d_key, kind="stable")
    d_key = d_key[d_order]
    widest = float((d_box[:, 2] - d_box[:, 0]).max())
    g_base = g_frame * (4.0 * span) - lo_x
    lo = np.searchsorted(d_key, g_base + g_box[:, 0] - widest - slack, side="left")
    hi = np.searchsorted(d_key, g_base + g_box[:, 2] + slack, side="right")
    counts = np.maximum(hi - lo, 0)
    pg = np.repeat(np.arange(len(g_frame)), counts)
    offset = np.arange(len(pg)) - np.repeat(np.cumsum(counts) - counts, counts)
    pd = d_order[lo[pg] + offset]
    # Keys are frame-major with a 4 * span stride, so every search stays inside the gt box's own frame, and
    # the search already bounds the tracker x0 by the gt x1 (up to the slack; such pairs have no overlap and
    # are dropped by the exact similarity). The remaining interval tests:
    keep = np.ones(len(pg), dtype=bool)
    for g_col, d_col, below in ((0, 2, False), (3, 1, True), (1, 3, False)):
        g_values, d_values = np.ascontiguousarray(g_box[:, g_col]), np.ascontiguousarray(d_box[:, d_col])
        if below:
            keep &= d_values[pd] <= g_values[pg]
        else:
            keep &= d_values[pd] >= g_values[pg]
    return pg[keep], pd[keep]


def _certified_components(
    competing: np.ndarray, g: np.ndarray, d: np.ndarray, weight: np.ndarray, matched: np.ndarray
) -> np.ndarray:
    """Matches, in place, every connected component whose rows' best columns are all different.

    Giving each row its heaviest pair reaches the upper bound sum(row maxima), so where that choice is
    one-to-one it is the optimal assignment of the component (unique unless weights tie).

    Args:
        competing: (K,) pairs still to match, frame-ordered.
        g: (P,) gt detection index of every pair.
        d: (P,) tracker detection index of every pair.
        weight: (P,) positive weights on ``competing``.
        matched: (P,) bool, set for the pairs of the certified components.

    Returns:
        The pairs of the remaining components.
    """
    _, rows = np.unique(g[competing], return_inverse=True)
    _, cols = np.unique(d[competing], return_inverse=True)
    n_r, n_c = int(rows.max()) + 1, int(cols.max()) + 1
    graph = coo_array((np.ones(len(rows)), (rows, n_r + cols)), shape=(n_r + n_c, n_r + n_c))
    _, label = connected_components(graph, directed=False)
    order = np.argsort(rows, kind="stable")
    w = weight[competing][order]
    starts = np.r_[0, np.flatnonzero(np.diff(rows[order])) + 1]
    row_max = np.maximum.reduceat(w, starts)
    is_max = w == np.repeat(row_max, np.diff(np.r_[starts, len(order)]))
    # First heaviest pair of each row.
    at_max = np.flatnonzero(is_max)
    max_rows = rows[order][at_max]
    best = order[at_max[np.r_[True, max_rows[1:] != max_rows[:-1]]]]
    uses = np.bincount(cols[best], minlength=n_c)
    bad = np.zeros(label.max() + 1, dtype=bool)
    bad[label[n_r + np.flatnonzero(uses > 1)]] = True
    pair_bad = bad[label[rows]]
    matched[competing[best[~pair_bad[best]]]] = True
    return competing[pair_bad]


def _max_weight_matching(
    frame: np.ndarray, g: np.ndarray, d: np.ndarray, weight: np.ndarray, n_g: int, n_d: int,
    bonus: Callable[[int, np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """Per-frame optimal assignment maximising the summed weight, as ``linear_sum_assignment(-W)`` per frame.

    Args:
        frame: (P,) frame of each pair, non-decreasing.
        g: (P,) global gt detection index (detections are frame-ordered, so frames never share one).
        d: (P,) global tracker detection index.
        weight: (P,) non-negative weights; only positive entries can be matched.
        n_g: number of gt detections.
        n_d: number of tracker detections.
        bonus: optional ``bonus(frame, part, matched) -> (k,)`` extra weight for the k competing pairs
            ``part`` of one frame, called in frame order with the matches of all earlier frames final in
            ``matched`` (CLEAR's continuation of the previous timestep's partner).

    Returns:
        (P,) bool, the pairs with positive weight that the assignment matches.
    """
    positive = weight > 0
    row_count = np.bincount(g[positive], minlength=n_g)
    col_count = np.bincount(d[positive], minlength=n_d)
    matched = positive & (row_count[g] == 1) & (col_count[d] == 1)
    competing = np.flatnonzero(positive & ~matched)
    if bonus is None and len(competing):
        competing = _certified_components(competing, g, d, weight, matched)
    if len(competing) == 0:
        return matched
    # Compact row / column numbers; each frame's rows (columns) are a contiguous run of them.
    _, rows = np.unique(g[competing], return_inverse=True)
    _, cols = np.unique(d[competing], return_inverse=True)
    bounds = np.r_[0, np.flatnonzero(np.diff(frame[competing])) + 1, len(competing)]
    starts = bounds[:-1]
    row_base = np.minimum.reduceat(rows, starts)
    col_base = np.minimum.reduceat(cols, starts)
    n_rows = np.maximum.reduceat(rows, starts) - row_base + 1
    n_cols = np.maximum.reduceat(cols, starts) - col_base + 1
    part_of = np.repeat(np.arange(len(starts)), np.diff(bounds))
    flat = (rows - row_base[part_of]) * n_cols[part_of] + (cols - col_base[part_of])
    w = weight[competing]
    partner = np.full(len(rows), -1)
    # Plain Python scalars in the loop: it runs once per frame with competing pairs.
    b_list, nr_list, nc_list = bounds.tolist(), n_rows.tolist(), n_cols.tolist()
    rb_list, cb_list = row_base.tolist(), col_base.tolist()
    if bonus is None:
        # Every frame's dense matrix lives in one buffer, filled at once; the loop only solves.
        sizes = n_rows * n_cols
        offsets = np.r_[0, np.cumsum(sizes)]
        buffer = np.zeros(int(offsets[-1]))
        buffer[offsets[part_of] + flat] = w
        o_list = offsets.tolist()
        solved_r, solved_c = [], []
        for k in range(len(starts)):
            rr, cc = linear_sum_assignment(
                buffer[o_list[k]:o_list[k + 1]].reshape(nr_list[k], nc_list[k]), maximize=True
            )
            solved_r.append(rr + rb_list[k])
            solved_c.append(cc + cb_list[k])
        # An assigned (row, column) is a match only where a competing pair (positive weight) exists.
        partner[np.concatenate(solved_r)] = np.concatenate(solved_c)
    else:
        for k in range(len(starts)):
            lo, hi = b_list[k], b_list[k + 1]
            part = competing[lo:hi]
            sub = np.zeros(nr_list[k] * nc_list[k])
            sub[flat[lo:hi]] = w[lo:hi] + bonus(int(frame[part[0]]), part, matched)
            rr, cc = linear_sum_assignment(sub.reshape(nr_list[k], nc_list[k]), maximize=True)
            partner[rr + rb_list[k]] = cc + cb_list[k]
            matched[part] = partner[rows[lo:hi]] == cols[lo:hi]
    matched[competing] = partner[rows] == cols
    return matched


def _compact(key: np.ndarray, n_keys: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(key, return_inverse=True)`` for integer keys in [0, n_keys), by a table when that is small."""
    if n_keys > 8 * len(key) + 65536:
        return np.unique(key, return_inverse=True)
    present = np.zeros(n_keys, dtype=bool)
    present[key] = True
    cells = np.flatnonzero(present)
    lookup = np.cumsum(present) - 1
    return cells, lookup[key]


def hota(seq: TrackingSequence) -> dict[str, np.ndarray | float]:
    """HOTA family for one sequence, as ``trackeval.metrics.HOTA.eval_sequence``.

    Args:
        seq: the sequence.

    Returns:
        Field name -> value: (19,) arrays over ``HOTA_ALPHAS`` for HOTA, DetA, AssA, DetRe, DetPr, AssRe,
        AssPr, LocA, OWTA, HOTA_TP, HOTA_FN, HOTA_FP; floats HOTA(0), LocA(0), HOTALocA(0).
    """
    n_alpha = len(HOTA_ALPHAS)
    res: dict = {k: np.zeros(n_alpha) for k in ("HOTA_TP", "HOTA_FN", "HOTA_FP", "AssA", "AssRe", "AssPr")}
    if seq.num_tracker_dets == 0 or seq.num_gt_dets == 0:
        res["HOTA_FN"] = seq.num_gt_dets * np.ones(n_alpha) if seq.num_tracker_dets == 0 else res["HOTA_FN"]
        res["HOTA_FP"] = seq.num_tracker_dets * np.ones(n_alpha) if seq.num_tracker_dets else res["HOTA_FP"]
        res["LocA"] = np.ones(n_alpha)
        return _hota_final(res)
    frame, g, d, sim = seq.pair_frame, seq.pair_gt, seq.pair_tracker, seq.pair_similarity
    gid, tid = seq.gt_ids[g], seq.tracker_ids[d]
    row_sum = np.bincount(g, weights=sim, minlength=seq.num_gt_dets)
    col_sum = np.bincount(d, weights=sim, minlength=seq.num_tracker_dets)
    denom = row_sum[g] + col_sum[d] - sim
    sim_iou = np.divide(sim, denom, out=np.zeros_like(sim), where=denom > _EPS)
    # Id pairs that ever overlap, compactly numbered (cells of TrackEval's (gt id, tracker id) matrices).
    cells, cell = _compact(gid * seq.num_tracker_ids + tid, seq.num_gt_ids * seq.num_tracker_ids)
    cell_g, cell_t = cells // seq.num_tracker_ids, cells % seq.num_tracker_ids
    potential = np.bincount(cell, weights=sim_iou, minlength=len(cells))
    gt_id_count = np.bincount(seq.gt_ids, minlength=seq.num_gt_ids).astype(np.float64)[cell_g]
    tr_id_count = np.bincount(seq.tracker_ids, minlength=seq.num_tracker_ids).astype(np.float64)[cell_t]
    alignment = potential / (gt_id_count + tr_id_count - potential)
    score = alignment[cell] * sim
    m = np.flatnonzero(_max_weight_matching(frame, g, d, score, seq.num_gt_dets, seq.num_tracker_dets))
    m_sim, m_cell = sim[m], cell[m]
    # A match counts for alpha_a when sim >= alpha_a - eps: it counts for the first `level` alphas.
    level = np.searchsorted(HOTA_ALPHAS - _EPS, m_sim, side="right")
    n_cells = len(cells)
    per_level = np.bincount(m_cell * (n_alpha + 1) + level, minlength=n_cells * (n_alpha + 1))
    # counts[a, cell] = matches of the cell with level > a (reverse cumulative sum over levels).
    counts = np.cumsum(per_level.reshape(n_cells, n_alpha + 1)[:, :0:-1], axis=1)[:, ::-1].T
    tp = counts.sum(axis=1).astype(np.float64)
    sim_per_level = np.bincount(level, weights=m_sim, minlength=n_alpha + 1)
    loca_sum = np.cumsum(sim_per_level[:0:-1])[::-1]
    res["HOTA_TP"] = tp
    res["HOTA_FN"] = seq.num_gt_dets - tp
    res["HOTA_FP"] = seq.num_tracker_dets - tp
    tp_div = np.maximum(1, tp)
    res["AssA"] = (counts * (counts / np.maximum(1, gt_id_count + tr_id_count - counts))).sum(axis=1) / tp_div
    res["AssRe"] = (counts * (counts / np.maximum(1, gt_id_count))).sum(axis=1) / tp_div
    res["AssPr"] = (counts * (counts / np.maximum(1, tr_id_count))).sum(axis=1) / tp_div
    res["LocA"] = np.maximum(1e-10, loca_sum) / np.maximum(1e-10, tp)
    return _hota_final(res)


def _hota_final(res: dict) -> dict:
    tp, fn, fp = res["HOTA_TP"], res["HOTA_FN"], res["HOTA_FP"]
    res["DetRe"] = tp / np.maximum(1, tp + fn)
    res["DetPr"] = tp / np.maximum(1, tp + fp)
    res["DetA"] = tp / np.maximum(1, tp + fn + fp)
    res["HOTA"] = np.sqrt(res["DetA"] * res["AssA"])
    res["OWTA"] = np.sqrt(res["DetRe"] * res["AssA"])
    res["HOTA(0)"] = float(res["HOTA"][0])
    res["LocA(0)"] = float(res["LocA"][0])
    res["HOTALocA(0)"] = res["HOTA(0)"] * res["LocA(0)"]
    return res


def _clear_matches(seq: TrackingSequence, threshold: float) -> np.ndarray:
    """Indices of the pairs CLEAR matches: similarity >= threshold, continuing last timestep's partner first."""
    g, d, sim = seq.pair_gt, seq.pair_tracker, seq.pair_similarity
    weight = np.where(sim >= threshold - _EPS, sim, 0.0)
    g_counts, d_counts = np.diff(seq.gt_offsets), np.diff(seq.tracker_offsets)
    # "Previous timestep" is the previous frame that holds both gt and tracker detections.
    active = np.flatnonzero((g_counts > 0) & (d_counts > 0))
    prev_active = np.full(seq.num_frames, -1)
    prev_active[active[1:]] = active[:-1]
    frame_start = np.searchsorted(seq.pair_frame, np.arange(seq.num_frames + 1))
    pair_gid, pair_tid = seq.gt_ids[g], seq.tracker_ids[d]

    def continuation(t: int, part: np.ndarray, matched: np.ndarray) -> np.ndarray:
        # 1000 where the pair continues the gt's partner of the previous timestep, else 0.
        p = prev_active[t]
        if p < 0:
            return np.zeros(len(part))
        prev = np.arange(frame_start[p], frame_start[p + 1])
        prev = prev[matched[prev]]
        partner = np.full(seq.num_gt_ids, -1)
        partner[pair_gid[prev]] = pair_tid[prev]
        return 1000.0 * (partner[pair_gid[part]] == pair_tid[part])

    matched = _max_weight_matching(
        seq.pair_frame, g, d, weight, seq.num_gt_dets, seq.num_tracker_dets, bonus=continuation
    )
    return np.flatnonzero(matched)


class MotmetricsAccumulator:
    """py-motmetrics 1.4.0 ``MOTAccumulator`` event counting (one per sequence / scene).

    Per frame: an object keeps the hypothesis it was last matched to (at any earlier frame) when that
    hypothesis is present at a finite distance; the remaining objects and hypotheses get a minimum-cost,
    maximum-cardinality assignment over finite distances; a match to a hypothesis other than the object's
    last one is a switch; unmatched objects are misses and unmatched hypotheses false positives.
    """

    __slots__ = ("matches", "switches", "misses", "false_positives", "objects", "distance_sum", "_partner")

    def __init__(self) -> None:
        self.matches = self.switches = self.misses = self.false_positives = self.objects = 0
        self.distance_sum = 0.0
        self._partner: dict = {}

    def update(self, oids: Sequence, hids: Sequence, dist: np.ndarray) -> list:
        """Adds one frame.

        Args:
            oids: G object ids.
            hids: H hypothesis ids.
            dist: (G, H) distances, NaN where a pair may not match.

        Returns:
            The hypothesis ids counted as (non-switch) matches in this frame.
        """
        o_used, h_used = np.zeros(len(oids), bool), np.zeros(len(hids), bool)
        matched = []
        if len(oids) and len(hids):
            for i, oid in enumerate(oids):
                if oid not in self._partner:
                    continue
                js = [j for j, h in enumerate(hids) if not h_used[j] and h == self._partner[oid]]
                if js and np.isfinite(dist[i, js[0]]):
                    o_used[i], h_used[js[0]] = True, True
                    self.matches += 1
                    self.distance_sum += dist[i, js[0]]
                    matched.append(hids[js[0]])
            rest = dist.copy()
            rest[o_used, :] = np.nan
            rest[:, h_used] = np.nan
            valid = np.isfinite(rest)
            if valid.any():
                # motmetrics' scipy path prices missing edges out so that cardinality is maximal.
                large = 2 * min(rest.shape) * (np.abs(rest[valid]).max() + 1) + 1
                rows, cols = linear_sum_assignment(np.where(valid, rest, large))
                for i, j in zip(rows.tolist(), cols.tolist()):
                    if not valid[i, j]:
                        continue
                    if oids[i] in self._partner and self._partner[oids[i]] != hids[j]:
                        self.switches += 1
                    else:
                        self.matches += 1
                        matched.append(hids[j])
                    self.distance_sum += rest[i, j]
                    self._partner[oids[i]] = hids[j]
                    o_used[i], h_used[j] = True, True
        self.misses += int((~o_used).sum())
        self.false_positives += int((~h_used).sum())
        self.objects += len(oids)
        return matched


def clear_motmetrics(seq: TrackingSequence, config: TrackingConfig = TrackingConfig()) -> dict[str, float]:
    """CLEAR counts as py-motmetrics 1.4.0 computes them (distance 1 - similarity, pairs below
    ``clear_threshold`` not allowed). They differ from TrackEval's CLEAR when a ground truth reappears after a
    frame without its last partner: motmetrics continues from the last match at any time, TrackEval only from
    the previous timestep.

    Args:
        seq: the sequence.
        config: ``clear_threshold``.

    Returns:
        motmetrics names: num_matches, num_switches, num_false_positives, num_misses, num_objects, mota,
        motp (mean distance of matches and switches, NaN without any).
    """
    acc = MotmetricsAccumulator()
    frame_start = np.searchsorted(seq.pair_frame, np.arange(seq.num_frames + 1))
    for t in range(seq.num_frames):
        g0, g1 = seq.gt_offsets[t], seq.gt_offsets[t + 1]
        d0, d1 = seq.tracker_offsets[t], seq.tracker_offsets[t + 1]
        dist = np.full((g1 - g0, d1 - d0), np.nan)
        pairs = slice(frame_start[t], frame_start[t + 1])
        sim = seq.pair_similarity[pairs]
        ok = sim >= config.clear_threshold
        dist[seq.pair_gt[pairs][ok] - g0, seq.pair_tracker[pairs][ok] - d0] = 1.0 - sim[ok]
        acc.update(seq.gt_ids[g0:g1].tolist(), seq.tracker_ids[d0:d1].tolist(), dist)
    detections = acc.matches + acc.switches
    return {
        "num_matches": acc.matches, "num_switches": acc.switches, "num_false_positives": acc.false_positives,
        "num_misses": acc.misses, "num_objects": acc.objects,
        "mota": 1.0 - (acc.misses + acc.switches + acc.false_positives) / acc.objects if acc.objects else float("nan"),
        "motp": acc.distance_sum / detections if detections else float("nan"),
    }


def clear(seq: TrackingSequence, config: TrackingConfig = TrackingConfig()) -> dict[str, float]:
    """CLEAR MOT metrics for one sequence, as ``trackeval.metrics.CLEAR.eval_sequence``.

    Args:
        seq: the sequence.
        config: ``clear_threshold`` is the match threshold.

    Returns:
        Field name -> value (MOTA, MOTP, MODA, CLR_Re, CLR_Pr, MTR, PTR, MLR, sMOTA, CLR_F1, FP_per_frame,
        MOTAL, MOTP_sum, and integer counts CLR_TP, CLR_FN, CLR_FP, IDSW, MT, PT, ML, Frag, CLR_Frames).
    """
    res: dict = {k: 0 for k in ("CLR_TP", "CLR_FN", "CLR_FP", "IDSW", "MT", "PT", "ML", "Frag", "MOTP_sum")}
    res["CLR_Frames"] = seq.num_frames
    if seq.num_tracker_dets == 0 or seq.num_gt_dets == 0:
        res["CLR_FN"], res["CLR_FP"] = seq.num_gt_dets, seq.num_tracker_dets
        res["ML"] = seq.num_gt_ids if seq.num_tracker_dets == 0 else 0
        # TrackEval returns early here with CLR_Frames 0 and every other float field 0 except MLR.
        out = {k: 0 for k in _CLEAR_FLOATS} | res | {"CLR_Frames": 0, "MLR": 1.0}
        return out
    m = _clear_matches(seq, config.clear_threshold)
    m_frame, m_gid, m_tid = seq.pair_frame[m], seq.gt_ids[seq.pair_gt[m]], seq.tracker_ids[seq.pair_tracker[m]]
    n_match = len(m)
    res["CLR_TP"] = n_match
    res["CLR_FN"] = seq.num_gt_dets - n_match
    res["CLR_FP"] = seq.num_tracker_dets - n_match
    res["MOTP_sum"] = float(seq.pair_similarity[m].sum())
    order = np.lexsort((m_frame, m_gid))
    s_gid, s_tid, s_frame = m_gid[order], m_tid[order], m_frame[order]
    same_gt = s_gid[1:] == s_gid[:-1]
    res["IDSW"] = int(np.sum(same_gt & (s_tid[1:] != s_tid[:-1])))
    g_counts, d_counts = np.diff(seq.gt_offsets), np.diff(seq.tracker_offsets)
    active_rank = np.cumsum((g_counts > 0) & (d_counts > 0)) - 1
    s_rank = active_rank[s_frame]
    run_start = np.ones(n_match, dtype=bool)
    run_start[1:] = ~(same_gt & (s_rank[1:] == s_rank[:-1] + 1))
    starts = np.bincount(s_gid[run_start], minlength=seq.num_gt_ids)
    res["Frag"] = int(np.sum(np.maximum(starts - 1, 0)))
    gt_id_count = np.bincount(seq.gt_ids, minlength=seq.num_gt_ids)
    matched_count = np.bincount(m_gid, minlength=seq.num_gt_ids)
    present = gt_id_count > 0
    ratio = matched_count[present] / gt_id_count[present]
    res["MT"] = int(np.sum(ratio > 0.8))
    res["PT"] = int(np.sum(ratio >= 0.2)) - res["MT"]
    res["ML"] = seq.num_gt_ids - res["MT"] - res["PT"]
    return _clear_final(res)


_CLEAR_FLOATS = (
    "MOTA", "MOTP", "MODA", "CLR_Re", "CLR_Pr", "MTR", "PTR", "MLR", "sMOTA", "CLR_F1", "FP_per_frame", "MOTAL",
)


def _clear_final(res: dict) -> dict:
    num_gt_ids = res["MT"] + res["ML"] + res["PT"]
    tp, fn, fp, idsw = res["CLR_TP"], res["CLR_FN"], res["CLR_FP"], res["IDSW"]
    res["MTR"] = res["MT"] / max(1.0, num_gt_ids)
    res["MLR"] = res["ML"] / max(1.0, num_gt_ids)
    res["PTR"] = res["PT"] / max(1.0, num_gt_ids)
    res["CLR_Re"] = tp / max(1.0, tp + fn)
    res["CLR_Pr"] = tp / max(1.0, tp + fp)
    res["MODA"] = (tp - fp) / max(1.0, tp + fn)
    res["MOTA"] = (tp - fp - idsw) / max(1.0, tp + fn)
    res["MOTP"] = res["MOTP_sum"] / max(1.0, tp)
    res["sMOTA"] = (res["MOTP_sum"] - fp - idsw) / max(1.0, tp + fn)
    res["CLR_F1"] = tp / max(1.0, tp + 0.5 * fn + 0.5 * fp)
    res["FP_per_frame"] = fp / max(1.0, res["CLR_Frames"])
    safe_log_idsw = np.log10(idsw) if idsw > 0 else idsw
    res["MOTAL"] = (tp - fp - safe_log_idsw) / max(1.0, tp + fn)
    return res


def _thresholded_counts(seq: TrackingSequence, threshold: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Id pairs (gt id, tracker id) with their number of frames of similarity >= threshold (only pairs > 0)."""
    hit = seq.pair_similarity >= threshold
    key = seq.gt_ids[seq.pair_gt[hit]] * seq.num_tracker_ids + seq.tracker_ids[seq.pair_tracker[hit]]
    cells, inverse = _compact(key, seq.num_gt_ids * seq.num_tracker_ids)
    counts = np.bincount(inverse, minlength=len(cells))
    return cells // seq.num_tracker_ids, cells % seq.num_tracker_ids, counts.astype(np.float64)


def _assignment_total(rows: np.ndarray, cols: np.ndarray, values: np.ndarray) -> float:
    """Largest sum of ``values`` over a one-to-one matching of the given (row, col) cells (others are 0)."""
    if len(values) == 0:
        return 0.0
    u_r, r_idx = np.unique(rows, return_inverse=True)
    u_c, c_idx = np.unique(cols, return_inverse=True)
    dense = np.zeros((len(u_r), len(u_c)))
    dense[r_idx, c_idx] = values
    rr, cc = linear_sum_assignment(dense, maximize=True)
    return float(dense[rr, cc].sum())


def identity(seq: TrackingSequence, config: TrackingConfig = TrackingConfig()) -> dict[str, float]:
    """Identity metrics (IDF1, IDR, IDP, IDTP, IDFN, IDFP), as ``trackeval.metrics.Identity``.

    Args:
        seq: the sequence.
        config: ``identity_threshold`` is the IDTP threshold.

    Returns:
        Field name -> value.
    """
    res: dict = {"IDTP": 0, "IDFN": 0, "IDFP": 0}
    if seq.num_tracker_dets == 0 or seq.num_gt_dets == 0:
        res["IDFN"], res["IDFP"] = seq.num_gt_dets, seq.num_tracker_dets
        return {"IDF1": 0, "IDR": 0, "IDP": 0} | res
    # TrackEval solves a (G+D) x (G+D) assignment whose cost is IDFN + IDFP = total gt dets + total tracker
    # dets - 2 * (summed co-occurrence counts of the matched id pairs); so IDTP is the largest such sum over
    # one-to-one id matchings, found on the id pairs that co-occur at all.
    rows, cols, counts = _thresholded_counts(seq, config.identity_threshold)
    idtp = int(round(_assignment_total(rows, cols, counts)))
    res["IDTP"] = idtp
    res["IDFN"] = seq.num_gt_dets - idtp
    res["IDFP"] = seq.num_tracker_dets - idtp
    return _identity_final(res)


def _identity_final(res: dict) -> dict:
    tp, fn, fp = res["IDTP"], res["IDFN"], res["IDFP"]
    res["IDR"] = tp / max(1.0, tp + fn)
    res["IDP"] = tp / max(1.0, tp + fp)
    res["IDF1"] = tp / max(1.0, tp + 0.5 * fp + 0.5 * fn)
    return res


def vace(seq: TrackingSequence, config: TrackingConfig = TrackingConfig()) -> dict[str, float]:
    """VACE metrics (STDA, ATA, FDA, SFDA), relaxed per-frame variant, as ``trackeval.metrics.VACE``.

    Args:
        seq: the sequence; every id must have at least one detection.
        config: ``vace_threshold`` is the per-frame overlap criterion.

    Returns:
        Field name -> value (ATA and SFDA are NaN when undefined, as in TrackEval).
    """
    frame, g, d, sim = seq.pair_frame, seq.pair_gt, seq.pair_tracker, seq.pair_similarity
    rows, cols, potential = _thresholded_counts(seq, config.vace_threshold)
    gt_id_count = np.bincount(seq.gt_ids, minlength=seq.num_gt_ids).astype(np.float64)
    tr_id_count = np.bincount(seq.tracker_ids, minlength=seq.num_tracker_ids).astype(np.float64)
    # Frames in which both ids are present, for the id pairs with any overlap frame.
    gt_presence = np.zeros((seq.num_gt_ids, seq.num_frames))
    gt_presence[seq.gt_ids, np.repeat(np.arange(seq.num_frames), np.diff(seq.gt_offsets))] = 1
    tr_presence = np.zeros((seq.num_tracker_ids, seq.num_frames))
    tr_presence[seq.tracker_ids, np.repeat(np.arange(seq.num_frames), np.diff(seq.tracker_offsets))] = 1
    both = np.einsum("kt,kt->k", gt_presence[rows], tr_presence[cols])
    temporal_iou = potential / (gt_id_count[rows] + tr_id_count[cols] - both)
    res: dict = {"STDA": _assignment_total(rows, cols, temporal_iou)}
    res["VACE_IDs"], res["VACE_GT_IDs"] = seq.num_tracker_ids, seq.num_gt_ids
    g_counts, d_counts = np.diff(seq.gt_offsets), np.diff(seq.tracker_offsets)
    matched = _max_weight_matching(frame, g, d, sim, seq.num_gt_dets, seq.num_tracker_dets)
    overlap = np.bincount(frame[matched], weights=sim[matched], minlength=seq.num_frames)
    both_present = (g_counts > 0) & (d_counts > 0)
    res["FDA"] = float(np.sum(overlap[both_present] / (0.5 * (g_counts + d_counts)[both_present])))
    res["num_non_empty_timesteps"] = int(np.sum((g_counts > 0) | (d_counts > 0)))
    return res | _vace_final(res)


def _vace_final(res: dict) -> dict:
    with np.errstate(invalid="ignore", divide="ignore"):
        ata = np.float64(res["STDA"]) / (0.5 * (res["VACE_IDs"] + res["VACE_GT_IDs"]))
        sfda = np.float64(res["FDA"]) / res["num_non_empty_timesteps"]
    return {"ATA": float(ata), "SFDA": float(sfda)}


def ideucl(seq: TrackingSequence, config: TrackingConfig = TrackingConfig()) -> dict[str, float]:
    """IDEucl for one sequence, as ``trackeval.metrics.IDEucl``: the fraction of ground-truth path length
    covered by the matched tracker identity (Hungarian over summed centroid travel).

    Args:
        seq: the sequence, with ``gt_centroids``.
        config: ``ideucl_threshold`` is the per-frame match threshold.

    Returns:
        ``{"IDEucl": value}``.
    """
    if seq.num_tracker_dets == 0 or seq.num_gt_dets == 0:
        return {"IDEucl": 0.0}
    if seq.gt_centroids is None:
        raise InputError("IDEucl: expected ground-truth centroids in the sequence, got none")
    g, d = seq.pair_gt, seq.pair_tracker
    hit = seq.pair_similarity >= config.ideucl_threshold
    hg, hd = g[hit], d[hit]
    pair_cell = seq.gt_ids[hg] * seq.num_tracker_ids + seq.tracker_ids[hd]
    # Path length of the gt centroids restricted to the frames where the (gt, tracker) pair matched,
    # in frame order (pairs are already frame-ordered).
    order = np.argsort(pair_cell, kind="stable")
    cells, pts = pair_cell[order], seq.gt_centroids[hg[order]]
    steps = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    same = cells[1:] == cells[:-1]
    uniq = np.unique(cells)
    pair_dist = np.bincount(np.searchsorted(uniq, cells[1:][same]), weights=steps[same], minlength=len(uniq))
    gt_order = np.argsort(seq.gt_ids, kind="stable")
    gids, gpts = seq.gt_ids[gt_order], seq.gt_centroids[gt_order]
    g_same = gids[1:] == gids[:-1]
    g_steps = np.linalg.norm(np.diff(gpts, axis=0), axis=1)
    gt_len = np.bincount(gids[1:][g_same], weights=g_steps[g_same], minlength=seq.num_gt_ids)
    oid, hid = uniq // seq.num_tracker_ids, uniq % seq.num_tracker_ids
    hyp_len = _assignment_total(oid, hid, pair_dist)
    total = gt_len.sum()
    return {"IDEucl": float(hyp_len / total) if total != 0 else 0.0}


def track_rates(seq: TrackingSequence, config: TrackingConfig = TrackingConfig()) -> dict[str, float]:
    """False-track and missed-track rates from CLEAR's per-frame matches.

    A tracker track is a false track when the fraction of its detections matched to any ground truth is
    below ``track_rate_threshold``; a ground-truth track is missed when the fraction of its frames matched
    to any tracker detection is below it.

    Args:
        seq: the sequence.
        config: ``clear_threshold`` for per-frame matching, ``track_rate_threshold`` for tracks.

    Returns:
        FalseTracks, MissedTracks (counts), FTR (false tracks / tracker tracks), MTR_tracks
        (missed tracks / gt tracks), as fractions in [0, 1] (0 when there are no tracks).
    """
    g, d = seq.pair_gt, seq.pair_tracker
    m = (_clear_matches(seq, config.clear_threshold) if seq.num_gt_dets and seq.num_tracker_dets
         else np.zeros(0, dtype=np.int64))
    tr_count = np.bincount(seq.tracker_ids, minlength=seq.num_tracker_ids)
    gt_count = np.bincount(seq.gt_ids, minlength=seq.num_gt_ids)
    tr_matched = np.bincount(seq.tracker_ids[d[m]], minlength=seq.num_tracker_ids)
    gt_matched = np.bincount(seq.gt_ids[g[m]], minlength=seq.num_gt_ids)
    false_tracks = int(np.sum(tr_matched < config.track_rate_threshold * tr_count))
    missed = int(np.sum(gt_matched < config.track_rate_threshold * gt_count))
    res = {"FalseTracks": false_tracks, "MissedTracks": missed, "TrackerTracks": seq.num_tracker_ids,
           "GTTracks": seq.num_gt_ids}
    return _track_rates_final(res)


def _track_rates_final(res: dict) -> dict:
    res["FTR"] = res["FalseTracks"] / max(1, res["TrackerTracks"])
    res["MTR_tracks"] = res["MissedTracks"] / max(1, res["GTTracks"])
    return res


_SUMMED = {
    TrackingMetric.CLEAR: ("CLR_TP", "CLR_FN", "CLR_FP", "IDSW", "MT", "PT", "ML", "Frag", "CLR_Frames",
                           "MOTP_sum"),
    TrackingMetric.IDENTITY: ("IDTP", "IDFN", "IDFP"),
    TrackingMetric.VACE: ("VACE_IDs", "VACE_GT_IDs", "num_non_empty_timesteps", "STDA", "FDA"),
    TrackingMetric.TRACK_RATES: ("FalseTracks", "MissedTracks", "TrackerTracks", "GTTracks"),
}


def combine_sequences(metric: TrackingMetric, per_sequence: Sequence[dict]) -> dict:
    """Combines per-sequence results as TrackEval's ``combine_sequences``.

    Args:
        metric: which metric family the results belong to.
        per_sequence: S per-sequence result dicts of that family.

    Returns:
        The combined result dict.
    """
    if metric is TrackingMetric.HOTA:
        res = {k: sum(r[k] for r in per_sequence) for k in ("HOTA_TP", "HOTA_FN", "HOTA_FP")}
        for k in ("AssRe", "AssPr", "AssA"):
            res[k] = sum(r[k] * r["HOTA_TP"] for r in per_sequence) / np.maximum(1.0, res["HOTA_TP"])
        loca = sum(r["LocA"] * r["HOTA_TP"] for r in per_sequence)
        res["LocA"] = np.maximum(1e-10, loca) / np.maximum(1e-10, res["HOTA_TP"])
        return _hota_final(res)
    if metric is TrackingMetric.IDEUCL:
        return {"IDEucl": sum(r["IDEucl"] for r in per_sequence) / len(per_sequence)}
    res = {k: sum(r[k] for r in per_sequence) for k in _SUMMED[metric]}
    final = {
        TrackingMetric.CLEAR: _clear_final,
        TrackingMetric.IDENTITY: _identity_final,
        TrackingMetric.VACE: lambda r: r | _vace_final(r),
        TrackingMetric.TRACK_RATES: _track_rates_final,
    }[metric]
    return final(res)


_FUNCTIONS: dict[TrackingMetric, Callable[[TrackingSequence, TrackingConfig], dict]] = {
    TrackingMetric.HOTA: lambda seq, config: hota(seq),
    TrackingMetric.CLEAR: clear,
    TrackingMetric.IDENTITY: identity,
    TrackingMetric.VACE: vace,
    TrackingMetric.IDEUCL: ideucl,
    TrackingMetric.TRACK_RATES: track_rates,
}


def evaluate_tracking(
    sequences: Mapping[str, TrackingSequence],
    metrics: Sequence[TrackingMetric] = (TrackingMetric.HOTA, TrackingMetric.CLEAR, TrackingMetric.IDENTITY),
    config: TrackingConfig = TrackingConfig(),
) -> dict[str, dict[TrackingMetric, dict]]:
    """Evaluates every sequence and combines them.

    Args:
        sequences: sequence name -> sequence (S entries).
        metrics: metric families to compute.
        config: thresholds.

    Returns:
        ``{name: {metric: fields}}`` for each sequence, plus ``"COMBINED_SEQ"`` combining them all.
    """
    if not sequences:
        raise InputError("tracking evaluation: expected at least one sequence, got none")
    out: dict[str, dict[TrackingMetric, dict]] = {
        name: {m: _FUNCTIONS[m](seq, config) for m in metrics} for name, seq in sequences.items()
    }
    out["COMBINED_SEQ"] = {m: combine_sequences(m, [out[n][m] for n in sequences]) for m in metrics}
    return out


def summary(result: Mapping[TrackingMetric, dict]) -> dict[str, float | int]:
    """Flattens one result entry to TrackEval's summary names: arrays over alpha are averaged.

    Args:
        result: ``{metric: fields}`` of one sequence or of ``COMBINED_SEQ``.

    Returns:
        Metric name -> value; counts are ints, rates and scores are fractions in [0, 1].
    """
    flat: dict[str, float | int] = {}
    for fields in result.values():
        for name, value in fields.items():
            if isinstance(value, np.ndarray):
                flat[name] = float(np.mean(value))
            elif isinstance(value, (int, np.integer)):
                flat[name] = int(value)
            else:
                flat[name] = float(value)
    return flat
