"""Typed tracking results: the field names of each metric family as ``str`` Enums, and one value container.

Field names are TrackEval's, so :func:`avdata.eval.tracking.summary` and the JSON written by
``avdata eval tracking`` read as TrackEval's summaries do.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from enum import Enum

import numpy as np

from avdata.eval.names import TrackingMetric

__all__ = [
    "ClearField",
    "FamilyResult",
    "HotaField",
    "IdentityField",
    "IdeuclField",
    "TrackRatesField",
    "VaceField",
    "FIELDS",
]

Value = float | int | np.ndarray


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


class IdentityField(str, Enum):
    """Identity fields."""

    IDF1 = "IDF1"
    IDR = "IDR"
    IDP = "IDP"
    IDTP = "IDTP"
    IDFN = "IDFN"
    IDFP = "IDFP"


class VaceField(str, Enum):
    """VACE fields."""

    STDA = "STDA"
    VACE_IDS = "VACE_IDs"
    VACE_GT_IDS = "VACE_GT_IDs"
    FDA = "FDA"
    NUM_NON_EMPTY_TIMESTEPS = "num_non_empty_timesteps"
    ATA = "ATA"
    SFDA = "SFDA"


class IdeuclField(str, Enum):
    """IDEucl's single field."""

    IDEUCL = "IDEucl"


class TrackRatesField(str, Enum):
    """Track-level false / missed track counts and rates."""

    FALSE_TRACKS = "FalseTracks"
    MISSED_TRACKS = "MissedTracks"
    TRACKER_TRACKS = "TrackerTracks"
    GT_TRACKS = "GTTracks"
    FTR = "FTR"
    MTR_TRACKS = "MTR_tracks"


FIELDS: Mapping[TrackingMetric, type[Enum]] = {
    TrackingMetric.HOTA: HotaField,
    TrackingMetric.CLEAR: ClearField,
    TrackingMetric.IDENTITY: IdentityField,
    TrackingMetric.VACE: VaceField,
    TrackingMetric.IDEUCL: IdeuclField,
    TrackingMetric.TRACK_RATES: TrackRatesField,
}


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
        expected = {f.value for f in FIELDS[self.family]}
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
