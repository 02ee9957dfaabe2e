"""Trajectory prediction metrics: ADE, FDE, minADE_k, minFDE_k in both definitions in use, and miss rate.

For agent i with ground truth g_t (t over the valid future steps, the last being t_f) and modes p^m:

* ADE(m) = mean_t ||p^m_t - g_t||, FDE(m) = ||p^m_{t_f} - g_{t_f}||;
* ADE / FDE: of the most likely mode (the first mode when no probabilities are given);
* minFDE_k = min over the k most likely modes of FDE(m) (both benchmarks agree);
* minADE_k, nuScenes definition: min over the k modes of ADE(m), minimised independently of FDE;
* minADE_k, Argoverse definition: ADE of the mode that minimises FDE;
* miss rate, nuScenes definition (MissRateTopK_2): a miss when every one of the k modes has a maximum
  pointwise distance above the threshold; Argoverse definition: a miss when minFDE_k is above it.

Every metric is averaged over agents.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

from avdata.errors import InputError

__all__ = ["DEFAULT_KS", "PredictionConfig", "PredictionMetric", "evaluate_prediction"]

DEFAULT_KS = (1, 5, 10)


class PredictionMetric(str, Enum):
    """Metric name stems; k-dependent names are ``f"{stem}_{k}"``."""

    ADE = "ADE"
    FDE = "FDE"
    MIN_ADE_NUSCENES = "minADE_nuscenes"
    MIN_ADE_ARGOVERSE = "minADE_argoverse"
    MIN_FDE = "minFDE"
    MISS_RATE_NUSCENES = "MR_nuscenes"
    MISS_RATE_ARGOVERSE = "MR_argoverse"


@dataclass(frozen=True, slots=True, kw_only=True)
class PredictionConfig:
    """Thresholds of the prediction metrics.

    Attributes:
        ks: numbers of modes to report min-metrics for; each must be in [1, M]. None takes those of
            :data:`DEFAULT_KS` not above M.
        miss_threshold_m: distance above which a prediction misses.
    """

    ks: tuple[int, ...] | None = None
    miss_threshold_m: float = 2.0


_DEFAULT_CONFIG = PredictionConfig()


def evaluate_prediction(
    gt_xy: np.ndarray,
    pred_xy: np.ndarray,
    probability: np.ndarray | None = None,
    valid: np.ndarray | None = None,
    config: PredictionConfig = _DEFAULT_CONFIG,
) -> dict[str, float]:
    """Prediction metrics averaged over agents.

    Args:
        gt_xy: (N, T, 2) ground-truth future positions.
        pred_xy: (N, M, T, 2) M predicted modes per agent.
        probability: (N, M) mode probabilities (ranking only), or None for the given order.
        valid: (N, T) bool, which ground-truth steps exist; None means all. Each agent needs one.
        config: ks and miss threshold.

    Returns:
        Metric name -> value; ``ADE``, ``FDE`` and, per k, ``minADE_nuscenes_k``, ``minADE_argoverse_k``,
        ``minFDE_k``, ``MR_nuscenes_k``, ``MR_argoverse_k`` (miss rates as fractions in [0, 1]).
    """
    gt = np.asarray(gt_xy, dtype=np.float64)
    pred = np.asarray(pred_xy, dtype=np.float64)
    if gt.ndim != 3 or pred.ndim != 4 or pred.shape[0] != gt.shape[0] or pred.shape[2:] != gt.shape[1:]:
        raise InputError(f"prediction: expected gt (N, T, D) and predictions (N, M, T, D), got {gt.shape} and {pred.shape}")
    n, m, t = pred.shape[:3]
    mask = np.ones((n, t), dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    if mask.shape != (n, t) or not mask.any(axis=1).all():
        raise InputError(f"prediction valid: expected (N, T) = ({n}, {t}) with a valid step per agent, got {mask.shape}")
    if probability is not None:
        probability = np.asarray(probability, dtype=np.float64)
        if probability.shape != (n, m):
            raise InputError(f"prediction probability: expected ({n}, {m}), got {probability.shape}")
        rank = np.argsort(-probability, axis=1, kind="stable")
        pred = np.take_along_axis(pred, rank[:, :, None, None], axis=1)
    dist = np.linalg.norm(pred - gt[:, None], axis=-1)  # (N, M, T)
    dist = np.where(mask[:, None], dist, np.nan)
    ade = np.nanmean(dist, axis=2)  # (N, M)
    last = t - 1 - np.argmax(mask[:, ::-1], axis=1)
    fde = dist[np.arange(n), :, last]  # (N, M)
    max_dist = np.nanmax(dist, axis=2)
    out = {PredictionMetric.ADE.value: float(ade[:, 0].mean()), PredictionMetric.FDE.value: float(fde[:, 0].mean())}
    ks = tuple(k for k in DEFAULT_KS if k <= m) if config.ks is None else config.ks
    bad = [k for k in ks if not 1 <= k <= m]
    if bad:
        raise InputError(f"prediction ks: expected numbers of modes in [1, {m}] (the predictions have {m} modes), "
                         f"got {', '.join(map(str, bad))}")
    for k in ks:
        best_fde_mode = np.argmin(fde[:, :k], axis=1)
        min_fde = fde[np.arange(n), best_fde_mode]
        out[f"{PredictionMetric.MIN_ADE_NUSCENES.value}_{k}"] = float(ade[:, :k].min(axis=1).mean())
        out[f"{PredictionMetric.MIN_ADE_ARGOVERSE.value}_{k}"] = float(ade[np.arange(n), best_fde_mode].mean())
        out[f"{PredictionMetric.MIN_FDE.value}_{k}"] = float(min_fde.mean())
        out[f"{PredictionMetric.MISS_RATE_NUSCENES.value}_{k}"] = float(
            np.mean((max_dist[:, :k] > config.miss_threshold_m).all(axis=1))
        )
        out[f"{PredictionMetric.MISS_RATE_ARGOVERSE.value}_{k}"] = float(np.mean(min_fde > config.miss_threshold_m))
    return out
