"""A user's own components for the study tests, named in study files as 'tests.studies.components:...'."""

from __future__ import annotations

import numpy as np

from avdata.perception import Detections, KalmanTracker, Tracks


def still_tracker() -> KalmanTracker:
    """The Kalman tracker, as a user factory (a fresh one per scene)."""
    return KalmanTracker()


def stand_still(tracks: Tracks, horizon_steps: int, step_s: float) -> np.ndarray:
    """Predicts that nothing moves."""
    return np.repeat(tracks.boxes.center[:, None, :2], horizon_steps, axis=1)


class TruthDetector:
    """A 'model' that returns the item's own ground-truth boxes: the pipeline must then score it as perfect."""

    def __call__(self, item: dict) -> Detections:
        from avdata.frames import Boxes3D

        boxes = item["boxes"].numpy().astype(np.float64)
        classes = np.full(len(boxes), "car")  # studies score class-agnostically
        b = Boxes3D.from_yaw(boxes[:, :3], boxes[:, 3:6], boxes[:, 6], item["frame"], classes=classes)
        return Detections(boxes=b, scores=np.ones(len(b)), sensors=np.full(len(b), "truth"),
                          timestamp_ns=int(item["timestamp_ns"]))


def truth_detector() -> TruthDetector:
    """The factory a study names (no checkpoint)."""
    return TruthDetector()


#: torch's thread count each call of :class:`ThreadProbe` saw.
SEEN_THREADS: set[int] = set()


class ThreadProbe(TruthDetector):
    """The truth detector, noting how many threads torch had while it ran."""

    def __call__(self, item: dict) -> Detections:
        import torch

        SEEN_THREADS.add(torch.get_num_threads())
        return super().__call__(item)


def thread_probe() -> ThreadProbe:
    """The factory a study names."""
    return ThreadProbe()


def nan_predictor(tracks: Tracks, horizon_steps: int, step_s: float) -> np.ndarray:
    """A broken predictor: every position NaN."""
    return np.full((len(tracks.boxes), horizon_steps, 2), np.nan)


def text_predictor(tracks: Tracks, horizon_steps: int, step_s: float) -> str:
    """A broken predictor: no array at all."""
    return "soon"
