"""Multi-object tracking metrics as TrackEval 1.3.0 defines them, evaluated over all frames of a sequence at once.

* the per-frame similarities of a sequence are one flat array of (frame, gt det, tracker det) pairs
  (:class:`TrackingSequence`, built by :mod:`.sequence`);
* the per-frame optimal assignments (Hungarian) are split into independent parts: a pair that is the only
  positive entry of both its row and its column is matched in every optimal assignment, so only frames with
  competing pairs reach ``scipy.optimize.linear_sum_assignment`` (:mod:`avdata.eval.matching`);
* CLEAR's identity-continuation bonus (prefer the previous frame's partner) only matters in those competing
  parts, so they are solved in frame order while everything else is vectorised.

Frame bookkeeping mirrors TrackEval: "previous timestep" for CLEAR continuation and fragmentation is the
previous frame that held both ground truth and tracker detections.

Modules: one per metric family (:mod:`.hota`, :mod:`.clear`, :mod:`.identity`, :mod:`.vace`, :mod:`.ideucl`,
:mod:`.track_rates`), each declaring the family once (``FAMILY``: its field names as a ``str`` Enum, its
per-sequence function and its ``combine_*``); :mod:`.results` is the registry that finds them by their
``TrackingMetric`` name and holds the typed result; :mod:`.evaluate` runs and combines them; :mod:`.motmetrics`
emulates py-motmetrics (nuScenes tracking); the benchmark protocols read their files in :mod:`.kitti`,
:mod:`.mot` and :mod:`.nuscenes`.
"""

from avdata.eval.names import Similarity, TrackingMetric
from avdata.eval.tracking.clear import ClearField, clear
from avdata.eval.tracking.evaluate import COMBINED, combine_sequences, evaluate_tracking, summary
from avdata.eval.tracking.hota import HOTA_ALPHAS, HotaField, hota
from avdata.eval.tracking.identity import IdentityField, identity
from avdata.eval.tracking.ideucl import IdeuclField, ideucl
from avdata.eval.tracking.motmetrics import MotmetricsAccumulator, clear_motmetrics
from avdata.eval.tracking.results import FamilyResult, MetricFamily, family_of
from avdata.eval.tracking.sequence import TrackingConfig, TrackingSequence
from avdata.eval.tracking.track_rates import TrackRatesField, track_rates
from avdata.eval.tracking.vace import VaceField, vace

__all__ = [
    "COMBINED",
    "HOTA_ALPHAS",
    "ClearField",
    "FamilyResult",
    "HotaField",
    "IdentityField",
    "IdeuclField",
    "MetricFamily",
    "MotmetricsAccumulator",
    "Similarity",
    "TrackRatesField",
    "TrackingConfig",
    "TrackingMetric",
    "TrackingSequence",
    "VaceField",
    "clear",
    "clear_motmetrics",
    "combine_sequences",
    "evaluate_tracking",
    "family_of",
    "hota",
    "identity",
    "ideucl",
    "summary",
    "track_rates",
    "vace",
]
