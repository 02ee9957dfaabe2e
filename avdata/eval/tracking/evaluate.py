"""Evaluating and combining sequences: every metric family per sequence, then TrackEval's combination."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from avdata.errors import InputError
from avdata.eval.names import TrackingMetric
from avdata.eval.tracking.clear import clear, combine_clear
from avdata.eval.tracking.hota import combine_hota, hota
from avdata.eval.tracking.identity import combine_identity, identity
from avdata.eval.tracking.ideucl import combine_ideucl, ideucl
from avdata.eval.tracking.results import FamilyResult
from avdata.eval.tracking.sequence import TrackingConfig, TrackingSequence
from avdata.eval.tracking.track_rates import combine_track_rates, track_rates
from avdata.eval.tracking.vace import combine_vace, vace

__all__ = ["COMBINED", "combine_sequences", "evaluate_tracking", "summary"]

COMBINED = "COMBINED_SEQ"
_DEFAULT_CONFIG = TrackingConfig()

_FUNCTIONS: Mapping[TrackingMetric, Callable[[TrackingSequence, TrackingConfig], FamilyResult]] = {
    TrackingMetric.HOTA: hota,
    TrackingMetric.CLEAR: clear,
    TrackingMetric.IDENTITY: identity,
    TrackingMetric.VACE: vace,
    TrackingMetric.IDEUCL: ideucl,
    TrackingMetric.TRACK_RATES: track_rates,
}
_COMBINERS: Mapping[TrackingMetric, Callable[[Sequence[Mapping[str, Any]]], FamilyResult]] = {
    TrackingMetric.HOTA: combine_hota,
    TrackingMetric.CLEAR: combine_clear,
    TrackingMetric.IDENTITY: combine_identity,
    TrackingMetric.VACE: combine_vace,
    TrackingMetric.IDEUCL: combine_ideucl,
    TrackingMetric.TRACK_RATES: combine_track_rates,
}


def combine_sequences(metric: TrackingMetric, per_sequence: Sequence[Mapping[str, Any]]) -> FamilyResult:
    """Combines per-sequence results as TrackEval's ``combine_sequences``.

    Args:
        metric: which metric family the results belong to.
        per_sequence: S per-sequence results of that family.

    Returns:
        The combined result.
    """
    return _COMBINERS[metric](per_sequence)


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
    out: dict[str, dict[TrackingMetric, FamilyResult]] = {
        name: {m: _FUNCTIONS[m](seq, config) for m in metrics} for name, seq in sequences.items()
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
