"""A 3D multi-object tracker after AB3DMOT (Weng et al., IROS 2020): Kalman filter, per-class association.

State of a track (10): centre x, y, z, heading yaw, length, width, height, and velocity vx, vy, vz, all in
the detections' frame (a fixed frame such as ``world``; in a moving sensor frame the constant-velocity model
is wrong by the frame's own motion, as in AB3DMOT without ego-motion compensation). Boxes must be upright
about +z of that frame (within ``upright_tolerance_rad``; a y-down camera frame is refused with one line).
Per frame (dt from the detection times):

1. predict: x' = F x (F adds v dt to the centre), P' = F P F^T + Q with Q = diag(process_sigma^2) * dt: a
   random walk on centre, heading, size and velocity (AB3DMOT's Q = I per frame; heading and size noise is
   what lets the filter follow the detector instead of lagging it). Every track's ``since_update`` grows by 1;
2. associate, per class: similarity between predicted tracks and detections of that class: ``giou_3d``
   (3D generalised IoU, BEV polygons and their convex hull times the height overlap), ``iou_3d`` or
   ``dist_3d`` (negative centre distance); ``hungarian`` (``linear_sum_assignment``) or ``greedy`` (best
   pair first) matching; pairs below the class's threshold stay unmatched;
3. update: if the detection's heading opposes the track's by more than 90 degrees, the *track's* heading is
   turned by pi first (AB3DMOT's orientation correction: a detector's flipped box flips the track instead
   of spinning it), then the Kalman update with z = (x, y, z, yaw, l, w, h); ``since_update = 0``;
4. birth: every unmatched detection starts a track with one hit;
5. report a track when ``since_update < max_age`` and (``hits >= min_hits`` or the sequence is at most
   ``min_hits`` frames old), then remove tracks with ``since_update >= max_age`` (AB3DMOT's semantics:
   ``max_age=2`` shows a track one frame after its last detection, at its predicted box).

The default :class:`TrackerConfig` is AB3DMOT's KITTI configuration for PointRCNN detections (car: Hungarian,
GIoU >= -0.2, min_hits 3, max_age 2; pedestrian: greedy, GIoU >= -0.4, 1, 4; cyclist: Hungarian, distance
<= 2 m, 3, 4), with AB3DMOT's filter matrices at KITTI's 10 Hz (P0 = 10 on the box, 10^4 (m/frame)^2 on the
velocity; Q = 1 per frame on the box, 0.01 (m/frame)^2 on the velocity; R = I). On AB3DMOT's PointRCNN files of
KITTI val 0001, 0006 and 0008 it reports the boxes, tracks, 2D boxes and scores AB3DMOT's own code reports; only
the height of a box's bottom differs a little, as AB3DMOT filters the bottom of the box and this filter its centre.

A track's score is the mean score of the detections that updated it. :class:`Tracks` says which detection
of the frame updated each track (``detection_index``, -1 when it coasted) and carries that detection's
``extras`` (for a coasting track, its last detection's), so a KITTI result keeps the detector's 2D box.

Any callable ``(Detections) -> Tracks`` is a :class:`Tracker`: studies and examples accept a user's own.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from scipy.optimize import linear_sum_assignment

from avdata.errors import InputError, shown
from avdata.eval.geometry import bev_corners, bev_intersection_area, box3d_iou
from avdata.frames import Boxes3D
from avdata.perception.detections import Detections
from avdata.perception.detector import load_callable

__all__ = ["ClassConfig", "KalmanTracker", "Tracker", "TrackerConfig", "Tracks", "checked_tracks", "giou_3d", "load_tracker"]


@dataclass(frozen=True, slots=True, kw_only=True)
class Tracks:
    """The tracker's output at one time.

    Attributes:
        boxes: N track boxes; ``ids`` are the track ids, ``classes`` set, ``velocity`` (N, 3) in m/s.
        scores: (N,) confidence of each track (mean score of its detections, in [0, 1]).
        timestamp_ns: the time of the estimate.
        detection_index: (N,) index of the frame's detection that updated each track, -1 if it coasted.
        extras: the ``Detections.extras`` columns of each track's last detection (N rows each).
    """

    boxes: Boxes3D
    scores: np.ndarray
    timestamp_ns: int
    detection_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    extras: dict[str, np.ndarray] = field(default_factory=dict)


class Tracker(Protocol):
    """Anything that turns one frame's detections into the current tracks (called once per frame, in order)."""

    def __call__(self, detections: Detections) -> Tracks:
        """The tracks after this frame's detections (detections in a fixed frame, times non-decreasing)."""
        ...


#: Largest min_hits and max_age: the counters are int64 arrays, and a longer sequence is a typing slip.
MAX_FRAMES = 1_000_000


def _is_integer(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)  # YAML's true is an int to Python


def _is_finite(value: object) -> bool:
    """A number a float64 holds: not YAML's true, a string, a list, nan, inf or an integer of 400 digits."""
    return isinstance(value, int | float) and not isinstance(value, bool) and abs(value) <= sys.float_info.max


#: metric -> the thresholds it can reach: GIoU in [-1, 1], IoU in [0, 1], a distance >= 0 (a GIoU threshold of 2.5
#: never matched, so every detection started a track).
_THRESHOLDS = {"giou_3d": (-1.0, 1.0), "iou_3d": (0.0, 1.0), "dist_3d": (0.0, np.inf)}
_METRICS = tuple(_THRESHOLDS)
_ALGORITHMS = ("hungarian", "greedy")


@dataclass(frozen=True, slots=True, kw_only=True)
class ClassConfig:
    """Association and life cycle of one class.

    Attributes:
        metric: ``giou_3d``, ``iou_3d`` or ``dist_3d``.
        threshold: least similarity of a match (GIoU/IoU), or largest centre distance in metres (``dist_3d``).
        algorithm: ``hungarian`` or ``greedy``.
        min_hits: updates before a track is reported (except in the sequence's first ``min_hits`` frames).
        max_age: a track is reported while ``since_update < max_age`` and removed at ``max_age``.
    """

    metric: str = "giou_3d"
    threshold: float = -0.2
    algorithm: str = "hungarian"
    min_hits: int = 3
    max_age: int = 2

    def __post_init__(self) -> None:
        if self.metric not in _METRICS or self.algorithm not in _ALGORITHMS:
            raise InputError(f"tracker: expected metric in {_METRICS} and algorithm in {_ALGORITHMS}, "
                             f"got {self.metric!r}, {self.algorithm!r}")
        # Checked by type, as a YAML config gives them: min_hits .nan was a ValueError traceback, threshold [1] or
        # true passed as 1.
        counts = (self.min_hits, self.max_age)
        if not all(_is_integer(n) and 1 <= n <= MAX_FRAMES for n in counts) or not _is_finite(self.threshold):
            raise InputError(f"tracker: expected integers min_hits, max_age in [1, {MAX_FRAMES}] and a finite number "
                             f"threshold, got {shown(self.min_hits)}, {shown(self.max_age)}, {shown(self.threshold)}")
        low, high = _THRESHOLDS[self.metric]
        if not low <= self.threshold <= high:
            raise InputError(f"tracker: expected the {self.metric} threshold in [{low:g}, {high:g}], got {self.threshold!r}")


def _ab3dmot_kitti() -> dict[str, ClassConfig]:
    return {"car": ClassConfig(metric="giou_3d", threshold=-0.2, algorithm="hungarian", min_hits=3, max_age=2),
            "pedestrian": ClassConfig(metric="giou_3d", threshold=-0.4, algorithm="greedy", min_hits=1, max_age=4),
            "cyclist": ClassConfig(metric="dist_3d", threshold=2.0, algorithm="hungarian", min_hits=3, max_age=4),
            "*": ClassConfig()}


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackerConfig:
    """Parameters of :class:`KalmanTracker` (defaults: AB3DMOT's KITTI configuration, see the module docstring).

    Attributes:
        classes: class -> :class:`ClassConfig`; ``"*"`` for every other class.
        process_sigma: random-walk standard deviations per square-root second of (x, y, z, yaw, l, w, h, vx, vy, vz)
            in metres, radians and m/s (AB3DMOT's Q at 10 Hz: sqrt(10) on the box, sqrt(10) m/s on the velocity).
        measurement_sigma: standard deviations of the measured (x, y, z, yaw, l, w, h).
        initial_sigma: prior standard deviations of a new track's (x, y, z, yaw, l, w, h, vx, vy, vz).
        upright_tolerance_rad: largest angle between a box's z axis and the frame's +z: a y-down camera frame (90
            degrees) is refused; a smaller tilt (a slope, a pitched sensor's noise) is dropped, keeping the yaw.
    """

    classes: dict[str, ClassConfig] = field(default_factory=_ab3dmot_kitti)
    process_sigma: tuple[float, ...] = (10**0.5,) * 10
    measurement_sigma: tuple[float, ...] = (1.0,) * 7
    initial_sigma: tuple[float, ...] = (10**0.5,) * 7 + (1000.0,) * 3
    upright_tolerance_rad: float = np.pi / 4

    def __post_init__(self) -> None:
        for name, size in (("process_sigma", 10), ("measurement_sigma", 7), ("initial_sigma", 10)):
            values = getattr(self, name)
            if not isinstance(values, tuple) or len(values) != size or not all(_is_finite(v) and v > 0 for v in values):
                raise InputError(f"tracker: expected {size} positive {name}, got {shown(values)}")
        # At 90 degrees and beyond a y-down camera frame would pass; nan passed any tilt.
        if not (_is_finite(self.upright_tolerance_rad) and 0 <= self.upright_tolerance_rad < np.pi / 2):
            raise InputError(f"tracker: expected upright_tolerance_rad in [0, pi/2), got {shown(self.upright_tolerance_rad)}")
        if "*" not in self.classes:
            raise InputError(f"tracker: expected a default class '*' in classes, got {sorted(self.classes)}")

    def of(self, cls: str) -> ClassConfig:
        """The configuration of class ``cls``."""
        return self.classes.get(cls, self.classes["*"])


def load_tracker(spec: str, what: str, config: TrackerConfig | None = None) -> Tracker:
    """A fresh tracker: ``kalman`` (with ``config``) or what the factory ``"pkg.mod:fn"`` returns, called with nothing.

    ``what`` names the setting in messages (``--tracker``, ``case C1: tracker``).
    """
    if spec == "kalman":
        return KalmanTracker(config)
    tracker = load_callable(spec, what)()
    if not callable(tracker):  # os:getcwd returned a string, called on the first frame: a TypeError traceback
        raise InputError(f"{what}: expected {spec!r} to return a callable tracker, got {type(tracker).__name__}")
    checked: Tracker = tracker
    return checked


def checked_tracks(tracks: object, what: str) -> Tracks:
    """``tracks`` if a user's tracker returned :class:`Tracks`, else one line naming the setting ``what``."""
    if not isinstance(tracks, Tracks):
        raise InputError(f"{what}: expected the tracker to return Tracks, got {type(tracks).__name__}")
    return tracks


_H = np.hstack([np.eye(7), np.zeros((7, 3))])


class KalmanTracker:
    """The tracker of the module docstring; one instance per sequence.

    Args:
        config: parameters.
    """

    def __init__(self, config: TrackerConfig | None = None):
        self.config = config or TrackerConfig()
        self._x = np.zeros((0, 10))
        self._p = np.zeros((0, 10, 10))
        self._ids = np.zeros(0, dtype=np.int64)
        self._classes = np.zeros(0, dtype=str)
        self._score_sum = np.zeros(0)
        self._hits = np.zeros(0, dtype=np.int64)
        self._since_update = np.zeros(0, dtype=np.int64)
        self._extras: dict[str, np.ndarray] = {}
        self._extra_keys: set[str] | None = None  # fixed by the first frame
        self._next_id = 0
        self._frames = 0
        self._time_ns: int | None = None
        self._frame: str | None = None
        self._r = np.diag(np.square(np.asarray(self.config.measurement_sigma, dtype=float)))

    def __call__(self, detections: Detections) -> Tracks:
        """Predicts to the detections' time, associates, updates, starts and ends tracks; returns the reported tracks."""
        frame = detections.boxes.frame
        if self._frame is not None and frame != self._frame:
            raise InputError(f"tracker: expected detections in {self._frame!r}, got {frame!r}")
        _check_upright(detections.boxes, self.config.upright_tolerance_rad)
        self._frame = frame
        t = int(detections.timestamp_ns)
        if self._time_ns is not None and t < self._time_ns:
            raise InputError(f"tracker: expected non-decreasing times, got {t} after {self._time_ns}")
        dt = 0.0 if self._time_ns is None else (t - self._time_ns) * 1e-9
        self._time_ns = t
        self._frames += 1
        extras = {key: np.asarray(value) for key, value in detections.extras.items()}
        if self._extra_keys is None:
            self._extra_keys = set(extras)
            self._extras = {key: value[:0] for key, value in extras.items()}
        elif self._extra_keys != set(extras):
            raise InputError(f"tracker: expected detection extras {sorted(self._extra_keys)}, got {sorted(extras)}")
        self._predict(dt)
        det_z = np.c_[detections.boxes.center, detections.boxes.yaw(), detections.boxes.size_lwh]
        det_cls = np.asarray(detections.boxes.classes if detections.boxes.classes is not None else [], dtype=str)
        rows, cols = self._associate(det_z, det_cls)
        self._update(rows, det_z[cols], detections.scores[cols], {k: v[cols] for k, v in extras.items()})
        matched_det = np.full(len(self._x), -1, dtype=np.int64)
        matched_det[rows] = cols
        unmatched = np.setdiff1d(np.arange(len(det_z)), cols)
        self._birth(det_z[unmatched], det_cls[unmatched], detections.scores[unmatched],
                    {k: v[unmatched] for k, v in extras.items()})
        matched_det = np.r_[matched_det, unmatched]
        tracks = self._report(frame, t, matched_det)
        max_age = np.array([self.config.of(c).max_age for c in self._classes.tolist()], dtype=np.int64)
        self._keep(self._since_update < max_age)
        return tracks

    def _predict(self, dt: float) -> None:
        self._since_update += 1
        if not len(self._x) or dt == 0.0:
            return
        f = np.eye(10)
        f[0, 7] = f[1, 8] = f[2, 9] = dt
        q = np.diag(np.square(self.config.process_sigma)) * dt
        self._x = self._x @ f.T
        self._x[:, 3] = _wrap(self._x[:, 3])
        self._p = f @ self._p @ f.T + q

    def _associate(self, det_z: np.ndarray, det_cls: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rows_all, cols_all = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)]
        for cls in np.intersect1d(self._classes, det_cls).tolist():
            config = self.config.of(cls)
            trk = np.flatnonzero(self._classes == cls)
            det = np.flatnonzero(det_cls == cls)
            sim = similarity(self._x[trk, :7], det_z[det], config.metric)
            threshold = -config.threshold if config.metric == "dist_3d" else config.threshold
            if config.algorithm == "hungarian":
                r, c = linear_sum_assignment(-sim)
            else:
                r, c = _greedy(sim)
            ok = sim[r, c] >= threshold
            rows_all.append(trk[r[ok]])
            cols_all.append(det[c[ok]])
        return np.concatenate(rows_all).astype(np.int64), np.concatenate(cols_all).astype(np.int64)

    def _update(self, rows: np.ndarray, z: np.ndarray, scores: np.ndarray, extras: dict[str, np.ndarray]) -> None:
        self._since_update[rows] = 0
        if not len(rows):
            return
        x, p = self._x[rows], self._p[rows]
        # AB3DMOT's orientation correction: turn the *track* by pi when the detection opposes it.
        flip = np.abs(_wrap(z[:, 3] - x[:, 3])) > np.pi / 2
        x[flip, 3] = _wrap(x[flip, 3] + np.pi)
        innovation = z - x[:, :7]
        innovation[:, 3] = _wrap(innovation[:, 3])
        s = _H @ p @ _H.T + self._r
        k = p @ _H.T @ np.linalg.inv(s)
        x = x + np.einsum("nij,nj->ni", k, innovation)
        x[:, 3] = _wrap(x[:, 3])
        p = (np.eye(10) - k @ _H) @ p
        self._x[rows], self._p[rows] = x, p
        self._hits[rows] += 1
        self._score_sum[rows] += scores
        for key, value in extras.items():
            self._extras[key][rows] = value

    def _birth(self, z: np.ndarray, classes: np.ndarray, scores: np.ndarray, extras: dict[str, np.ndarray]) -> None:
        n = len(z)
        p0 = np.diag(np.square(self.config.initial_sigma))
        self._x = np.r_[self._x, np.c_[z, np.zeros((n, 3))]]
        self._p = np.r_[self._p, np.broadcast_to(p0, (n, 10, 10))]
        self._ids = np.r_[self._ids, np.arange(self._next_id, self._next_id + n)]
        self._next_id += n
        self._classes = np.r_[self._classes.astype(object), classes.astype(object)].astype(str)
        self._score_sum = np.r_[self._score_sum, scores]
        self._hits = np.r_[self._hits, np.ones(n, dtype=np.int64)]
        self._since_update = np.r_[self._since_update, np.zeros(n, dtype=np.int64)]
        for key, value in extras.items():
            self._extras[key] = np.concatenate([self._extras[key], value])

    def _keep(self, mask: np.ndarray) -> None:
        self._x, self._p, self._ids = self._x[mask], self._p[mask], self._ids[mask]
        self._classes, self._score_sum = self._classes[mask], self._score_sum[mask]
        self._hits, self._since_update = self._hits[mask], self._since_update[mask]
        self._extras = {key: value[mask] for key, value in self._extras.items()}

    def _report(self, frame: str, t: int, matched_det: np.ndarray) -> Tracks:
        min_hits = np.array([self.config.of(c).min_hits for c in self._classes.tolist()], dtype=np.int64)
        max_age = np.array([self.config.of(c).max_age for c in self._classes.tolist()], dtype=np.int64)
        shown = (self._since_update < max_age) & ((self._hits >= min_hits) | (self._frames <= min_hits))
        x = self._x[shown]
        boxes = Boxes3D.from_yaw(x[:, 0:3], np.maximum(x[:, 4:7], 0.0), x[:, 3], frame, ids=self._ids[shown].astype(str),
                                 classes=self._classes[shown], velocity=x[:, 7:10])
        return Tracks(boxes=boxes, scores=self._score_sum[shown] / self._hits[shown], timestamp_ns=t,
                      detection_index=matched_det[shown], extras={k: v[shown] for k, v in self._extras.items()})


def similarity(boxes_a: np.ndarray, boxes_b: np.ndarray, metric: str) -> np.ndarray:
    """(N, M) similarity of rows ``(x, y, z, yaw, l, w, h)``: ``giou_3d``, ``iou_3d`` or ``dist_3d`` (negated)."""
    if metric == "dist_3d":
        negative_distance: np.ndarray = -np.linalg.norm(boxes_a[:, None, :3] - boxes_b[None, :, :3], axis=2)
        return negative_distance
    a, b = boxes_a[:, [0, 1, 2, 4, 5, 6, 3]], boxes_b[:, [0, 1, 2, 4, 5, 6, 3]]
    return giou_3d(a, b) if metric == "giou_3d" else box3d_iou(a, b)


def giou_3d(boxes_a: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    """(N, M) 3D generalised IoU of rows ``(x, y, z, l, w, h, yaw)`` (z the centre), as AB3DMOT defines it.

    GIoU = IoU - (C - U) / C with U the union volume and C the volume of the convex hull of both BEV
    rectangles times the height range spanned by both boxes.
    """
    if not len(boxes_a) or not len(boxes_b):
        return np.zeros((len(boxes_a), len(boxes_b)))
    bev_a, bev_b = boxes_a[:, [0, 1, 3, 4, 6]], boxes_b[:, [0, 1, 3, 4, 6]]
    inter_bev = bev_intersection_area(bev_a, bev_b)
    top = np.minimum((boxes_a[:, 2] + boxes_a[:, 5] / 2)[:, None], (boxes_b[:, 2] + boxes_b[:, 5] / 2)[None])
    bottom = np.maximum((boxes_a[:, 2] - boxes_a[:, 5] / 2)[:, None], (boxes_b[:, 2] - boxes_b[:, 5] / 2)[None])
    inter = inter_bev * np.clip(top - bottom, 0.0, None)
    vol_a = np.prod(boxes_a[:, 3:6], axis=1)[:, None]
    vol_b = np.prod(boxes_b[:, 3:6], axis=1)[None]
    union = vol_a + vol_b - inter
    span_top = np.maximum((boxes_a[:, 2] + boxes_a[:, 5] / 2)[:, None], (boxes_b[:, 2] + boxes_b[:, 5] / 2)[None])
    span_bottom = np.minimum((boxes_a[:, 2] - boxes_a[:, 5] / 2)[:, None], (boxes_b[:, 2] - boxes_b[:, 5] / 2)[None])
    origin = bev_a[:, None, None, 0:2]  # relative to each row's centre, for well-conditioned cross products
    points = np.concatenate([np.broadcast_to(bev_corners(bev_a)[:, None], (len(bev_a), len(bev_b), 4, 2)),
                             np.broadcast_to(bev_corners(bev_b)[None], (len(bev_a), len(bev_b), 4, 2))], axis=2)
    hull = _hull_area(points - origin) * (span_top - span_bottom)
    # Zero-volume boxes (a detector's zero width) overlap nothing: IoU 0 as box3d_iou has it, and no hull term where
    # the hull is flat. 0 / 0 was a NaN that linear_sum_assignment refused with a traceback.
    iou = np.divide(inter, union, out=np.zeros_like(union), where=union > 0)
    giou: np.ndarray = iou - np.divide(hull - union, hull, out=np.zeros_like(hull), where=hull > 0)
    return giou


def _hull_area(points: np.ndarray) -> np.ndarray:
    """Area of the convex hull of (..., K, 2) points: the sum over hull edges i -> j of cross(p_i, p_j) / 2.

    i -> j is a hull edge when every point lies left of it or on its closed segment (a collinear point
    beyond the segment means a longer edge exists); repeated points count once.
    """
    k = points.shape[-2]
    pi, pj = points[..., :, None, None, :], points[..., None, :, None, :]
    pk = points[..., None, None, :, :]
    edge, rel = pj - pi, pk - pi
    cross = edge[..., 0] * rel[..., 1] - edge[..., 1] * rel[..., 0]
    scale = np.max(np.abs(points), axis=(-1, -2))[..., None, None, None] ** 2
    eps = 1e-9 * np.maximum(scale, 1.0)
    along = np.einsum("...d,...d->...", edge, rel)
    length2 = np.einsum("...d,...d->...", edge, edge)
    on_segment = (np.abs(cross) <= eps) & (along >= -eps) & (along <= length2 + eps)
    is_edge = np.all((cross > eps) | on_segment, axis=-1)
    same = np.all(np.abs(points[..., :, None, :] - points[..., None, :, :]) <= 1e-12, axis=-1)
    first = ~np.any(same & np.tril(np.ones((k, k), dtype=bool), -1), axis=-1)
    is_edge &= first[..., :, None] & first[..., None, :] & (length2[..., 0] > 0)
    pair_cross = pi[..., 0, 0] * pj[..., 0, 1] - pi[..., 0, 1] * pj[..., 0, 0]
    area: np.ndarray = 0.5 * np.sum(np.where(is_edge, pair_cross, 0.0), axis=(-1, -2))
    return area


def _greedy(similarity_matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pairs taken best first, each row and column once (AB3DMOT's greedy matching)."""
    order = np.argsort(-similarity_matrix, axis=None, kind="stable")
    rows, cols = np.unravel_index(order, similarity_matrix.shape)
    used_r, used_c = np.zeros(similarity_matrix.shape[0], bool), np.zeros(similarity_matrix.shape[1], bool)
    out_r, out_c = [], []
    for r, c in zip(rows.tolist(), cols.tolist(), strict=True):
        if not used_r[r] and not used_c[c]:
            used_r[r] = used_c[c] = True
            out_r.append(r)
            out_c.append(c)
    return np.array(out_r, dtype=np.int64), np.array(out_c, dtype=np.int64)


def _check_upright(boxes: Boxes3D, tolerance_rad: float) -> None:
    if not len(boxes):
        return
    up_z = boxes.rotation_matrix()[:, 2, 2]
    tilt = np.arccos(np.clip(up_z, -1.0, 1.0))
    if np.any(tilt > tolerance_rad):
        worst = float(np.degrees(tilt.max()))
        raise InputError(f"tracker: expected boxes upright about +z of {boxes.frame!r}, got one tilted by {worst:.1f} "
                         "degrees (a y-down camera frame? use avdata.perception.detection_files.upright)")


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2.0 * np.pi) - np.pi
