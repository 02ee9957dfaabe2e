"""Id-pair bookkeeping shared by the identity-based metrics (HOTA, Identity, VACE)."""

from __future__ import annotations

import numpy as np

from avdata.eval.tracking.sequence import TrackingSequence, compact_keys

__all__ = ["thresholded_id_counts"]


def thresholded_id_counts(seq: TrackingSequence, threshold: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Id pairs (gt id, tracker id) with their number of frames of similarity >= threshold (only pairs > 0)."""
    hit = seq.pair_similarity >= threshold
    # np.take / np.compress rather than fancy / boolean indexing: same values, faster on these sizes.
    gid = np.take(seq.gt_ids, np.compress(hit, seq.pair_gt))
    key = gid * seq.num_tracker_ids + np.take(seq.tracker_ids, np.compress(hit, seq.pair_tracker))
    cells, inverse = compact_keys(key, seq.num_gt_ids * seq.num_tracker_ids)
    counts = np.bincount(inverse, minlength=len(cells))
    return cells // seq.num_tracker_ids, cells % seq.num_tracker_ids, counts.astype(np.float64)
