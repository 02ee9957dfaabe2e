"""Simulated detections: noise statistics match the stated sigmas, misses match the stated probabilities, seeded."""

from __future__ import annotations

import numpy as np
import pytest

from avdata.errors import InputError
from avdata.frames import Boxes3D, Transform
from avdata.perception.detections import NOISE_LEVELS, DetectionSimulator, NoiseModel, rng_for

#: The sensor 15 m up, turned 30 degrees about z: noise must be applied in its frame, not in world.
WORLD_T_SENSOR = Transform.from_euler("ZYX", np.array([np.pi / 6, 0.0, 0.0]), np.array([5.0, -3.0, 15.0]))


def _truth(n: int = 1, range_m: float = 40.0) -> Boxes3D:
    sensor_xyz = np.tile([range_m, 0.0, 0.0], (n, 1))
    centre = WORLD_T_SENSOR.apply(sensor_xyz)
    return Boxes3D.from_yaw(centre, np.tile([4.0, 2.0, 1.5], (n, 1)), np.full(n, 0.3), "world",
                            ids=[str(i) for i in range(n)], classes=["car"] * n)


def test_none_is_the_truth_in_the_sensor_frame() -> None:
    truth = _truth(5)
    sim = DetectionSimulator(noise=NOISE_LEVELS["none"])
    det = sim.detect(truth, np.full(5, 10), np.zeros(5), WORLD_T_SENSOR, "infra/lidar", 7, rng_for(0, 1))
    back = det.boxes.transform(WORLD_T_SENSOR, "world")
    assert det.boxes.frame == "infra/lidar" and det.timestamp_ns == 7
    np.testing.assert_allclose(back.center, truth.center, atol=1e-9)
    np.testing.assert_allclose(back.quat_wxyz, truth.quat_wxyz, atol=1e-9)
    np.testing.assert_allclose(back.size_lwh, truth.size_lwh, atol=1e-12)
    assert list(det.boxes.classes) == ["car"] * 5


def test_noise_statistics_match_the_stated_sigmas() -> None:
    n, range_m = 8000, 40.0
    noise = NOISE_LEVELS["med"]
    sim = DetectionSimulator(noise=noise.__class__(**{**{f: getattr(noise, f) for f in noise.__slots__},
                                                       "miss_probability": (0, 0, 0, 0), "false_positives_per_frame": 0.0}))
    truth = _truth(n, range_m)
    det = sim.detect(truth, np.full(n, 5), np.zeros(n), WORLD_T_SENSOR, "s", 0, rng_for(3, 0))
    assert len(det) == n
    scale = 1 + noise.growth_per_m * range_m  # 1.4 at 40 m for "med"
    err = det.boxes.center - np.array([range_m, 0.0, 0.0])
    np.testing.assert_allclose(err.std(axis=0), [0.3 * scale, 0.3 * scale, 0.1 * scale], rtol=0.04)
    np.testing.assert_allclose(err.mean(axis=0), 0.0, atol=0.02)
    rel_size = det.boxes.size_lwh / np.array([4.0, 2.0, 1.5]) - 1
    np.testing.assert_allclose(rel_size.std(axis=0), 0.05 * scale, rtol=0.04)
    yaw_sensor = 0.3 - np.pi / 6
    dyaw = (det.boxes.yaw() - yaw_sensor + np.pi) % (2 * np.pi) - np.pi
    assert dyaw.std() == pytest.approx(0.05 * scale, rel=0.04)


def test_miss_probability_by_occlusion_and_unseen_objects() -> None:
    model = NoiseModel(miss_probability=(0.1, 0.2, 0.5, 0.9))
    rates = []
    for level in range(4):
        n = 5000
        truth = _truth(n, 20.0)
        det = DetectionSimulator(noise=model).detect(truth, np.full(n, 3), np.full(n, level), WORLD_T_SENSOR, "s", 0,
                                                     rng_for(9, level))
        rates.append(len(det) / n)
    np.testing.assert_allclose(rates, [0.9, 0.8, 0.5, 0.1], atol=0.02)
    # No lidar return in the box: never detected, whatever the miss probability.
    unseen = DetectionSimulator(noise=NoiseModel()).detect(_truth(10), np.zeros(10), np.zeros(10), WORLD_T_SENSOR, "s", 0,
                                                           rng_for(0))
    assert len(unseen) == 0


def test_false_positives_are_poisson_in_the_field_of_view() -> None:
    model = NoiseModel(false_positives_per_frame=2.5)
    sim = DetectionSimulator(noise=model, max_range_m=60.0, horizontal_fov_deg=180.0)
    empty = Boxes3D.empty("world")
    from dataclasses import replace
    empty = replace(empty, ids=np.zeros(0, str), classes=np.zeros(0, str))
    counts, azimuths, ranges = [], [], []
    for frame in range(600):
        det = sim.detect(empty, np.zeros(0), np.zeros(0), WORLD_T_SENSOR, "s", frame, rng_for(5, frame))
        counts.append(len(det))
        azimuths.append(np.arctan2(det.boxes.center[:, 1], det.boxes.center[:, 0]))
        ranges.append(np.hypot(det.boxes.center[:, 0], det.boxes.center[:, 1]))
    assert np.mean(counts) == pytest.approx(2.5, rel=0.08)
    assert np.var(counts) == pytest.approx(2.5, rel=0.2)
    az, r = np.concatenate(azimuths), np.concatenate(ranges)
    assert np.all(np.abs(az) <= np.pi / 2 + 1e-12) and np.all((r >= 5.0) & (r <= 60.0))


def test_same_seed_same_detections_other_seed_other() -> None:
    truth = _truth(50)
    sim = DetectionSimulator(noise=NOISE_LEVELS["high"])
    a = sim.detect(truth, np.full(50, 3), np.ones(50), WORLD_T_SENSOR, "s", 0, rng_for(7, "scene", 3, 1))
    b = sim.detect(truth, np.full(50, 3), np.ones(50), WORLD_T_SENSOR, "s", 0, rng_for(7, "scene", 3, 1))
    c = sim.detect(truth, np.full(50, 3), np.ones(50), WORLD_T_SENSOR, "s", 0, rng_for(8, "scene", 3, 1))
    np.testing.assert_array_equal(a.boxes.center, b.boxes.center)
    np.testing.assert_array_equal(a.scores, b.scores)
    assert len(a) != len(c) or not np.array_equal(a.boxes.center, c.boxes.center)


def test_bad_noise_models_are_refused() -> None:
    with pytest.raises(InputError, match="centre_xy_sigma_m"):
        NoiseModel(centre_xy_sigma_m=-1.0)
    with pytest.raises(InputError, match="miss probabilities"):
        NoiseModel(miss_probability=(0.1, 0.2, 1.5, 0.0))
    with pytest.raises(InputError, match="visibility values"):
        DetectionSimulator(noise=NOISE_LEVELS["none"]).detect(_truth(2), np.ones(3), np.zeros(2), WORLD_T_SENSOR, "s", 0,
                                                                rng_for(0))
