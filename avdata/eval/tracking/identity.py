"""Identity metrics (Ristani et al., 2016: IDF1, IDR, IDP) as ``trackeval.metrics.Identity``."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from enum import Enum
from typing import Any

from avdata.eval.matching import max_assignment_total
from avdata.eval.names import TrackingMetric
from avdata.eval.tracking.id_pairs import thresholded_id_counts
from avdata.eval.tracking.results import FamilyResult, MetricFamily
from avdata.eval.tracking.sequence import TrackingConfig, TrackingSequence

__all__ = ["FAMILY", "IdentityField", "combine_identity", "identity"]

_DEFAULT_CONFIG = TrackingConfig()


class IdentityField(str, Enum):
    """Identity fields."""

    IDF1 = "IDF1"
    IDR = "IDR"
    IDP = "IDP"
    IDTP = "IDTP"
    IDFN = "IDFN"
    IDFP = "IDFP"


def identity(seq: TrackingSequence, config: TrackingConfig = _DEFAULT_CONFIG) -> FamilyResult:
    """Identity metrics (IDF1, IDR, IDP, IDTP, IDFN, IDFP), as ``trackeval.metrics.Identity``.

    Args:
        seq: the sequence.
        config: ``identity_threshold`` is the IDTP threshold.

    Returns:
        Field name -> value.
    """
    res: dict[str, Any] = {"IDTP": 0, "IDFN": 0, "IDFP": 0}
    if seq.num_tracker_dets == 0 or seq.num_gt_dets == 0:
        res["IDFN"], res["IDFP"] = seq.num_gt_dets, seq.num_tracker_dets
        return FamilyResult(family=TrackingMetric.IDENTITY, fields={"IDF1": 0, "IDR": 0, "IDP": 0} | res)
    # TrackEval solves a (G+D) x (G+D) assignment whose cost is IDFN + IDFP = total gt dets + total tracker
    # dets - 2 * (summed co-occurrence counts of the matched id pairs); so IDTP is the largest such sum over
    # one-to-one id matchings, found on the id pairs that co-occur at all.
    rows, cols, counts = thresholded_id_counts(seq, config.identity_threshold)
    idtp = int(round(max_assignment_total(rows, cols, counts)))
    res["IDTP"] = idtp
    res["IDFN"] = seq.num_gt_dets - idtp
    res["IDFP"] = seq.num_tracker_dets - idtp
    return FamilyResult(family=TrackingMetric.IDENTITY, fields=_identity_final(res))


def _identity_final(res: dict[str, Any]) -> dict[str, Any]:
    tp, fn, fp = res["IDTP"], res["IDFN"], res["IDFP"]
    res["IDR"] = tp / max(1.0, tp + fn)
    res["IDP"] = tp / max(1.0, tp + fp)
    res["IDF1"] = tp / max(1.0, tp + 0.5 * fp + 0.5 * fn)
    return res

def combine_identity(per_sequence: Sequence[Mapping[str, Any]]) -> FamilyResult:
    """Combines per-sequence Identity results as TrackEval's ``combine_sequences`` (counts summed).

    Args:
        per_sequence: S per-sequence results.

    Returns:
        The combined result.
    """
    res = {k: sum(r[k] for r in per_sequence) for k in ("IDTP", "IDFN", "IDFP")}
    return FamilyResult(family=TrackingMetric.IDENTITY, fields=_identity_final(res))


FAMILY = MetricFamily(metric=TrackingMetric.IDENTITY, fields=IdentityField, compute=identity, combine=combine_identity)
