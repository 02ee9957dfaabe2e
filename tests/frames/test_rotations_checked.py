"""The one rotation / quaternion repair rule (max |R^T R - I|, | |q| - 1 |; silent <= 1e-6, warned <= 1e-2,
refused beyond), on real calibration files."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from avdata.errors import InputError
from avdata.frames import RepairWarning, normalize_quat_checked, orthonormalize_checked
from avdata.frames.rotations import repaired_rotation
from tests.realdata import REALDATA


def kitti_r0_rect(path: Path) -> np.ndarray:
    for line in path.read_text().splitlines():
        if line.startswith("R0_rect:"):
            return np.array(line.split(":", 1)[1].split(), dtype=np.float64).reshape(3, 3)
    raise AssertionError(f"{path}: no R0_rect")


def test_printed_calibrations_are_repaired_silently_and_to_the_nearest_rotation() -> None:
    kitti = kitti_r0_rect(REALDATA / "kitti/object/training/calib/000000.txt")
    dair = np.array(json.loads((REALDATA / "dair_v2x/cooperative/calib/lidar_i2v/017314.json").read_text())["rotation"])
    for matrix in (kitti, dair):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            repaired, residual = orthonormalize_checked(matrix, where="calib")
        np.testing.assert_allclose(repaired @ repaired.T, np.eye(3), atol=1e-14)
        assert 1e-9 < residual <= 1e-6  # printed to 7-9 digits: float noise, not exact
        assert residual == pytest.approx(np.abs(matrix.T @ matrix - np.eye(3)).max(), abs=1e-15)
        # the polar factor is the nearest rotation: no random rotation close by is nearer
        rng = np.random.default_rng(0)
        for _ in range(50):
            nearby = Rotation.from_rotvec(rng.normal(scale=1e-6, size=3)).as_matrix() @ repaired
            assert np.linalg.norm(nearby - matrix) >= np.linalg.norm(repaired - matrix)


def test_a_visibly_skewed_rotation_warns_through_the_callback_and_a_scaled_one_is_rejected() -> None:
    rotation = Rotation.from_euler("ZYX", [0.4, 0.1, -0.2]).as_matrix()
    skewed = rotation.copy()
    skewed[0, 1] += 1e-3
    lines: list[str] = []
    repaired, residual = orthonormalize_checked(skewed, where="calib.json rotation", warn=lines.append)
    assert lines == ["calib.json rotation: rotation off orthonormality by 0.000916 (> 1e-06); replaced by the nearest "
                     "rotation"]
    assert 1e-6 < float(residual) < 1e-3
    np.testing.assert_allclose(repaired @ repaired.T, np.eye(3), atol=1e-14)
    with pytest.warns(RepairWarning, match="calib.json rotation"):
        orthonormalize_checked(skewed, where="calib.json rotation")
    batch = np.stack([rotation, rotation, 1.1 * rotation])
    with pytest.raises(InputError, match=r"calib.json rotation \(entry 2\): expected a rotation \(max \|R\^T R - I\| "
                                         r"<= 0.01\), got deviation 0.21"):
        orthonormalize_checked(batch, where="calib.json rotation")
    with pytest.raises(InputError, match="finite"):
        orthonormalize_checked(np.full((3, 3), np.nan))


def test_a_reflection_is_refused_by_the_one_rule() -> None:
    # The checked repair kept a reflection a reflection; the source rule refused it: one rule now, refused.
    mirror = np.diag([1.0, -1.0, 1.0]) + 1e-8
    with pytest.raises(InputError, match="got finite values with det > 0"):
        orthonormalize_checked(mirror)


def test_the_one_rule_gives_one_verdict_for_every_caller() -> None:
    # 1.007 I was repaired with a warning by one rule and refused by the other (issue 30).
    lines: list[str] = []
    scaled = 1.007 * np.eye(3)
    with pytest.raises(InputError, match="deviation 0.014"):
        repaired_rotation(scaled, "calib")
    with pytest.raises(InputError, match="deviation 0.014"):
        orthonormalize_checked(scaled, where="calib", warn=lines.append)
    nudged = 1.001 * np.eye(3)
    _, warning = repaired_rotation(nudged, "calib")
    orthonormalize_checked(nudged, where="calib", warn=lines.append)
    assert lines == [warning] == ["calib: rotation off orthonormality by 0.002 (> 1e-06); replaced by the nearest rotation"]


def test_quaternion_norms_silent_warned_rejected() -> None:
    lyft = json.loads((REALDATA / "nuscenes_schema/lyft/v1.01-train/v1.01-train/sample_annotation.json").read_text())
    quats = np.array([row["rotation"] for row in lyft])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        unit, residual = normalize_quat_checked(quats, where="sample_annotation.json rotation")
    np.testing.assert_allclose(np.linalg.norm(unit, axis=1), 1.0, atol=1e-15)
    assert residual.shape == (len(quats),) and residual.max() <= 1e-6
    lines: list[str] = []
    unit, residual = normalize_quat_checked(np.array([0.0, 0.0, 0.0, 1.002]), warn=lines.append)
    np.testing.assert_allclose(unit, [0.0, 0.0, 0.0, 1.0], atol=0)
    assert residual == pytest.approx(0.002) and len(lines) == 1
    with pytest.raises(InputError, match=r"ego pose \(entry 1\): expected a unit quaternion \(\| \|q\| - 1 \| <= 0.01\), "
                                         r"got deviation 0.5"):
        normalize_quat_checked(np.array([[1.0, 0, 0, 0], [0.5, 0, 0, 0]]), where="ego pose")
