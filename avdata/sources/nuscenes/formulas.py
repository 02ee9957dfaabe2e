"""nuscenes-devkit formulas, operation for operation, vectorised over annotations."""

from __future__ import annotations

import numpy as np

#: Size of the velocity window of the devkit's ``NuScenes.box_velocity`` (seconds).
MAX_VELOCITY_TIME_DIFF_S = 1.5


def box_velocity(
    translation_first: np.ndarray,
    translation_last: np.ndarray,
    timestamp_first_us: np.ndarray,
    timestamp_last_us: np.ndarray,
    has_prev: np.ndarray,
    has_next: np.ndarray,
) -> np.ndarray:
    """The devkit's ``NuScenes.box_velocity`` for N annotations (NaN where it returns NaN).

    The devkit takes ``first`` = the previous annotation of the instance (or the annotation itself
    when there is none) and ``last`` = the next one (or itself), and returns
    ``(last.translation - first.translation) / (1e-6 * t_last - 1e-6 * t_first)``; NaN when the
    annotation has neither neighbour, or when the time difference exceeds 1.5 s (3 s when both
    neighbours exist). The arithmetic here is the same, so results agree bit for bit.

    Args:
        translation_first: (N, 3) centre of ``first`` in the global frame, metres.
        translation_last: (N, 3) centre of ``last``.
        timestamp_first_us: (N,) its sample's timestamp as the table stores it (microseconds).
        timestamp_last_us: (N,) the same for ``last``.
        has_prev: (N,) whether the annotation has a previous annotation (``first`` is it).
        has_next: (N,) whether it has a next one.

    Returns:
        (N, 3) velocity in m/s in the global frame.
    """
    has_prev = np.asarray(has_prev, dtype=bool)
    has_next = np.asarray(has_next, dtype=bool)
    pos_diff = np.asarray(translation_last, dtype=np.float64) - np.asarray(translation_first, dtype=np.float64)
    time_diff = 1e-6 * np.asarray(timestamp_last_us, dtype=np.float64) - 1e-6 * np.asarray(
        timestamp_first_us, dtype=np.float64)
    max_time_diff = MAX_VELOCITY_TIME_DIFF_S * np.where(has_prev & has_next, 2, 1)
    known = (has_prev | has_next) & ~(time_diff > max_time_diff)
    with np.errstate(divide="ignore", invalid="ignore"):
        velocity = pos_diff / time_diff[:, None]
    return np.where(known[:, None], velocity, np.nan).reshape(-1, 3)
