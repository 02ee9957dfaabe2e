"""A tracking sequence: detections frame by frame and the similarity of every overlapping same-frame pair.

Every metric family (``hota``, ``clear``, ``identity``, ``vace``, ``ideucl``, ``track_rates``) reads this one
container; the protocols (``kitti``, ``mot``, the avdata protocol) build it from their files.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from avdata.errors import InputError
from avdata.eval import geometry
from avdata.eval.matching import overlapping_pairs, stable_int_order
from avdata.eval.names import Similarity

__all__ = ["TrackingConfig", "TrackingSequence", "compact_keys"]


def compact_keys(key: np.ndarray, n_keys: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(key, return_inverse=True)`` for integer keys in [0, n_keys), by a table when that is small.

    Args:
        key: (N,) non-negative integers below ``n_keys``.
        n_keys: bound of the keys.

    Returns:
        The sorted distinct keys and (N,) the index of each key among them.
    """
    if n_keys > 8 * len(key) + 65536:
        return np.unique(key, return_inverse=True)
    present = np.zeros(n_keys, dtype=bool)
    present[key] = True
    cells = np.flatnonzero(present)
    # Each present key's rank, written where it is: np.cumsum over the whole bool array would cast every
    # entry through a buffered loop, this touches the present ones only; only those entries are read.
    lookup = np.empty(n_keys, dtype=np.int64)
    lookup[cells] = np.arange(len(cells))
    return cells, np.take(lookup, key)


def _unique_ids(raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(raw, return_inverse=True)``, by a table for small non-negative integer ids."""
    if raw.dtype.kind in "iu" and len(raw) and raw.min() >= 0:
        return compact_keys(raw, int(raw.max()) + 1)
    return np.unique(raw, return_inverse=True)


def _has_repeats(frame: np.ndarray, ids: np.ndarray, n_ids: int) -> bool:
    """Whether an id occurs twice in one frame.

    Args:
        frame: (N,) non-decreasing frame of each detection.
        ids: (N,) ids in [0, n_ids).
        n_ids: bound of the ids.
    """
    if len(frame) == 0:
        return False
    n_cells = (int(frame[-1]) + 1) * n_ids
    if n_cells <= 32 * len(frame) + 65536:
        # A table of (frame, id) cells (a fraction of a sort's cost): a repeat leaves fewer cells than detections.
        present = np.zeros(n_cells, dtype=bool)
        present[frame * n_ids + ids] = True
        return int(np.count_nonzero(present)) < len(frame)
    # Detections by id, frame-ordered within an id (a stable sort): a repeat is adjacent.
    order = stable_int_order(ids, n_ids)
    f, i = np.take(frame, order), np.take(ids, order)
    return bool(np.any((i[1:] == i[:-1]) & (f[1:] == f[:-1])))


def _in_frame_order(
    frame: np.ndarray, ids: np.ndarray, boxes: np.ndarray, num_frames: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Detections stably sorted by frame (in [0, num_frames)); the arrays themselves when already in order."""
    if len(frame) < 2 or bool(np.all(frame[1:] >= frame[:-1])):
        return frame, ids, boxes
    order = stable_int_order(frame, num_frames)
    # np.take rather than fancy indexing: the same values without the general indexing machinery's set-up.
    return np.take(frame, order), np.take(ids, order), np.take(boxes, order, axis=0)


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
        pair_id_pair: (P,) index of each pair's (gt id, tracker id) in ``id_pair_gt`` / ``id_pair_tracker``.
        id_pair_gt: (C,) gt id of each (gt id, tracker id) that overlaps in some frame, ordered by gt id then
            tracker id (numbered once here for HOTA's, CLEAR's and the identity metrics' bookkeeping).
        id_pair_tracker: (C,) tracker id of each of them.
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
    pair_id_pair: np.ndarray
    id_pair_gt: np.ndarray
    id_pair_tracker: np.ndarray
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

        Candidate pairs come from a sorted sweep over axis-aligned bounds (``overlapping_pairs``: exact for 2D
        boxes and distances, a circumscribed-circle bound for rotated boxes); the exact similarity is computed
        on those only.

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
        gt_boxes = np.asarray(gt_boxes, dtype=np.float64)
        tracker_boxes = np.asarray(tracker_boxes, dtype=np.float64)
        gt_id, tracker_id = np.asarray(gt_id), np.asarray(tracker_id)
        _check_detections("gt", gt_frame, gt_id, gt_boxes, num_frames, similarity)
        _check_detections("tracker", tracker_frame, tracker_id, tracker_boxes, num_frames, similarity)
        gt_frame, gt_id, gt_boxes = _in_frame_order(gt_frame, gt_id, gt_boxes, num_frames)
        tracker_frame, tracker_id, tracker_boxes = _in_frame_order(tracker_frame, tracker_id, tracker_boxes, num_frames)
        g_counts = np.bincount(gt_frame, minlength=num_frames)
        d_counts = np.bincount(tracker_frame, minlength=num_frames)
        if similarity is Similarity.IOU_2D:
            # 2D boxes as transposed views of contiguous columns, made once: the sweep, the centroids and the
            # pairs' IoU then run over contiguous memory (the same values as on the rows).
            gt_boxes = np.ascontiguousarray(gt_boxes.T).T
            tracker_boxes = np.ascontiguousarray(tracker_boxes.T).T
        g_box, d_box, centroids = _sweep_bounds(similarity, gt_boxes, tracker_boxes, euclidean_zero_distance_m)
        pg, pd = overlapping_pairs(gt_frame, g_box, tracker_frame, d_box)
        if similarity is Similarity.IOU_2D:
            ga = np.take(gt_boxes.T, pg, axis=1).T
            tb = np.take(tracker_boxes.T, pd, axis=1).T
        else:
            ga, tb = np.take(gt_boxes, pg, axis=0), np.take(tracker_boxes, pd, axis=0)
        sim = _paired_similarity(similarity, ga, tb, euclidean_zero_distance_m)
        positive = sim > 0
        if not positive.all():  # candidates whose bounds only touch, or overlap without the boxes doing so
            pg, pd, sim = (np.compress(positive, x) for x in (pg, pd, sim))
        return cls._build(
            g_counts=g_counts,
            d_counts=d_counts,
            raw_gt_ids=gt_id,
            raw_tracker_ids=tracker_id,
            pairs=(np.take(gt_frame, pg), pg, pd, sim),
            gt_centroids=centroids,
        )

    @classmethod
    def _build(
        cls, *, g_counts: np.ndarray, d_counts: np.ndarray, raw_gt_ids: np.ndarray, raw_tracker_ids: np.ndarray,
        pairs: tuple[np.ndarray, ...], gt_centroids: np.ndarray | None,
    ) -> TrackingSequence:
        """The sequence of per-frame detection counts, raw ids and positive pairs (frame, gt, tracker, similarity)."""
        gt_unique, gt_ids = _unique_ids(np.asarray(raw_gt_ids))
        tr_unique, tr_ids = _unique_ids(np.asarray(raw_tracker_ids))
        gt_offsets = np.concatenate([[0], np.cumsum(g_counts)]).astype(np.int64)
        tr_offsets = np.concatenate([[0], np.cumsum(d_counts)]).astype(np.int64)
        for name, ids, offsets in (("gt", gt_ids, gt_offsets), ("tracker", tr_ids, tr_offsets)):
            frame = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
            if _has_repeats(frame, ids, int(ids.max()) + 1 if len(ids) else 1):
                raise InputError(f"{name} ids: expected ids unique within each frame, got a repeated id")
        frame, g, d, sim = pairs
        g, d = np.asarray(g, dtype=np.int64), np.asarray(d, dtype=np.int64)
        # np.take rather than fancy indexing: the same values without the general indexing machinery's set-up.
        n_tr_ids = len(tr_unique)
        id_pairs, pair_id_pair = compact_keys(
            np.take(gt_ids, g) * n_tr_ids + np.take(tr_ids, d), len(gt_unique) * n_tr_ids
        )
        return cls(
            num_frames=len(g_counts),
            gt_offsets=gt_offsets,
            gt_ids=gt_ids.astype(np.int64),
            tracker_offsets=tr_offsets,
            tracker_ids=tr_ids.astype(np.int64),
            pair_frame=np.asarray(frame, dtype=np.int64),
            pair_gt=g,
            pair_tracker=d,
            pair_similarity=np.asarray(sim, dtype=np.float64),
            pair_id_pair=pair_id_pair.astype(np.int64),
            id_pair_gt=(id_pairs // max(n_tr_ids, 1)).astype(np.int64),
            id_pair_tracker=(id_pairs % max(n_tr_ids, 1)).astype(np.int64),
            gt_centroids=gt_centroids,
            num_gt_ids=len(gt_unique),
            num_tracker_ids=len(tr_unique),
        )

    @property
    def num_gt_dets(self) -> int:
        """Number of ground-truth detections."""
        return int(self.gt_offsets[-1])

    @property
    def num_tracker_dets(self) -> int:
        """Number of tracker detections."""
        return int(self.tracker_offsets[-1])


def _check_detections(
    name: str, frames: np.ndarray, ids: np.ndarray, boxes: np.ndarray, num_frames: int, similarity: Similarity
) -> None:
    """Refuses detections whose ids, frames or boxes do not fit ``similarity``, naming ``name`` (gt or tracker)."""
    width = {Similarity.IOU_2D: 4, Similarity.IOU_BEV: 7, Similarity.IOU_3D: 7}.get(similarity)
    if ids.shape != frames.shape:
        raise InputError(f"{name} ids: expected one per detection, shape {frames.shape}, got {ids.shape}")
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
    # As the file protocols require (a NaN or infinite bound has no overlap to measure). A finite sum
    # holds no NaN or infinity (one reduction); only when it is not (those, or an overflow of finite
    # values) is each value checked.
    with np.errstate(over="ignore"):
        total = boxes.sum()
    if not np.isfinite(total) and not np.isfinite(boxes).all():
        bad = int(np.count_nonzero(~np.isfinite(boxes).all(axis=1)))
        raise InputError(f"{name} boxes: expected finite values, got {bad} boxes with NaN or infinity")


def _sweep_bounds(
    similarity: Similarity, gt_boxes: np.ndarray, tracker_boxes: np.ndarray, zero_distance_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Ng, 4) and (Nd, 4) axis-aligned bounds that pairs with positive similarity overlap, and (Ng, 2) centroids."""
    if similarity is Similarity.IOU_2D:
        g_box, d_box = gt_boxes, tracker_boxes
        # Column by column: one long loop each (on (N, 2) slices numpy runs N inner loops of 2, each with its set-up).
        centroids = np.empty((len(gt_boxes), 2))
        np.add(gt_boxes[:, 0], gt_boxes[:, 2], out=centroids[:, 0])
        np.add(gt_boxes[:, 1], gt_boxes[:, 3], out=centroids[:, 1])
        centroids /= 2
    elif similarity is Similarity.EUCLIDEAN:
        z = zero_distance_m
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
    return g_box, d_box, centroids


def _paired_similarity(similarity: Similarity, ga: np.ndarray, tb: np.ndarray, zero_distance_m: float) -> np.ndarray:
    """(K,) similarity of each pair (row k of ``ga`` with row k of ``tb``)."""
    if similarity is Similarity.IOU_2D:
        sim = geometry.box2d_iou(ga, tb, paired=True)
    elif similarity is Similarity.IOU_BEV:
        sim = geometry.bev_iou(ga, tb, paired=True)
    elif similarity is Similarity.IOU_3D:
        sim = geometry.box3d_iou(ga, tb, paired=True)
    else:
        sim = np.maximum(0, 1 - geometry.centre_distance(ga, tb, paired=True) / zero_distance_m)
    return sim


def _concat_ids(per_frame: Sequence[np.ndarray]) -> np.ndarray:
    if not len(per_frame):
        return np.zeros(0, dtype=np.int64)
    return np.concatenate([np.asarray(x).ravel() for x in per_frame])


def _concat_floats(per_frame: Sequence[np.ndarray]) -> np.ndarray:
    return np.concatenate(per_frame).astype(np.float64) if len(per_frame) else np.zeros(0)


def _concat_rows(per_frame: Sequence[np.ndarray], width: int) -> np.ndarray:
    rows = [np.asarray(x, dtype=np.float64).reshape(-1, width) for x in per_frame]
    return np.concatenate(rows) if rows else np.zeros((0, width))

