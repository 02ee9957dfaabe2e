"""IDEucl (Euclidean identity score) as ``trackeval.metrics.IDEucl``."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from enum import Enum
from typing import Any

import numpy as np

from avdata.errors import InputError
from avdata.eval.matching import max_assignment_total
from avdata.eval.names import TrackingMetric
from avdata.eval.tracking.results import FamilyResult, MetricFamily
from avdata.eval.tracking.sequence import TrackingConfig, TrackingSequence

__all__ = ["FAMILY", "IdeuclField", "combine_ideucl", "ideucl"]

_DEFAULT_CONFIG = TrackingConfig()


class IdeuclField(str, Enum):
    """IDEucl's single field."""

    IDEUCL = "IDEucl"


def ideucl(seq: TrackingSequence, config: TrackingConfig = _DEFAULT_CONFIG) -> FamilyResult:
    """IDEucl for one sequence, as ``trackeval.metrics.IDEucl``.

    The fraction of ground-truth path length covered by the matched tracker identity (Hungarian over summed
    centroid travel).

    Args:
        seq: the sequence, with ``gt_centroids``.
        config: ``ideucl_threshold`` is the per-frame match threshold.

    Returns:
        ``{"IDEucl": value}``.
    """
    if seq.num_tracker_dets == 0 or seq.num_gt_dets == 0:
        return FamilyResult(family=TrackingMetric.IDEUCL, fields={"IDEucl": 0.0})
    if seq.gt_centroids is None:
        raise InputError("IDEucl: expected ground-truth centroids in the sequence, got none")
    hit = seq.pair_similarity >= config.ideucl_threshold
    hg = seq.pair_gt[hit]
    pair_cell = seq.pair_id_pair[hit]
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
    oid, hid = seq.id_pair_gt[uniq], seq.id_pair_tracker[uniq]
    hyp_len = max_assignment_total(oid, hid, pair_dist)
    total = gt_len.sum()
    return FamilyResult(family=TrackingMetric.IDEUCL, fields={"IDEucl": float(hyp_len / total) if total != 0 else 0.0})


def combine_ideucl(per_sequence: Sequence[Mapping[str, Any]]) -> FamilyResult:
    """Combines per-sequence IDEucl as TrackEval does: the mean over sequences.

    Args:
        per_sequence: S per-sequence results.

    Returns:
        The combined result.
    """
    return FamilyResult(family=TrackingMetric.IDEUCL,
                        fields={"IDEucl": sum(r["IDEucl"] for r in per_sequence) / len(per_sequence)})


FAMILY = MetricFamily(metric=TrackingMetric.IDEUCL, fields=IdeuclField, compute=ideucl, combine=combine_ideucl)
