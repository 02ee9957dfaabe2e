"""The registry of tracking metric families, and the typed result of one family.

A family is declared once, in its own module ``avdata.eval.tracking.<name>`` where ``<name>`` is the lower-cased
member name of :class:`~avdata.eval.names.TrackingMetric` (``TRACK_RATES`` -> ``track_rates``): a module-level
``FAMILY = MetricFamily(...)`` holding its field names (a ``str`` Enum, TrackEval's names, so
:func:`avdata.eval.tracking.summary` and the JSON of ``avdata eval tracking`` read as TrackEval's summaries do),
its per-sequence function and its combination over sequences. Its registration is its one member of
``TrackingMetric``, which stays in the light :mod:`avdata.eval.names` so that the command line lists the choices
without importing the metric code. :func:`family_of` loads a family's module on first use; evaluation, combination
and the check of every result read the family from there.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Any

import numpy as np

from avdata.eval.names import TrackingMetric
from avdata.eval.tracking.sequence import TrackingConfig, TrackingSequence

__all__ = ["FamilyResult", "MetricFamily", "family_of"]

Value = float | int | np.ndarray


@dataclass(frozen=True, slots=True, kw_only=True)
class MetricFamily:
    """One tracking metric family, as its module declares it.

    Attributes:
        metric: the family's registered name.
        fields: the ``str`` Enum of its field names.
        compute: ``compute(sequence, config)``, the family's result for one sequence.
        combine: ``combine(per_sequence)``, the result over S sequences, as TrackEval's ``combine_sequences``.
    """

    metric: TrackingMetric
    fields: type[Enum]
    compute: Callable[[TrackingSequence, TrackingConfig], FamilyResult]
    combine: Callable[[Sequence[Mapping[str, Any]]], FamilyResult]


_LOADED: dict[TrackingMetric, MetricFamily] = {}


def family_of(metric: TrackingMetric) -> MetricFamily:
    """The family registered as ``metric``, from the ``FAMILY`` of its module (loaded once).

    Args:
        metric: the family's name.

    Returns:
        Its declaration.
    """
    found = _LOADED.get(metric)
    if found is None:
        module_name = f"{__package__}.{metric.name.lower()}"
        declared = getattr(importlib.import_module(module_name), "FAMILY", None)
        if not isinstance(declared, MetricFamily) or declared.metric is not metric:
            raise TypeError(f"{module_name}: expected FAMILY, a MetricFamily of {metric.value}, got {declared!r}")
        found = _LOADED[metric] = declared
    return found


@dataclass(frozen=True, slots=True, kw_only=True)
class FamilyResult(Mapping[str, Value]):
    """The values of one metric family for one sequence (or combined), read like a mapping.

    Keys are the family's field Enum members or their string values (``result[HotaField.DET_A]`` and
    ``result["DetA"]`` are the same). Iteration yields the string names in the order the metric computed
    them, which is the order of the JSON output.

    Attributes:
        family: the metric family.
        fields: field name (str) -> value; exactly the family's fields.
    """

    family: TrackingMetric
    fields: Mapping[str, Value]

    def __post_init__(self) -> None:
        """Checks that the values hold exactly the family's fields."""
        expected = {f.value for f in family_of(self.family).fields}
        if set(self.fields) != expected:
            raise ValueError(f"{self.family.value} result: expected fields {sorted(expected)}, got {sorted(self.fields)}")

    def __getitem__(self, key: str) -> Value:
        """The value of field ``key`` (an Enum member or its name)."""
        return self.fields[key.value if isinstance(key, Enum) else key]

    def __iter__(self) -> Iterator[str]:
        """Field names in computation order."""
        return iter(self.fields)

    def __len__(self) -> int:
        """Number of fields."""
        return len(self.fields)
