"""A 3D multi-object tracker: constant-velocity Kalman filter with Hungarian assignment (AB3DMOT-style).

State of a track (10): centre x, y, z, heading yaw, length, width, height, and velocity vx, vy, vz, all in
the detections' frame (use a fixed frame such as ``world``; in a moving frame the constant-velocity model
is wrong by the frame's own motion). Per frame (dt from the detection times):

1. predict: x' = F x, P' = F P F^T + Q, with F adding v dt to the centre and Q the velocity noise of a
   white acceleration of standard deviation ``accel_sigma_mps2`` (piecewise-constant model);
2. assign: cost = BEV distance between predicted track centres and detections of the same class;
   Hungarian (``scipy.optimize.linear_sum_assignment``), pairs farther than the class's gate are unmatched;
3. update matched tracks with z = (x, y, z, yaw, l, w, h) (a detection heading more than 90 degrees from the
   track's is turned by 180 degrees first, as AB3DMOT does, so a flipped box does not spin the track);
4. birth: every unmatched detection starts a tentative track; death: a track unmatched for more than
   ``max_age`` frames is removed.

Reported: tracks with at least ``min_hits`` updates (or every track during the first ``min_hits`` frames,
as AB3DMOT reports), last updated at most ``max_coast_frames`` frames ago.

Any callable ``(Detections) -> Tracks`` is a :class:`Tracker`: studies and examples accept a user's own.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from scipy.optimize import linear_sum_assignment

from avdata.errors import InputError
from avdata.frames import Boxes3D
from avdata.perception.detections import Detections

__all__ = ["KalmanTracker", "Tracker", "TrackerConfig", "Tracks"]


@dataclass(frozen=True, slots=True, kw_only=True)
class Tracks:
    """The tracker's output at one time.

    Attributes:
        boxes: N track boxes; ``ids`` are the track ids, ``classes`` set, ``velocity`` (N, 3) in m/s.
        scores: (N,) confidence of each track (the score of its last detection).
        timestamp_ns: the time of the estimate.
    """

    boxes: Boxes3D
    scores: np.ndarray
    timestamp_ns: int


class Tracker(Protocol):
    """Anything that turns one frame's detections into the current tracks (called once per frame, in order)."""

    def __call__(self, detections: Detections) -> Tracks:
        """The tracks after this frame's detections (detections in a fixed frame, times non-decreasing)."""
        ...


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackerConfig:
    """Parameters of :class:`KalmanTracker`.

    Attributes:
        gate_m: BEV distance beyond which a detection cannot update a track, per class (``"*"`` for the rest).
        min_hits: updates before a track is reported.
        max_age: frames without an update before a track is removed.
        max_coast_frames: report a confirmed track up to this many frames after its last update.
        accel_sigma_mps2: process noise, standard deviation of the acceleration.
        measurement_sigma: standard deviations of the measured (x, y, z, yaw, l, w, h), metres and radians.
        initial_velocity_sigma_mps: prior standard deviation of a new track's velocity.
    """

    gate_m: dict[str, float] = field(default_factory=lambda: {"pedestrian": 1.5, "cyclist": 2.0, "*": 3.0})
    min_hits: int = 2
    max_age: int = 3
    max_coast_frames: int = 1
    accel_sigma_mps2: float = 3.0
    measurement_sigma: tuple[float, ...] = (0.3, 0.3, 0.3, 0.2, 0.3, 0.2, 0.2)
    initial_velocity_sigma_mps: float = 10.0

    def __post_init__(self) -> None:
        if len(self.measurement_sigma) != 7 or min(self.measurement_sigma) <= 0:
            raise InputError(f"tracker: expected 7 positive measurement sigmas, got {self.measurement_sigma!r}")
        if self.min_hits < 1 or self.max_age < 0 or self.max_coast_frames < 0:
            raise InputError(f"tracker: expected min_hits >= 1 and max_age, max_coast_frames >= 0, got "
                             f"{self.min_hits}, {self.max_age}, {self.max_coast_frames}")
        if "*" not in self.gate_m:
            raise InputError(f"tracker: expected a default gate '*' in gate_m, got {sorted(self.gate_m)}")


_H = np.hstack([np.eye(7), np.zeros((7, 3))])


class KalmanTracker:
    """The constant-velocity Kalman tracker of the module docstring; one instance per sequence.

    Args:
        config: parameters.
    """

    def __init__(self, config: TrackerConfig | None = None):
        self.config = config or TrackerConfig()
        self._x = np.zeros((0, 10))
        self._p = np.zeros((0, 10, 10))
        self._ids = np.zeros(0, dtype=np.int64)
        self._classes = np.zeros(0, dtype=str)
        self._scores = np.zeros(0)
        self._hits = np.zeros(0, dtype=np.int64)
        self._since_update = np.zeros(0, dtype=np.int64)
        self._next_id = 0
        self._frames = 0
        self._time_ns: int | None = None
        self._frame: str | None = None
        self._r = np.diag(np.square(np.asarray(self.config.measurement_sigma, dtype=float)))

    def __call__(self, detections: Detections) -> Tracks:
        """Predicts to the detections' time, assigns, updates, starts and ends tracks; returns the reported tracks."""
        frame = detections.boxes.frame
        if self._frame is not None and frame != self._frame:
            raise InputError(f"tracker: expected detections in {self._frame!r}, got {frame!r}")
        self._frame = frame
        t = int(detections.timestamp_ns)
        if self._time_ns is not None and t < self._time_ns:
            raise InputError(f"tracker: expected non-decreasing times, got {t} after {self._time_ns}")
        dt = 0.0 if self._time_ns is None else (t - self._time_ns) * 1e-9
        self._time_ns = t
        self._frames += 1
        self._predict(dt)
        det_z = np.c_[detections.boxes.center, detections.boxes.yaw(), detections.boxes.size_lwh]
        det_cls = np.asarray(detections.boxes.classes if detections.boxes.classes is not None else [], dtype=str)
        rows, cols = self._assign(det_z, det_cls)
        self._update(rows, det_z[cols], detections.scores[cols])
        self._since_update += 1
        self._since_update[rows] = 0
        unmatched = np.setdiff1d(np.arange(len(det_z)), cols)
        self._birth(det_z[unmatched], det_cls[unmatched], detections.scores[unmatched])
        alive = self._since_update <= self.config.max_age
        self._keep(alive)
        return self._report(frame, t)

    def _predict(self, dt: float) -> None:
        if not len(self._x) or dt == 0.0:
            return
        f = np.eye(10)
        f[0, 7] = f[1, 8] = f[2, 9] = dt
        q = np.zeros((10, 10))
        a2 = self.config.accel_sigma_mps2**2
        for i, v in ((0, 7), (1, 8), (2, 9)):  # white-acceleration block per axis
            q[i, i], q[i, v], q[v, i], q[v, v] = a2 * dt**4 / 4, a2 * dt**3 / 2, a2 * dt**3 / 2, a2 * dt**2
        self._x = self._x @ f.T
        self._p = f @ self._p @ f.T + q

    def _assign(self, det_z: np.ndarray, det_cls: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        empty = np.zeros(0, dtype=np.int64)
        if not len(self._x) or not len(det_z):
            return empty, empty
        dist = np.hypot(self._x[:, None, 0] - det_z[None, :, 0], self._x[:, None, 1] - det_z[None, :, 1])
        gate = np.array([self.config.gate_m.get(c, self.config.gate_m["*"]) for c in det_cls.tolist()])
        allowed = (self._classes[:, None] == det_cls[None, :]) & (dist <= gate[None, :])
        if not allowed.any():
            return empty, empty
        cost = np.where(allowed, dist, 1e6)
        rows, cols = linear_sum_assignment(cost)
        ok = allowed[rows, cols]
        return rows[ok].astype(np.int64), cols[ok].astype(np.int64)

    def _update(self, rows: np.ndarray, z: np.ndarray, scores: np.ndarray) -> None:
        if not len(rows):
            return
        x, p = self._x[rows], self._p[rows]
        z = z.copy()
        # Bring each detection's heading within 90 degrees of the track's (a box is symmetric under a half turn).
        diff = _wrap(z[:, 3] - x[:, 3])
        flip = np.abs(diff) > np.pi / 2
        z[flip, 3] = _wrap(z[flip, 3] + np.pi)
        innovation = z - x[:, :7]
        innovation[:, 3] = _wrap(innovation[:, 3])
        s = _H @ p @ _H.T + self._r
        k = p @ _H.T @ np.linalg.inv(s)
        x = x + np.einsum("nij,nj->ni", k, innovation)
        x[:, 3] = _wrap(x[:, 3])
        p = (np.eye(10) - k @ _H) @ p
        self._x[rows], self._p[rows] = x, p
        self._hits[rows] += 1
        self._scores[rows] = scores

    def _birth(self, z: np.ndarray, classes: np.ndarray, scores: np.ndarray) -> None:
        n = len(z)
        if not n:
            return
        x = np.c_[z, np.zeros((n, 3))]
        p0 = np.diag(np.r_[np.square(self.config.measurement_sigma), np.full(3, self.config.initial_velocity_sigma_mps**2)])
        self._x = np.r_[self._x, x]
        self._p = np.r_[self._p, np.broadcast_to(p0, (n, 10, 10))]
        self._ids = np.r_[self._ids, np.arange(self._next_id, self._next_id + n)]
        self._next_id += n
        self._classes = np.r_[self._classes.astype(object), classes.astype(object)].astype(str)
        self._scores = np.r_[self._scores, scores]
        self._hits = np.r_[self._hits, np.ones(n, dtype=np.int64)]
        self._since_update = np.r_[self._since_update, np.zeros(n, dtype=np.int64)]

    def _keep(self, mask: np.ndarray) -> None:
        self._x, self._p, self._ids = self._x[mask], self._p[mask], self._ids[mask]
        self._classes, self._scores = self._classes[mask], self._scores[mask]
        self._hits, self._since_update = self._hits[mask], self._since_update[mask]

    def _report(self, frame: str, t: int) -> Tracks:
        confirmed = (self._hits >= self.config.min_hits) | (self._frames <= self.config.min_hits)
        shown = confirmed & (self._since_update <= self.config.max_coast_frames)
        x = self._x[shown]
        boxes = Boxes3D.from_yaw(x[:, 0:3], np.maximum(x[:, 4:7], 0.0), x[:, 3], frame, ids=self._ids[shown].astype(str),
                                 classes=self._classes[shown], velocity=x[:, 7:10])
        return Tracks(boxes=boxes, scores=self._scores[shown].copy(), timestamp_ns=t)


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2.0 * np.pi) - np.pi
