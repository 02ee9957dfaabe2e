"""HOTA (Luiten et al., IJCV 2021) as ``trackeval.metrics.HOTA``, over all frames of a sequence at once."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from enum import Enum
from typing import Any

import numpy as np

from avdata.eval.matching import max_weight_matching
from avdata.eval.names import TrackingMetric
from avdata.eval.tracking.results import FamilyResult, MetricFamily
from avdata.eval.tracking.sequence import TrackingConfig, TrackingSequence

__all__ = ["FAMILY", "HOTA_ALPHAS", "HotaField", "combine_hota", "hota"]

_DEFAULT_CONFIG = TrackingConfig()


class HotaField(str, Enum):
    """HOTA fields: (19,) arrays over the alphas, except the three ``(0)`` floats."""

    HOTA = "HOTA"
    DET_A = "DetA"
    ASS_A = "AssA"
    DET_RE = "DetRe"
    DET_PR = "DetPr"
    ASS_RE = "AssRe"
    ASS_PR = "AssPr"
    LOC_A = "LocA"
    OWTA = "OWTA"
    HOTA_TP = "HOTA_TP"
    HOTA_FN = "HOTA_FN"
    HOTA_FP = "HOTA_FP"
    HOTA_0 = "HOTA(0)"
    LOC_A_0 = "LocA(0)"
    HOTA_LOC_A_0 = "HOTALocA(0)"

_EPS = np.finfo(np.float64).eps
HOTA_ALPHAS = np.arange(0.05, 0.99, 0.05)
# The thresholds alpha - eps, between -inf and +inf sentinels.
_THRESHOLDS = np.r_[-np.inf, HOTA_ALPHAS - _EPS, np.inf, np.inf]


def hota(seq: TrackingSequence, config: TrackingConfig = _DEFAULT_CONFIG) -> FamilyResult:
    """HOTA family for one sequence, as ``trackeval.metrics.HOTA.eval_sequence``.

    Args:
        seq: the sequence.
        config: unused (HOTA integrates over all thresholds); accepted so every family has one signature.

    Returns:
        Field name -> value: (19,) arrays over ``HOTA_ALPHAS`` for HOTA, DetA, AssA, DetRe, DetPr, AssRe,
        AssPr, LocA, OWTA, HOTA_TP, HOTA_FN, HOTA_FP; floats HOTA(0), LocA(0), HOTALocA(0).
    """
    n_alpha = len(HOTA_ALPHAS)
    res: dict[str, Any] = {k: np.zeros(n_alpha) for k in ("HOTA_TP", "HOTA_FN", "HOTA_FP", "AssA", "AssRe", "AssPr")}
    if seq.num_tracker_dets == 0 or seq.num_gt_dets == 0:
        res["HOTA_FN"] = seq.num_gt_dets * np.ones(n_alpha) if seq.num_tracker_dets == 0 else res["HOTA_FN"]
        res["HOTA_FP"] = seq.num_tracker_dets * np.ones(n_alpha) if seq.num_tracker_dets else res["HOTA_FP"]
        res["LocA"] = np.ones(n_alpha)
        return _result(res)
    frame, g, d, sim = seq.pair_frame, seq.pair_gt, seq.pair_tracker, seq.pair_similarity
    # np.take rather than fancy indexing throughout: the same values without the general indexing machinery's set-up.
    row_sum = np.bincount(g, weights=sim, minlength=seq.num_gt_dets)
    col_sum = np.bincount(d, weights=sim, minlength=seq.num_tracker_dets)
    denom = np.take(row_sum, g) + np.take(col_sum, d) - sim
    sim_iou = np.divide(sim, denom, out=np.zeros_like(sim), where=denom > _EPS)
    # Id pairs that ever overlap, compactly numbered (cells of TrackEval's (gt id, tracker id) matrices).
    cell, cell_g, cell_t = seq.pair_id_pair, seq.id_pair_gt, seq.id_pair_tracker
    n_cells = len(cell_g)
    potential = np.bincount(cell, weights=sim_iou, minlength=n_cells)
    gt_id_count = np.bincount(seq.gt_ids, minlength=seq.num_gt_ids).astype(np.float64)[cell_g]
    tr_id_count = np.bincount(seq.tracker_ids, minlength=seq.num_tracker_ids).astype(np.float64)[cell_t]
    alignment = potential / (gt_id_count + tr_id_count - potential)
    score = np.take(alignment, cell) * sim
    m = np.flatnonzero(max_weight_matching(frame, g, d, score, seq.gt_offsets, seq.tracker_offsets))
    m_sim, m_cell = np.take(sim, m), np.take(cell, m)
    # A match counts for alpha_a when sim >= alpha_a - eps: it counts for the first `level` alphas, the number
    # of thresholds <= sim. With g = floor(20 sim) (thresholds are ~0.05 (a + 1), 0.05 apart), every threshold
    # below index g - 1 is <= sim and every one from g + 1 on is > sim, so two exact comparisons settle it
    # (cheaper than a binary search per match, whose branches mispredict).
    g_level = np.minimum(np.floor(m_sim * 20.0), len(HOTA_ALPHAS)).astype(np.int64)
    level = g_level - 1 + (m_sim >= np.take(_THRESHOLDS, g_level)) + (m_sim >= np.take(_THRESHOLDS, g_level + 1))
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
    return _result(res)


def _hota_final(res: dict[str, Any]) -> dict[str, Any]:
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

def combine_hota(per_sequence: Sequence[Mapping[str, Any]]) -> FamilyResult:
    """Combines per-sequence HOTA results as TrackEval's ``HOTA.combine_sequences``.

    Args:
        per_sequence: S per-sequence results.

    Returns:
        The combined result.
    """
    res: dict[str, Any] = {k: sum(r[k] for r in per_sequence) for k in ("HOTA_TP", "HOTA_FN", "HOTA_FP")}
    for k in ("AssRe", "AssPr", "AssA"):
        res[k] = sum(r[k] * r["HOTA_TP"] for r in per_sequence) / np.maximum(1.0, res["HOTA_TP"])
    loca = sum(r["LocA"] * r["HOTA_TP"] for r in per_sequence)
    res["LocA"] = np.maximum(1e-10, loca) / np.maximum(1e-10, res["HOTA_TP"])
    return _result(res)


def _result(res: dict[str, Any]) -> FamilyResult:
    return FamilyResult(family=TrackingMetric.HOTA, fields=_hota_final(res))


FAMILY = MetricFamily(metric=TrackingMetric.HOTA, fields=HotaField, compute=hota, combine=combine_hota)
