"""False-track and missed-track rates from CLEAR's per-frame matches."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from enum import Enum
from typing import Any

import numpy as np

from avdata.eval.names import TrackingMetric
from avdata.eval.tracking.clear import clear_matches
from avdata.eval.tracking.results import FamilyResult, MetricFamily
from avdata.eval.tracking.sequence import TrackingConfig, TrackingSequence

__all__ = ["FAMILY", "TrackRatesField", "combine_track_rates", "track_rates"]

_DEFAULT_CONFIG = TrackingConfig()


class TrackRatesField(str, Enum):
    """Track-level false / missed track counts and rates."""

    FALSE_TRACKS = "FalseTracks"
    MISSED_TRACKS = "MissedTracks"
    TRACKER_TRACKS = "TrackerTracks"
    GT_TRACKS = "GTTracks"
    FTR = "FTR"
    MTR_TRACKS = "MTR_tracks"


def track_rates(seq: TrackingSequence, config: TrackingConfig = _DEFAULT_CONFIG) -> FamilyResult:
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
    m = (clear_matches(seq, config.clear_threshold) if seq.num_gt_dets and seq.num_tracker_dets
         else np.zeros(0, dtype=np.int64))
    tr_count = np.bincount(seq.tracker_ids, minlength=seq.num_tracker_ids)
    gt_count = np.bincount(seq.gt_ids, minlength=seq.num_gt_ids)
    tr_matched = np.bincount(seq.tracker_ids[d[m]], minlength=seq.num_tracker_ids)
    gt_matched = np.bincount(seq.gt_ids[g[m]], minlength=seq.num_gt_ids)
    false_tracks = int(np.sum(tr_matched < config.track_rate_threshold * tr_count))
    missed = int(np.sum(gt_matched < config.track_rate_threshold * gt_count))
    res = {"FalseTracks": false_tracks, "MissedTracks": missed, "TrackerTracks": seq.num_tracker_ids,
           "GTTracks": seq.num_gt_ids}
    return FamilyResult(family=TrackingMetric.TRACK_RATES, fields=_track_rates_final(res))


def _track_rates_final(res: dict[str, Any]) -> dict[str, Any]:
    res["FTR"] = res["FalseTracks"] / max(1, res["TrackerTracks"])
    res["MTR_tracks"] = res["MissedTracks"] / max(1, res["GTTracks"])
    return res

def combine_track_rates(per_sequence: Sequence[Mapping[str, Any]]) -> FamilyResult:
    """Combines per-sequence track-rate results as TrackEval's ``combine_sequences`` (counts summed).

    Args:
        per_sequence: S per-sequence results.

    Returns:
        The combined result.
    """
    res = {k: sum(r[k] for r in per_sequence) for k in ("FalseTracks", "MissedTracks", "TrackerTracks", "GTTracks")}
    return FamilyResult(family=TrackingMetric.TRACK_RATES, fields=_track_rates_final(res))


FAMILY = MetricFamily(metric=TrackingMetric.TRACK_RATES, fields=TrackRatesField, compute=track_rates, combine=combine_track_rates)
