"""Rotated-box geometry against hand-worked cases, shapely-free Monte Carlo volumes and identities."""

import numpy as np
import pytest

from avdata.errors import InputError
from avdata.eval.geometry import (
    bev_corners,
    bev_intersection_area,
    bev_iou,
    box2d_iou,
    box3d_iou,
    centre_distance,
)


def _inside(points: np.ndarray, box: np.ndarray) -> np.ndarray:
    """(K,) whether (K, 3) points lie in one unified 3D box (x, y, z, l, w, h, yaw)."""
    d = points - box[:3]
    c, s = np.cos(box[6]), np.sin(box[6])
    local_x = c * d[:, 0] + s * d[:, 1]
    local_y = -s * d[:, 0] + c * d[:, 1]
    return (np.abs(local_x) <= box[3] / 2) & (np.abs(local_y) <= box[4] / 2) & (np.abs(d[:, 2]) <= box[5] / 2)


def test_hand_worked_bev_cases():
    unit = np.array([[0.0, 0.0, 2.0, 2.0, 0.0]])
    others = np.array(
        [
            [1.0, 0.0, 2.0, 2.0, 0.0],  # half overlap: 2 / (4 + 4 - 2)
            [2.0, 0.0, 2.0, 2.0, 0.0],  # touching edges
            [0.0, 0.0, 2.0, 2.0, np.pi / 2],  # same square rotated by 90 degrees
            [0.0, 0.0, 2.0, 2.0, np.pi / 4],  # octagon: 8 (sqrt 2 - 1)
            [5.0, 5.0, 1.0, 1.0, 0.3],  # disjoint
            [0.0, 0.0, 1.0, 1.0, 0.7],  # contained: 1 / 4
        ]
    )
    expected_area = [2.0, 0.0, 4.0, 8 * (np.sqrt(2) - 1), 0.0, 1.0]
    np.testing.assert_allclose(bev_intersection_area(unit, others)[0], expected_area, atol=1e-12)
    expected_iou = [1 / 3, 0.0, 1.0, 8 * (np.sqrt(2) - 1) / (8 - 8 * (np.sqrt(2) - 1)), 0.0, 0.25]
    np.testing.assert_allclose(bev_iou(unit, others)[0], expected_iou, atol=1e-12)


def test_hand_worked_3d_cases():
    a = np.array([[0.0, 0.0, 0.0, 4.0, 2.0, 2.0, 0.0]])
    b = np.array(
        [
            [0.0, 0.0, 1.0, 4.0, 2.0, 2.0, 0.0],  # half the height: 8 / (16 + 16 - 8)
            [0.0, 0.0, 0.0, 4.0, 2.0, 2.0, np.pi],  # flipped heading, same volume
            [0.0, 0.0, 2.0, 4.0, 2.0, 2.0, 0.0],  # stacked, touching
            [0.0, 0.0, 0.0, 4.0, 2.0, 2.0, np.pi / 2],  # crossed: BEV 2x2 overlap, 8 / (16 + 16 - 8)
        ]
    )
    np.testing.assert_allclose(box3d_iou(a, b)[0], [1 / 3, 1.0, 0.0, 1 / 3], atol=1e-12)


def test_monte_carlo_volume_agrees():
    rng = np.random.default_rng(7)
    n = 6
    boxes_a = np.c_[rng.uniform(-1, 1, (n, 3)), rng.uniform(1, 3, (n, 3)), rng.uniform(-np.pi, np.pi, n)]
    boxes_b = np.c_[rng.uniform(-1, 1, (n, 3)), rng.uniform(1, 3, (n, 3)), rng.uniform(-np.pi, np.pi, n)]
    exact = box3d_iou(boxes_a, boxes_b)
    samples = rng.uniform(-4, 4, (400_000, 3))
    volume = 8.0**3
    for i in range(n):
        in_a = _inside(samples, boxes_a[i])
        for j in range(n):
            in_b = _inside(samples, boxes_b[j])
            inter = np.mean(in_a & in_b) * volume
            union = np.prod(boxes_a[i, 3:6]) + np.prod(boxes_b[j, 3:6]) - inter
            # Standard error of the intersection estimate is below 0.05 m^3 here; allow 5 sigma on the IoU.
            assert exact[i, j] == pytest.approx(inter / union, abs=0.02)


def test_symmetry_invariance_and_paired():
    rng = np.random.default_rng(3)
    a = np.c_[rng.uniform(-3, 3, (40, 3)), rng.uniform(0.5, 5, (40, 3)), rng.uniform(-4, 4, 40)]
    b = np.c_[rng.uniform(-3, 3, (30, 3)), rng.uniform(0.5, 5, (30, 3)), rng.uniform(-4, 4, 30)]
    iou = box3d_iou(a, b)
    np.testing.assert_allclose(iou, box3d_iou(b, a).T, atol=1e-12)
    # Rigid motion of both sets (rotation about z by 1 rad, translation) leaves IoU unchanged.
    c, s = np.cos(1.0), np.sin(1.0)

    def move(x):
        out = x.copy()
        out[:, 0], out[:, 1] = c * x[:, 0] - s * x[:, 1] + 100, s * x[:, 0] + c * x[:, 1] - 50
        out[:, 6] += 1.0
        return out

    np.testing.assert_allclose(box3d_iou(move(a), move(b)), iou, atol=1e-9)
    np.testing.assert_allclose(np.diag(box3d_iou(a[:30], b)), box3d_iou(a[:30], b, paired=True), atol=0)
    np.testing.assert_allclose(np.diag(box3d_iou(a, a)), 1.0, atol=1e-12)
    assert ((iou >= 0) & (iou <= 1)).all()


def test_corners_are_counter_clockwise():
    corners = bev_corners(np.array([[1.0, 2.0, 4.0, 2.0, np.pi / 2]]))[0]
    np.testing.assert_allclose(corners, [[2, 4], [0, 4], [0, 0], [2, 0]], atol=1e-12)


def test_box2d_iou_and_distance():
    a = np.array([[0.0, 0.0, 2.0, 2.0], [0.0, 0.0, 0.0, 2.0]])
    b = np.array([[1.0, 1.0, 3.0, 3.0], [0.0, 0.0, 2.0, 2.0]])
    np.testing.assert_allclose(box2d_iou(a, b), [[1 / 7, 1.0], [0.0, 0.0]])
    np.testing.assert_allclose(box2d_iou(a, b, paired=True), [1 / 7, 0.0])
    np.testing.assert_allclose(centre_distance([[0, 0], [3, 4]], [[0, 0]]), [[0.0], [5.0]])


def test_bad_shapes_raise_input_error():
    with pytest.raises(InputError, match=r"boxes_a: expected an \(N, 7\) array"):
        box3d_iou(np.zeros((2, 5)), np.zeros((2, 7)))
    with pytest.raises(InputError, match="paired boxes"):
        box2d_iou(np.zeros((2, 4)), np.zeros((3, 4)), paired=True)
