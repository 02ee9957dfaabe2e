"""py-motmetrics 1.4.0's ``MOTAccumulator`` event counting (used by nuScenes tracking) and its CLEAR counts."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from avdata.eval.tracking.sequence import TrackingConfig, TrackingSequence

__all__ = ["MotmetricsAccumulator", "clear_motmetrics"]

_DEFAULT_CONFIG = TrackingConfig()


class MotmetricsAccumulator:
    """py-motmetrics 1.4.0 ``MOTAccumulator`` event counting (one per sequence / scene).

    Per frame: an object keeps the hypothesis it was last matched to (at any earlier frame) when that
    hypothesis is present at a finite distance; the remaining objects and hypotheses get a minimum-cost,
    maximum-cardinality assignment over finite distances; a match to a hypothesis other than the object's
    last one is a switch; unmatched objects are misses and unmatched hypotheses false positives.
    """

    __slots__ = ("matches", "switches", "misses", "false_positives", "objects", "distance_sum", "_partner")

    def __init__(self) -> None:
        """An accumulator without frames."""
        self.matches = self.switches = self.misses = self.false_positives = self.objects = 0
        self.distance_sum = 0.0
        self._partner: dict[Any, Any] = {}

    def update(self, oids: Sequence[Any], hids: Sequence[Any], dist: np.ndarray) -> list[Any]:
        """Adds one frame.

        Args:
            oids: G object ids.
            hids: H hypothesis ids.
            dist: (G, H) distances, NaN where a pair may not match.

        Returns:
            The hypothesis ids counted as (non-switch) matches in this frame.
        """
        o_used, h_used = np.zeros(len(oids), bool), np.zeros(len(hids), bool)
        matched = []
        if len(oids) and len(hids):
            for i, oid in enumerate(oids):
                if oid not in self._partner:
                    continue
                js = [j for j, h in enumerate(hids) if not h_used[j] and h == self._partner[oid]]
                if js and np.isfinite(dist[i, js[0]]):
                    o_used[i], h_used[js[0]] = True, True
                    self.matches += 1
                    self.distance_sum += dist[i, js[0]]
                    matched.append(hids[js[0]])
            rest = dist.copy()
            rest[o_used, :] = np.nan
            rest[:, h_used] = np.nan
            valid = np.isfinite(rest)
            if valid.any():
                # motmetrics' scipy path prices missing edges out so that cardinality is maximal.
                large = 2 * min(rest.shape) * (np.abs(rest[valid]).max() + 1) + 1
                rows, cols = linear_sum_assignment(np.where(valid, rest, large))
                for i, j in zip(rows.tolist(), cols.tolist(), strict=True):
                    if not valid[i, j]:
                        continue
                    if oids[i] in self._partner and self._partner[oids[i]] != hids[j]:
                        self.switches += 1
                    else:
                        self.matches += 1
                        matched.append(hids[j])
                    self.distance_sum += rest[i, j]
                    self._partner[oids[i]] = hids[j]
                    o_used[i], h_used[j] = True, True
        self.misses += int((~o_used).sum())
        self.false_positives += int((~h_used).sum())
        self.objects += len(oids)
        return matched


def clear_motmetrics(seq: TrackingSequence, config: TrackingConfig = _DEFAULT_CONFIG) -> dict[str, float]:
    """CLEAR counts as py-motmetrics 1.4.0 computes them.

    Distance is 1 - similarity, pairs below ``clear_threshold`` are not allowed. The counts differ from
    TrackEval's CLEAR when a ground truth reappears after a frame without its last partner: motmetrics
    continues from the last match at any time, TrackEval only from the previous timestep.

    Args:
        seq: the sequence.
        config: ``clear_threshold``.

    Returns:
        motmetrics names: num_matches, num_switches, num_false_positives, num_misses, num_objects, mota,
        motp (mean distance of matches and switches, NaN without any).
    """
    acc = MotmetricsAccumulator()
    frame_start = np.searchsorted(seq.pair_frame, np.arange(seq.num_frames + 1))
    for t in range(seq.num_frames):
        g0, g1 = seq.gt_offsets[t], seq.gt_offsets[t + 1]
        d0, d1 = seq.tracker_offsets[t], seq.tracker_offsets[t + 1]
        dist = np.full((g1 - g0, d1 - d0), np.nan)
        pairs = slice(frame_start[t], frame_start[t + 1])
        sim = seq.pair_similarity[pairs]
        ok = sim >= config.clear_threshold
        dist[seq.pair_gt[pairs][ok] - g0, seq.pair_tracker[pairs][ok] - d0] = 1.0 - sim[ok]
        acc.update(seq.gt_ids[g0:g1].tolist(), seq.tracker_ids[d0:d1].tolist(), dist)
    detections = acc.matches + acc.switches
    return {
        "num_matches": acc.matches, "num_switches": acc.switches, "num_false_positives": acc.false_positives,
        "num_misses": acc.misses, "num_objects": acc.objects,
        "mota": 1.0 - (acc.misses + acc.switches + acc.false_positives) / acc.objects if acc.objects else float("nan"),
        "motp": acc.distance_sum / detections if detections else float("nan"),
    }
