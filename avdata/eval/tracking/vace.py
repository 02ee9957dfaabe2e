"""VACE (STDA, ATA, FDA, SFDA; Kasturi et al., 2009), relaxed per-frame variant, as ``trackeval.metrics.VACE``."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from enum import Enum
from typing import Any

import numpy as np

from avdata.eval.matching import max_assignment_total, max_weight_matching
from avdata.eval.names import TrackingMetric
from avdata.eval.tracking.id_pairs import thresholded_id_counts
from avdata.eval.tracking.results import FamilyResult, MetricFamily
from avdata.eval.tracking.sequence import TrackingConfig, TrackingSequence

__all__ = ["FAMILY", "VaceField", "combine_vace", "vace"]

_DEFAULT_CONFIG = TrackingConfig()


class VaceField(str, Enum):
    """VACE fields."""

    STDA = "STDA"
    VACE_IDS = "VACE_IDs"
    VACE_GT_IDS = "VACE_GT_IDs"
    FDA = "FDA"
    NUM_NON_EMPTY_TIMESTEPS = "num_non_empty_timesteps"
    ATA = "ATA"
    SFDA = "SFDA"


def vace(seq: TrackingSequence, config: TrackingConfig = _DEFAULT_CONFIG) -> FamilyResult:
    """VACE metrics (STDA, ATA, FDA, SFDA), relaxed per-frame variant, as ``trackeval.metrics.VACE``.

    Args:
        seq: the sequence; every id must have at least one detection.
        config: ``vace_threshold`` is the per-frame overlap criterion.

    Returns:
        Field name -> value (ATA and SFDA are NaN when undefined, as in TrackEval).
    """
    frame, g, d, sim = seq.pair_frame, seq.pair_gt, seq.pair_tracker, seq.pair_similarity
    rows, cols, potential = thresholded_id_counts(seq, config.vace_threshold)
    gt_id_count = np.bincount(seq.gt_ids, minlength=seq.num_gt_ids).astype(np.float64)
    tr_id_count = np.bincount(seq.tracker_ids, minlength=seq.num_tracker_ids).astype(np.float64)
    # Frames in which both ids are present, for the id pairs with any overlap frame.
    gt_presence = np.zeros((seq.num_gt_ids, seq.num_frames))
    gt_presence[seq.gt_ids, np.repeat(np.arange(seq.num_frames), np.diff(seq.gt_offsets))] = 1
    tr_presence = np.zeros((seq.num_tracker_ids, seq.num_frames))
    tr_presence[seq.tracker_ids, np.repeat(np.arange(seq.num_frames), np.diff(seq.tracker_offsets))] = 1
    both = np.einsum("kt,kt->k", gt_presence[rows], tr_presence[cols])
    temporal_iou = potential / (gt_id_count[rows] + tr_id_count[cols] - both)
    res: dict[str, Any] = {"STDA": max_assignment_total(rows, cols, temporal_iou)}
    res["VACE_IDs"], res["VACE_GT_IDs"] = seq.num_tracker_ids, seq.num_gt_ids
    g_counts, d_counts = np.diff(seq.gt_offsets), np.diff(seq.tracker_offsets)
    matched = max_weight_matching(frame, g, d, sim, seq.gt_offsets, seq.tracker_offsets)
    overlap = np.bincount(frame[matched], weights=sim[matched], minlength=seq.num_frames)
    both_present = (g_counts > 0) & (d_counts > 0)
    res["FDA"] = float(np.sum(overlap[both_present] / (0.5 * (g_counts + d_counts)[both_present])))
    res["num_non_empty_timesteps"] = int(np.sum((g_counts > 0) | (d_counts > 0)))
    return FamilyResult(family=TrackingMetric.VACE, fields=res | _vace_final(res))


def _vace_final(res: dict[str, Any]) -> dict[str, Any]:
    with np.errstate(invalid="ignore", divide="ignore"):
        ata = np.float64(res["STDA"]) / (0.5 * (res["VACE_IDs"] + res["VACE_GT_IDs"]))
        sfda = np.float64(res["FDA"]) / res["num_non_empty_timesteps"]
    return {"ATA": float(ata), "SFDA": float(sfda)}

def combine_vace(per_sequence: Sequence[Mapping[str, Any]]) -> FamilyResult:
    """Combines per-sequence VACE results as TrackEval's ``combine_sequences`` (counts summed).

    Args:
        per_sequence: S per-sequence results.

    Returns:
        The combined result.
    """
    res = {k: sum(r[k] for r in per_sequence) for k in ("VACE_IDs", "VACE_GT_IDs", "num_non_empty_timesteps", "STDA", "FDA")}
    return FamilyResult(family=TrackingMetric.VACE, fields=res | _vace_final(res))


FAMILY = MetricFamily(metric=TrackingMetric.VACE, fields=VaceField, compute=vace, combine=combine_vace)
