"""A small, documented perception stack for studies and examples: simulated detections, collaboration, tracking, prediction.

These exist so that studies (``avdata.studies``) and examples run end to end on any unified dataset, with
ground truth and per-sensor visibility as input; they are baselines, not state of the art. A user's own
tracker plugs in as any callable ``(Detections) -> Tracks`` (:class:`avdata.perception.tracker.Tracker`).

* :mod:`~avdata.perception.detections`: detections from ground truth + visibility, seeded noise models.
* :mod:`~avdata.perception.collaboration`: which sensors' detections reach the ego (range, rate, latency), moved
  into the ego frame through the frame graph, and merged.
* :mod:`~avdata.perception.camera`: a simulated camera detector: what one camera sees, with 2D boxes in its image.
* :mod:`~avdata.perception.detection_files`: a detector's result files (AB3DMOT CSV, KITTI results) as ``Detections``.
* :mod:`~avdata.perception.tracker`: an AB3DMOT-grade 3D Kalman tracker (per-class GIoU / IoU / distance association).
* :mod:`~avdata.perception.cli`, :mod:`~avdata.perception.track_run`: ``avdata track``, a tracker per scene of a
  dataset over result files, written as KITTI or nuScenes tracking results or the unified tracks table.
* :mod:`~avdata.perception.predictor`: constant-velocity (kinematic) trajectory prediction.
"""

from avdata.perception.collaboration import CollaborationConfig, CollaborativePerception, FrameDelivery, merge_detections
from avdata.perception.detections import NOISE_LEVELS, Detections, DetectionSimulator, NoiseModel
from avdata.perception.predictor import predict_constant_velocity
from avdata.perception.tracker import KalmanTracker, Tracker, TrackerConfig, Tracks

__all__ = [
    "NOISE_LEVELS",
    "CollaborationConfig",
    "CollaborativePerception",
    "DetectionSimulator",
    "Detections",
    "FrameDelivery",
    "KalmanTracker",
    "NoiseModel",
    "Tracker",
    "TrackerConfig",
    "Tracks",
    "merge_detections",
    "predict_constant_velocity",
]
