"""Constant-velocity (kinematic) trajectory prediction.

Each track's future BEV position k steps ahead is p + v k dt (k = 1..T), one mode with probability 1:
the "kinematic" predictor of AVstack's studies, and the baseline any learned predictor must beat.
"""

from __future__ import annotations

import numpy as np

from avdata.errors import InputError
from avdata.perception.tracker import Tracks

__all__ = ["predict_constant_velocity"]


def predict_constant_velocity(tracks: Tracks, horizon_steps: int, step_s: float) -> np.ndarray:
    """Future BEV positions of every track.

    Args:
        tracks: N tracks with velocities, in a fixed frame.
        horizon_steps: T, the number of future steps.
        step_s: time between steps, seconds.

    Returns:
        (N, T, 2) x, y of each track at steps 1..T, in the tracks' frame.
    """
    if horizon_steps < 1 or not (step_s > 0):
        raise InputError(f"prediction: expected horizon_steps >= 1 and step_s > 0, got {horizon_steps} and {step_s}")
    velocity = tracks.boxes.velocity
    if velocity is None:
        raise InputError("prediction: expected tracks with velocities, got none")
    ahead_s = step_s * np.arange(1, horizon_steps + 1)
    xy: np.ndarray = tracks.boxes.center[:, None, :2] + velocity[:, None, :2] * ahead_s[None, :, None]
    return xy
