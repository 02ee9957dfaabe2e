"""Evaluating and combining sequences: every requested family per sequence, then TrackEval's combination.

The families come from the registry (:func:`avdata.eval.tracking.results.family_of`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from avdata.errors import InputError
from avdata.eval.names import TrackingMetric
from avdata.eval.tracking.results import FamilyResult, family_of
from avdata.eval.tracking.sequence import TrackingConfig, TrackingSequence

__all__ = ["COMBINED", "combine_sequences", "evaluate_tracking", "summary"]

COMBINED = "COMBINED_SEQ"
_DEFAULT_CONFIG = TrackingConfig()


def combine_sequences(metric: TrackingMetric, per_sequence: Sequence[Mapping[str, Any]]) -> FamilyResult:
    """Combines per-sequence results as TrackEval's ``combine_sequences``.

    Args:
        metric: which metric family the results belong to.
        per_sequence: S per-sequence results of that family.

    Returns:
        The combined result.
    """
    return family_of(metric).combine(per_sequence)


def evaluate_tracking(
    sequences: Mapping[str, TrackingSequence],
    metrics: Sequence[TrackingMetric] = (TrackingMetric.HOTA, TrackingMetric.CLEAR, TrackingMetric.IDENTITY),
    config: TrackingConfig = _DEFAULT_CONFIG,
) -> dict[str, dict[TrackingMetric, FamilyResult]]:
    """Evaluates every sequence and combines them.

    Args:
        sequences: sequence name -> sequence (S entries).
        metrics: metric families to compute.
        config: thresholds.

    Returns:
        ``{name: {metric: result}}`` for each sequence, plus :data:`COMBINED` (``"COMBINED_SEQ"``) combining
        them all.
    """
    if not sequences:
        raise InputError("tracking evaluation: expected at least one sequence, got none")
    if COMBINED in sequences:
        raise InputError(f"tracking evaluation: sequence name {COMBINED!r} is reserved for the combined result")
    computes = {m: family_of(m).compute for m in metrics}
    out: dict[str, dict[TrackingMetric, FamilyResult]] = {
        name: {m: compute(seq, config) for m, compute in computes.items()} for name, seq in sequences.items()
    }
    out[COMBINED] = {m: combine_sequences(m, [out[n][m] for n in sequences]) for m in metrics}
    return out


def summary(result: Mapping[TrackingMetric, Mapping[str, Any]]) -> dict[str, float | int]:
    """Flattens one result entry to TrackEval's summary names: arrays over alpha are averaged.

    Args:
        result: ``{metric: result}`` of one sequence or of ``COMBINED_SEQ``.

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
