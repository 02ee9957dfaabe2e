"""Vectorised box overlap and distance for evaluation: rotated 3D IoU, BEV IoU, 2D IoU, centre distance.

Box conventions (avdata, unified):

* 3D box rows are ``(x_m, y_m, z_m, length_m, width_m, height_m, yaw_rad)``: the centre of the box,
  its size along the box's own x (length), y (width) and z (height), and the yaw about +z,
  counter-clockwise from the reference x axis.
* BEV box rows are ``(x_m, y_m, length_m, width_m, yaw_rad)``.
* 2D box rows are ``(x0, y0, x1, y1)`` corners (pixels or metres), ``x0 <= x1``, ``y0 <= y1``.

The rotated BEV intersection is exact: by Green's theorem the area of the intersection of two convex
polygons A, B is ``1/2 * sum(cross(p, q))`` over the pieces ``p -> q`` of A's edges inside B and of B's
edges inside A. Each piece comes from clipping a segment against four half-planes, so every pair of boxes
is handled by array arithmetic over an ``(N, M, 4, 4)`` grid with no Python loop per pair.
"""

from __future__ import annotations

import numpy as np

from avdata.errors import InputError

__all__ = [
    "bev_corners",
    "bev_intersection_area",
    "bev_iou",
    "box2d_iou",
    "box3d_iou",
    "centre_distance",
]


def _as_rows(boxes: np.ndarray, width: int, name: str) -> np.ndarray:
    arr = np.asarray(boxes, dtype=np.float64)
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, width)
    if arr.ndim != 2 or arr.shape[1] != width:
        raise InputError(f"{name}: expected an (N, {width}) array of boxes, got shape {arr.shape}")
    return arr


def bev_corners(boxes_bev: np.ndarray) -> np.ndarray:
    """Corners of rotated rectangles, counter-clockwise.

    Args:
        boxes_bev: (N, 5) rows ``(x, y, length, width, yaw_rad)``.

    Returns:
        (N, 4, 2) corners in counter-clockwise order (for positive length and width).
    """
    b = _as_rows(boxes_bev, 5, "boxes_bev")
    half_l, half_w = b[:, 2] / 2.0, b[:, 3] / 2.0
    local = np.stack(
        [
            np.stack([half_l, -half_w], axis=-1),
            np.stack([half_l, half_w], axis=-1),
            np.stack([-half_l, half_w], axis=-1),
            np.stack([-half_l, -half_w], axis=-1),
        ],
        axis=1,
    )
    cos, sin = np.cos(b[:, 4])[:, None], np.sin(b[:, 4])[:, None]
    x = cos * local[..., 0] - sin * local[..., 1] + b[:, 0:1]
    y = sin * local[..., 0] + cos * local[..., 1] + b[:, 1:2]
    return np.stack([x, y], axis=-1)


def _cross(ax: np.ndarray, ay: np.ndarray, bx: np.ndarray, by: np.ndarray) -> np.ndarray:
    result: np.ndarray = ax * by - ay * bx
    return result


def _clipped_edge_area(poly_a: np.ndarray, poly_b: np.ndarray, keep_shared: bool) -> np.ndarray:
    """Green's-theorem contribution of A's edges clipped to the inside of B.

    Args:
        poly_a: (N, 1, 4, 2) counter-clockwise polygon A (broadcast against M).
        poly_b: (1, M, 4, 2) counter-clockwise polygon B.
        keep_shared: whether an edge of A lying on an edge of B with the same direction counts
            (True for one of the two calls, so a shared boundary is counted once).

    Returns:
        (N, M) the signed contribution ``1/2 * sum cross(p(t0), p(t1))``.
    """
    p = poly_a[..., :, None, :]  # (N, M, 4 edges of A, 1, 2)
    d = np.roll(poly_a, -1, axis=-2)[..., :, None, :] - p
    v = poly_b[..., None, :, :]  # (N, M, 1, 4 edges of B, 2)
    e = np.roll(poly_b, -1, axis=-2)[..., None, :, :] - v
    # Inside half-plane k of B: cross(e_k, x - v_k) >= 0. Along the edge x = p + t d: f0 + t * slope.
    f0 = _cross(e[..., 0], e[..., 1], p[..., 0] - v[..., 0], p[..., 1] - v[..., 1])
    slope = _cross(e[..., 0], e[..., 1], d[..., 0], d[..., 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        t_cross = -f0 / slope
    lower = np.where(slope > 0, t_cross, -np.inf)
    upper = np.where(slope < 0, t_cross, np.inf)
    parallel = slope == 0
    same_direction = (e[..., 0] * d[..., 0] + e[..., 1] * d[..., 1]) > 0
    on_line_kept = (f0 == 0) & same_direction if keep_shared else np.zeros_like(parallel)
    parallel_inside = (f0 > 0) | on_line_kept
    upper = np.where(parallel & ~parallel_inside, -np.inf, upper)
    t0 = np.clip(lower.max(axis=-1), 0.0, 1.0)
    t1 = np.clip(upper.min(axis=-1), 0.0, 1.0)
    valid = t1 > t0
    p2, d2 = p[..., 0, :], d[..., 0, :]
    start = p2 + t0[..., None] * d2
    end = p2 + t1[..., None] * d2
    contribution = 0.5 * _cross(start[..., 0], start[..., 1], end[..., 0], end[..., 1])
    result: np.ndarray = np.where(valid, contribution, 0.0).sum(axis=-1)
    return result


def _pair_shapes(a: np.ndarray, b: np.ndarray, paired: bool) -> None:
    if paired and len(a) != len(b):
        raise InputError(f"paired boxes: expected equal counts, got {len(a)} and {len(b)}")


def bev_intersection_area(boxes_a: np.ndarray, boxes_b: np.ndarray, *, paired: bool = False) -> np.ndarray:
    """Exact intersection area of rotated rectangles, for every pair or row by row.

    Args:
        boxes_a: (N, 5) rows ``(x, y, length, width, yaw_rad)``.
        boxes_b: (M, 5) rows ``(x, y, length, width, yaw_rad)``.
        paired: if True, N == M and row i of ``boxes_a`` is compared with row i of ``boxes_b`` only.

    Returns:
        (N, M) intersection areas, or (N,) when ``paired``.
    """
    a = _as_rows(boxes_a, 5, "boxes_a")
    b = _as_rows(boxes_b, 5, "boxes_b")
    _pair_shapes(a, b, paired)
    if paired:
        # Work relative to each pair's first centre, which keeps the cross products well conditioned.
        ca = bev_corners(a) - a[:, None, 0:2]
        cb = bev_corners(b) - a[:, None, 0:2]
        cap = np.minimum(a[:, 2] * a[:, 3], b[:, 2] * b[:, 3])
    else:
        if len(a) == 0 or len(b) == 0:
            return np.zeros((len(a), len(b)))
        ca = np.broadcast_to((bev_corners(a) - a[:, None, 0:2])[:, None], (len(a), len(b), 4, 2))
        cb = bev_corners(b)[None, :] - a[:, None, None, 0:2]
        cap = np.minimum((a[:, 2] * a[:, 3])[:, None], (b[:, 2] * b[:, 3])[None, :])
    area = _clipped_edge_area(ca, cb, keep_shared=True) + _clipped_edge_area(cb, ca, keep_shared=False)
    result: np.ndarray = np.clip(area, 0.0, cap)
    return result


def bev_iou(boxes_a: np.ndarray, boxes_b: np.ndarray, *, paired: bool = False) -> np.ndarray:
    """Bird's-eye-view IoU of rotated rectangles.

    Args:
        boxes_a: (N, 5) or (N, 7) boxes; 7-column 3D boxes are projected to ``(x, y, l, w, yaw)``.
        boxes_b: (M, 5) or (M, 7) boxes, same layout as ``boxes_a``.
        paired: if True, N == M and row i is compared with row i only.

    Returns:
        (N, M) IoU in [0, 1], or (N,) when ``paired``.
    """
    a, b = _to_bev(boxes_a, "boxes_a"), _to_bev(boxes_b, "boxes_b")
    inter = bev_intersection_area(a, b, paired=paired)
    area_a, area_b = a[:, 2] * a[:, 3], b[:, 2] * b[:, 3]
    union = (area_a + area_b if paired else area_a[:, None] + area_b[None, :]) - inter
    result: np.ndarray = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)
    return result


def _to_bev(boxes: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(boxes, dtype=np.float64)
    if arr.ndim == 2 and arr.shape[1] == 7:
        return arr[:, [0, 1, 3, 4, 6]]
    return _as_rows(arr, 5, name)


def box3d_iou(boxes_a: np.ndarray, boxes_b: np.ndarray, *, paired: bool = False) -> np.ndarray:
    """Exact 3D IoU of boxes rotated about z: BEV polygon intersection times height overlap.

    Args:
        boxes_a: (N, 7) rows ``(x, y, z, length, width, height, yaw_rad)``, z the box centre.
        boxes_b: (M, 7) rows, same layout.
        paired: if True, N == M and row i is compared with row i only.

    Returns:
        (N, M) IoU in [0, 1], or (N,) when ``paired``.
    """
    a = _as_rows(boxes_a, 7, "boxes_a")
    b = _as_rows(boxes_b, 7, "boxes_b")
    inter_bev = bev_intersection_area(a[:, [0, 1, 3, 4, 6]], b[:, [0, 1, 3, 4, 6]], paired=paired)
    a_top, a_bottom = a[:, 2] + a[:, 5] / 2, a[:, 2] - a[:, 5] / 2
    b_top, b_bottom = b[:, 2] + b[:, 5] / 2, b[:, 2] - b[:, 5] / 2
    vol_a, vol_b = a[:, 3] * a[:, 4] * a[:, 5], b[:, 3] * b[:, 4] * b[:, 5]
    if not paired:
        a_top, a_bottom, vol_a = a_top[:, None], a_bottom[:, None], vol_a[:, None]
        b_top, b_bottom, vol_b = b_top[None, :], b_bottom[None, :], vol_b[None, :]
    inter = inter_bev * np.clip(np.minimum(a_top, b_top) - np.maximum(a_bottom, b_bottom), 0.0, None)
    union = vol_a + vol_b - inter
    result: np.ndarray = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)
    return result


def box2d_iou(boxes_a: np.ndarray, boxes_b: np.ndarray, *, paired: bool = False) -> np.ndarray:
    """Axis-aligned 2D IoU, with TrackEval's handling of empty boxes (IoU 0 if either area <= eps).

    Args:
        boxes_a: (N, 4) rows ``(x0, y0, x1, y1)``.
        boxes_b: (M, 4) rows ``(x0, y0, x1, y1)``.
        paired: if True, N == M and row i is compared with row i only.

    Returns:
        (N, M) IoU in [0, 1], or (N,) when ``paired``.
    """
    a = _as_rows(boxes_a, 4, "boxes_a")
    b = _as_rows(boxes_b, 4, "boxes_b")
    _pair_shapes(a, b, paired)
    if not paired:
        a, b = a[:, None, :], b[None, :, :]
    # In-place steps (fewer temporaries); the arithmetic is the plain formula's, operation for operation.
    inter = np.minimum(a[..., 2], b[..., 2])
    inter -= np.maximum(a[..., 0], b[..., 0])
    np.maximum(inter, 0, out=inter)
    ih = np.minimum(a[..., 3], b[..., 3])
    ih -= np.maximum(a[..., 1], b[..., 1])
    np.maximum(ih, 0, out=ih)
    inter *= ih
    area_a = a[..., 2] - a[..., 0]
    area_a *= a[..., 3] - a[..., 1]
    area_b = b[..., 2] - b[..., 0]
    area_b *= b[..., 3] - b[..., 1]
    union = area_a + area_b
    union -= inter
    eps = np.finfo(np.float64).eps
    valid = (area_a > eps) & (area_b > eps)
    valid &= union > eps
    result: np.ndarray = np.divide(inter, union, out=np.zeros(inter.shape), where=valid)
    return result


def centre_distance(centres_a: np.ndarray, centres_b: np.ndarray, *, paired: bool = False) -> np.ndarray:
    """Euclidean distance between centres.

    Args:
        centres_a: (N, D) points (D = 2 for BEV distance as nuScenes uses, 3 for 3D).
        centres_b: (M, D) points.
        paired: if True, N == M and row i is compared with row i only.

    Returns:
        (N, M) distances, or (N,) when ``paired``.
    """
    a = np.asarray(centres_a, dtype=np.float64)
    b = np.asarray(centres_b, dtype=np.float64)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise InputError(f"centres: expected (N, D) and (M, D) arrays, got shapes {a.shape} and {b.shape}")
    _pair_shapes(a, b, paired)
    diff = a - b if paired else a[:, None, :] - b[None, :, :]
    result: np.ndarray = np.linalg.norm(diff, axis=-1)
    return result
