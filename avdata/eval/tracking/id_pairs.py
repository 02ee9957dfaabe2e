"""Id-pair bookkeeping shared by the identity-based metrics (HOTA, Identity, VACE)."""

from __future__ import annotations

import numpy as np

from avdata.eval.tracking.sequence import TrackingSequence

__all__ = ["thresholded_id_counts"]


def thresholded_id_counts(seq: TrackingSequence, threshold: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Id pairs (gt id, tracker id) with their number of frames of similarity >= threshold (only pairs > 0)."""
    # np.compress rather than boolean indexing: the same values without the general indexing machinery's set-up.
    counts = np.bincount(np.compress(seq.pair_similarity >= threshold, seq.pair_id_pair),
                         minlength=len(seq.id_pair_gt))
    hit = np.flatnonzero(counts)
    return np.take(seq.id_pair_gt, hit), np.take(seq.id_pair_tracker, hit), np.take(counts, hit).astype(np.float64)
