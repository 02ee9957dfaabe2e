"""Simulated 3D detections from ground truth and a sensor's visibility labels.

A sensor detects an object it could see (in its field of view with at least ``min_points`` lidar returns,
from the visibility labels), unless a miss is drawn with the probability of the object's occlusion level;
every detection is the true box with noise applied *in the sensor frame*, because that is where a
detector's errors live (they grow with range from the sensor, not from the world origin):

    centre_sensor += N(0, diag(s_xy, s_xy, s_z)^2) * g(r),   g(r) = 1 + growth_per_m * r
    size_lwh      *= 1 + N(0, s_size^2) * g(r)              (clipped at 10 % of the true size)
    yaw           += N(0, s_yaw^2) * g(r)                   (about the sensor-frame z of the box)
    score          = clip(N(0.85, 0.05), 0, 1) for true positives

with r the distance of the box centre from the sensor origin. False positives are a Poisson number per
sensor and frame, placed uniformly in the sensor's horizontal field of view and range on the ground plane
of the true objects, with car-like sizes and scores uniform with mean 0.45 and standard deviation 0.1.
Everything is drawn from a generator seeded
by (seed, frame index, sensor index), so the same inputs give the same detections on any executor.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace

import numpy as np

from avdata.errors import InputError
from avdata.frames import Boxes3D, Transform

__all__ = ["NOISE_LEVELS", "DetectionSimulator", "Detections", "NoiseModel", "rng_for"]


@dataclass(frozen=True, slots=True, kw_only=True)
class Detections:
    """The detections of one frame, in one reference frame.

    Attributes:
        boxes: N boxes with ``classes`` set (ids are None: a detector does not know object identities).
        scores: (N,) confidence in [0, 1] (checked; a detector's logit is turned into [0, 1] by its reader,
            which keeps the raw value in ``extras["score_raw"]``).
        sensors: (N,) name of the sensor frame each detection came from.
        timestamp_ns: the time the detections describe (the sensor's measurement time).
        extras: source-specific per-detection columns, each with N rows, carried through ``select``, ``to``
            and ``concatenate`` (e.g. ``box2d_px`` (N, 4) x1, y1, x2, y2 of a KITTI result, ``score_raw``).
    """

    boxes: Boxes3D
    scores: np.ndarray
    sensors: np.ndarray
    timestamp_ns: int
    extras: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.boxes)
        if self.boxes.classes is None and n:
            raise InputError("detections: expected boxes with classes, got none")
        for name in ("scores", "sensors"):
            value = np.asarray(getattr(self, name))
            if value.shape != (n,):
                raise InputError(f"detections: expected {n} {name}, got shape {value.shape}")
            object.__setattr__(self, name, value)
        if n and not np.all((self.scores >= 0.0) & (self.scores <= 1.0)):
            bad = self.scores[~((self.scores >= 0.0) & (self.scores <= 1.0))][0]
            raise InputError(f"detections: expected scores in [0, 1], got {bad!r} (declare a logit to its reader)")
        for key, value in self.extras.items():
            if len(np.asarray(value)) != n:
                raise InputError(f"detections: expected {n} rows of extra {key!r}, got {len(np.asarray(value))}")

    @classmethod
    def empty(cls, frame: str, timestamp_ns: int) -> Detections:
        """No detections, in ``frame``."""
        boxes = replace(Boxes3D.empty(frame), classes=np.zeros(0, dtype=str))
        return cls(boxes=boxes, scores=np.zeros(0), sensors=np.zeros(0, dtype=str), timestamp_ns=timestamp_ns)

    def __len__(self) -> int:
        return len(self.boxes)

    def select(self, index: np.ndarray) -> Detections:
        """The detections at ``index`` (indices or a boolean mask)."""
        return replace(self, boxes=self.boxes[index], scores=self.scores[index], sensors=self.sensors[index],
                       extras={key: np.asarray(value)[index] for key, value in self.extras.items()})

    def to(self, target_frame: str, target_T_frame: Transform) -> Detections:
        """The same detections expressed in ``target_frame``."""
        return replace(self, boxes=self.boxes.transform(target_T_frame, target_frame))

    @classmethod
    def concatenate(cls, parts: list[Detections], frame: str, timestamp_ns: int) -> Detections:
        """All detections of ``parts`` (each already in ``frame``) as one set stamped ``timestamp_ns``."""
        parts = [p for p in parts if len(p)]
        if not parts:
            return cls.empty(frame, timestamp_ns)
        if any(p.boxes.frame != frame for p in parts):
            raise InputError(f"detections: expected every part in {frame!r}, got {sorted({p.boxes.frame for p in parts})}")
        keys = set(parts[0].extras)
        if any(set(p.extras) != keys for p in parts):
            raise InputError(f"detections: expected the same extras in every part, got {[sorted(p.extras) for p in parts]}")
        extras = {key: np.concatenate([np.asarray(p.extras[key]) for p in parts]) for key in sorted(keys)}
        return cls(boxes=Boxes3D.concatenate([p.boxes for p in parts]), scores=np.concatenate([p.scores for p in parts]),
                   sensors=np.concatenate([p.sensors for p in parts]), timestamp_ns=timestamp_ns, extras=extras)


@dataclass(frozen=True, slots=True, kw_only=True)
class NoiseModel:
    """How far simulated detections are from the truth (see the module docstring for the formulas).

    Attributes:
        centre_xy_sigma_m: standard deviation of the centre along the sensor's x and y, at the sensor.
        centre_z_sigma_m: standard deviation of the centre along the sensor's z.
        size_sigma: relative standard deviation of each box dimension.
        yaw_sigma_rad: standard deviation of the heading.
        growth_per_m: every sigma grows by this fraction per metre of range from the sensor.
        miss_probability: probability of missing a seen object, by occlusion level 0, 1, 2, 3.
        false_positives_per_frame: mean number (Poisson) of false detections per sensor and frame.
    """

    centre_xy_sigma_m: float = 0.0
    centre_z_sigma_m: float = 0.0
    size_sigma: float = 0.0
    yaw_sigma_rad: float = 0.0
    growth_per_m: float = 0.0
    miss_probability: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    false_positives_per_frame: float = 0.0

    def __post_init__(self) -> None:
        values = {"centre_xy_sigma_m": self.centre_xy_sigma_m, "centre_z_sigma_m": self.centre_z_sigma_m,
                  "size_sigma": self.size_sigma, "yaw_sigma_rad": self.yaw_sigma_rad, "growth_per_m": self.growth_per_m,
                  "false_positives_per_frame": self.false_positives_per_frame}
        for name, value in values.items():
            if not np.isfinite(value) or value < 0:
                raise InputError(f"noise model: expected {name} >= 0, got {value!r}")
        miss = tuple(float(p) for p in self.miss_probability)
        if len(miss) != 4 or not all(0.0 <= p <= 1.0 for p in miss):
            raise InputError(f"noise model: expected 4 miss probabilities in [0, 1], got {self.miss_probability!r}")
        object.__setattr__(self, "miss_probability", miss)


#: Named noise levels of the studies. "none" is a perfect detector of what the sensor saw.
NOISE_LEVELS: dict[str, NoiseModel] = {
    "none": NoiseModel(),
    "low": NoiseModel(centre_xy_sigma_m=0.10, centre_z_sigma_m=0.05, size_sigma=0.02, yaw_sigma_rad=0.02,
                      growth_per_m=0.005, miss_probability=(0.02, 0.05, 0.20, 0.50), false_positives_per_frame=0.1),
    "med": NoiseModel(centre_xy_sigma_m=0.30, centre_z_sigma_m=0.10, size_sigma=0.05, yaw_sigma_rad=0.05,
                      growth_per_m=0.01, miss_probability=(0.05, 0.10, 0.30, 0.70), false_positives_per_frame=0.3),
    "high": NoiseModel(centre_xy_sigma_m=0.60, centre_z_sigma_m=0.20, size_sigma=0.10, yaw_sigma_rad=0.10,
                       growth_per_m=0.02, miss_probability=(0.10, 0.20, 0.50, 0.90), false_positives_per_frame=1.0),
}

_FP_SIZE_LWH = np.array([4.5, 1.9, 1.6])
_TP_SCORE = (0.85, 0.05)
_FP_SCORE = (0.45, 0.10)


def rng_for(seed: int, *keys: int | str) -> np.random.Generator:
    """A generator seeded by ``seed`` and ``keys``, the same on every machine and process (no Python hash)."""
    words = [int(seed) & 0xFFFFFFFF]
    for key in keys:
        if isinstance(key, str):
            words.append(int.from_bytes(hashlib.blake2b(key.encode(), digest_size=4).digest(), "little"))
        else:
            words.append(int(key) & 0xFFFFFFFF)
    return np.random.default_rng(words)


@dataclass(frozen=True, slots=True, kw_only=True)
class DetectionSimulator:
    """Detections of one sensor from ground truth and that sensor's visibility labels.

    Attributes:
        noise: the noise model.
        min_points: an object counts as seen with at least this many lidar returns in its box.
        max_range_m: false positives are placed within this distance of the sensor.
        horizontal_fov_deg: the sensor's horizontal field of view (false positives are placed in it).
    """

    noise: NoiseModel
    min_points: int = 1
    max_range_m: float = 100.0
    horizontal_fov_deg: float = 360.0

    def detect(
        self,
        gt_world: Boxes3D,
        n_points: np.ndarray,
        occlusion: np.ndarray,
        world_T_sensor: Transform,
        sensor: str,
        timestamp_ns: int,
        rng: np.random.Generator,
    ) -> Detections:
        """Detections of the sensor, in the sensor frame.

        Args:
            gt_world: (N) ground-truth boxes in ``world`` with classes.
            n_points: (N,) lidar returns of this sensor in each box (0 where the sensor did not see it).
            occlusion: (N,) occlusion level 0-3 of each box seen from this sensor.
            world_T_sensor: pose of the sensor at ``timestamp_ns``.
            sensor: the sensor frame name (the detections' frame).
            timestamp_ns: measurement time.
            rng: the random generator (see :func:`rng_for`).

        Returns:
            Detections in ``sensor``.
        """
        n_points = np.asarray(n_points).reshape(-1)
        occlusion = np.clip(np.asarray(occlusion, dtype=np.int64).reshape(-1), 0, 3)
        if n_points.shape[0] != len(gt_world) or occlusion.shape[0] != len(gt_world):
            raise InputError(f"{sensor}: expected {len(gt_world)} visibility values, "
                             f"got {n_points.shape[0]} and {occlusion.shape[0]}")
        sensor_T_world = world_T_sensor.inverse()
        truth = gt_world.transform(sensor_T_world, sensor)
        range_m = np.linalg.norm(truth.center, axis=1)
        # One uniform draw per object whatever the outcome, so a change of one object's visibility never
        # shifts the random stream of the others.
        u_miss = rng.random(len(truth))
        seen = n_points >= self.min_points  # the visibility labels already carry the sensor's range
        keep = seen & (u_miss >= np.asarray(self.noise.miss_probability)[occlusion])
        noise_draws = rng.standard_normal((len(truth), 8))
        idx = np.flatnonzero(keep)
        true_boxes = truth[idx]
        scale = 1.0 + self.noise.growth_per_m * range_m[idx]
        z = noise_draws[idx]
        sigma_c = np.array([self.noise.centre_xy_sigma_m, self.noise.centre_xy_sigma_m, self.noise.centre_z_sigma_m])
        centre = true_boxes.center + z[:, 0:3] * sigma_c * scale[:, None]
        size = true_boxes.size_lwh * np.clip(1.0 + z[:, 3:6] * self.noise.size_sigma * scale[:, None], 0.1, None)
        dyaw = z[:, 6] * self.noise.yaw_sigma_rad * scale
        # Heading noise turns the box about the sensor frame's z axis: q' = q_z(dyaw) * q.
        rotation = _rot_z(dyaw) @ true_boxes.rotation_matrix()
        scores = np.clip(_TP_SCORE[0] + _TP_SCORE[1] * z[:, 7], 0.0, 1.0)
        detected = Boxes3D.from_rotation(centre, size, rotation, sensor, classes=true_boxes.classes)
        fp = self._false_positives(truth, sensor, rng)
        boxes = Boxes3D.concatenate([detected, fp[0]]) if len(fp[0]) else detected
        all_scores = np.concatenate([scores, fp[1]])
        return Detections(boxes=boxes, scores=all_scores, sensors=np.full(len(boxes), sensor), timestamp_ns=timestamp_ns)

    def _false_positives(self, truth_sensor: Boxes3D, sensor: str, rng: np.random.Generator) -> tuple[Boxes3D, np.ndarray]:
        count = int(rng.poisson(self.noise.false_positives_per_frame)) if self.noise.false_positives_per_frame else 0
        draws = rng.random((count, 4))
        if count == 0:
            return replace(Boxes3D.empty(sensor), classes=np.zeros(0, dtype=str)), np.zeros(0)
        # Uniform in area over the annulus [5 m, max range] and the horizontal field of view.
        r_min, r_max = 5.0, self.max_range_m
        r = np.sqrt(r_min**2 + draws[:, 0] * (r_max**2 - r_min**2))
        half_fov = np.deg2rad(self.horizontal_fov_deg) / 2.0
        azimuth = (draws[:, 1] * 2.0 - 1.0) * half_fov
        # On the ground plane of the true objects (their median centre height in this frame), or the sensor's.
        z = float(np.median(truth_sensor.center[:, 2])) if len(truth_sensor) else 0.0
        centre = np.stack([r * np.cos(azimuth), r * np.sin(azimuth), np.full(count, z)], axis=1)
        yaw = draws[:, 2] * 2.0 * np.pi - np.pi
        boxes = Boxes3D.from_yaw(centre, np.tile(_FP_SIZE_LWH, (count, 1)), yaw, sensor, classes=np.full(count, "car"))
        scores = np.clip(_FP_SCORE[0] + _FP_SCORE[1] * (draws[:, 3] * 2.0 - 1.0) * np.sqrt(3.0), 0.0, 1.0)
        return boxes, scores


def _rot_z(angle_rad: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    out = np.zeros((len(angle_rad), 3, 3))
    out[:, 0, 0], out[:, 0, 1], out[:, 1, 0], out[:, 1, 1], out[:, 2, 2] = c, -s, s, c, 1.0
    return out
