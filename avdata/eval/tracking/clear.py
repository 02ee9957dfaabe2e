"""CLEAR MOT metrics (Bernardin and Stiefelhagen, 2008) as ``trackeval.metrics.CLEAR``."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from enum import Enum
from typing import Any

import numpy as np

from avdata.eval.matching import Continuation, max_weight_matching, stable_int_order
from avdata.eval.names import TrackingMetric
from avdata.eval.tracking.results import FamilyResult, MetricFamily
from avdata.eval.tracking.sequence import TrackingConfig, TrackingSequence

__all__ = ["FAMILY", "ClearField", "clear", "clear_matches", "combine_clear"]

_DEFAULT_CONFIG = TrackingConfig()


class ClearField(str, Enum):
    """CLEAR MOT fields (counts are integers)."""

    MOTA = "MOTA"
    MOTP = "MOTP"
    MODA = "MODA"
    CLR_RE = "CLR_Re"
    CLR_PR = "CLR_Pr"
    MTR = "MTR"
    PTR = "PTR"
    MLR = "MLR"
    #: TrackEval's soft MOTA, (sum of TP similarities - FP - IDSW) / n_gt; NOT AB3DMOT's scaled sMOTA, which is
    #: ``sAMOTA``'s summand in ``--protocol kitti-3dmot`` (avdata.eval.tracking.kitti_3dmot).
    SMOTA = "sMOTA"
    CLR_F1 = "CLR_F1"
    FP_PER_FRAME = "FP_per_frame"
    MOTAL = "MOTAL"
    MOTP_SUM = "MOTP_sum"
    CLR_TP = "CLR_TP"
    CLR_FN = "CLR_FN"
    CLR_FP = "CLR_FP"
    IDSW = "IDSW"
    MT = "MT"
    PT = "PT"
    ML = "ML"
    FRAG = "Frag"
    CLR_FRAMES = "CLR_Frames"

_EPS = np.finfo(np.float64).eps


def clear_matches(seq: TrackingSequence, threshold: float) -> np.ndarray:
    """Indices of the pairs CLEAR matches: similarity >= threshold, continuing last timestep's partner first.

    Args:
        seq: the sequence.
        threshold: similarity a match needs.

    Returns:
        (M,) indices into the sequence's pairs.
    """
    g, d, sim = seq.pair_gt, seq.pair_tracker, seq.pair_similarity
    weight = sim * (sim >= threshold - _EPS)  # sim where it reaches the threshold, else 0
    g_counts, d_counts = np.diff(seq.gt_offsets), np.diff(seq.tracker_offsets)
    # "Previous timestep" is the previous frame that holds both gt and tracker detections.
    active = np.flatnonzero((g_counts > 0) & (d_counts > 0))
    prev_active = np.full(seq.num_frames, -1)
    prev_active[active[1:]] = active[:-1]
    # 1000 for a pair that continues its gt's partner of the previous timestep (TrackEval's continuation).
    continuation = Continuation(previous_frame=prev_active, pair_key=seq.pair_id_pair, bonus=1000.0)
    matched = max_weight_matching(
        seq.pair_frame, g, d, weight, seq.gt_offsets, seq.tracker_offsets, continuation=continuation
    )
    return np.flatnonzero(matched)


def clear(seq: TrackingSequence, config: TrackingConfig = _DEFAULT_CONFIG) -> FamilyResult:
    """CLEAR MOT metrics for one sequence, as ``trackeval.metrics.CLEAR.eval_sequence``.

    Args:
        seq: the sequence.
        config: ``clear_threshold`` is the match threshold.

    Returns:
        Field name -> value (MOTA, MOTP, MODA, CLR_Re, CLR_Pr, MTR, PTR, MLR, sMOTA, CLR_F1, FP_per_frame,
        MOTAL, MOTP_sum, and integer counts CLR_TP, CLR_FN, CLR_FP, IDSW, MT, PT, ML, Frag, CLR_Frames).
    """
    res: dict[str, Any] = {k: 0 for k in ("CLR_TP", "CLR_FN", "CLR_FP", "IDSW", "MT", "PT", "ML", "Frag", "MOTP_sum")}
    res["CLR_Frames"] = seq.num_frames
    if seq.num_tracker_dets == 0 or seq.num_gt_dets == 0:
        res["CLR_FN"], res["CLR_FP"] = seq.num_gt_dets, seq.num_tracker_dets
        res["ML"] = seq.num_gt_ids if seq.num_tracker_dets == 0 else 0
        # TrackEval returns early here with CLR_Frames 0 and every other float field 0 except MLR.
        out = {k: 0 for k in _CLEAR_FLOATS} | res | {"CLR_Frames": 0, "MLR": 1.0}
        return FamilyResult(family=TrackingMetric.CLEAR, fields=out)
    m = clear_matches(seq, config.clear_threshold)
    m_frame = np.take(seq.pair_frame, m)
    m_gid = np.take(seq.gt_ids, np.take(seq.pair_gt, m))
    m_tid = np.take(seq.tracker_ids, np.take(seq.pair_tracker, m))
    n_match = len(m)
    res["CLR_TP"] = n_match
    res["CLR_FN"] = seq.num_gt_dets - n_match
    res["CLR_FP"] = seq.num_tracker_dets - n_match
    res["MOTP_sum"] = float(np.take(seq.pair_similarity, m).sum())
    # Matches by (gt id, frame): they are frame-ordered, so a stable sort by gt id.
    order = stable_int_order(m_gid, seq.num_gt_ids)
    s_gid, s_tid, s_frame = np.take(m_gid, order), np.take(m_tid, order), np.take(m_frame, order)
    same_gt = s_gid[1:] == s_gid[:-1]
    res["IDSW"] = int(np.sum(same_gt & (s_tid[1:] != s_tid[:-1])))
    g_counts, d_counts = np.diff(seq.gt_offsets), np.diff(seq.tracker_offsets)
    active_rank = np.cumsum((g_counts > 0) & (d_counts > 0)) - 1
    s_rank = np.take(active_rank, s_frame)
    run_start = np.ones(n_match, dtype=bool)
    run_start[1:] = ~(same_gt & (s_rank[1:] == s_rank[:-1] + 1))
    starts = np.bincount(np.compress(run_start, s_gid), minlength=seq.num_gt_ids)
    res["Frag"] = int(np.sum(np.maximum(starts - 1, 0)))
    gt_id_count = np.bincount(seq.gt_ids, minlength=seq.num_gt_ids)
    matched_count = np.bincount(m_gid, minlength=seq.num_gt_ids)
    present = gt_id_count > 0
    ratio = matched_count[present] / gt_id_count[present]
    res["MT"] = int(np.sum(ratio > 0.8))
    res["PT"] = int(np.sum(ratio >= 0.2)) - res["MT"]
    res["ML"] = seq.num_gt_ids - res["MT"] - res["PT"]
    return FamilyResult(family=TrackingMetric.CLEAR, fields=_clear_final(res))


_CLEAR_FLOATS = (
    "MOTA", "MOTP", "MODA", "CLR_Re", "CLR_Pr", "MTR", "PTR", "MLR", "sMOTA", "CLR_F1", "FP_per_frame", "MOTAL",
)


def _clear_final(res: dict[str, Any]) -> dict[str, Any]:
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

def combine_clear(per_sequence: Sequence[Mapping[str, Any]]) -> FamilyResult:
    """Combines per-sequence CLEAR results as TrackEval's ``combine_sequences`` (counts summed).

    Args:
        per_sequence: S per-sequence results.

    Returns:
        The combined result.
    """
    summed = ("CLR_TP", "CLR_FN", "CLR_FP", "IDSW", "MT", "PT", "ML", "Frag", "CLR_Frames", "MOTP_sum")
    res = {k: sum(r[k] for r in per_sequence) for k in summed}
    return FamilyResult(family=TrackingMetric.CLEAR, fields=_clear_final(res))


FAMILY = MetricFamily(metric=TrackingMetric.CLEAR, fields=ClearField, compute=clear, combine=combine_clear)
