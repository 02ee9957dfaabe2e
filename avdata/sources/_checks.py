"""Checks of point values read from source files without a checksum.

The rotation and quaternion rule (one measure, one pair of tolerances for every source) is
:mod:`avdata.frames.rotations` (``repaired_rotation``, ``repaired_quaternions``).
"""

from __future__ import annotations

import numpy as np


def point_values_problem(values: np.ndarray, names: tuple[str, ...], bound: float) -> str | None:
    """Why a point cloud's numbers cannot be measurements (None if they can): NaN, infinite or over ``bound``.

    Lidar formats without a checksum (KITTI and nuScenes ``.bin``, PCD) store a damaged float as another float;
    one in a high exponent bit makes it astronomically large or infinite. Two reductions over the values,
    cheap beside reading the cloud, so every cloud is checked.

    Args:
        values: (N, F) the numbers to check, F = len(names) per point (or (N,) for one field).
        names: the F field names, for the message.
        bound: largest magnitude accepted.
    """
    if values.size == 0:
        return None
    # Compared as float64: a float16 cloud (Argoverse 2) would cast the bound to its own type (1e7 -> inf).
    low, high = float(values.min()), float(values.max())  # NaN if any value is NaN
    if low >= -bound and high <= bound:
        return None
    with np.errstate(invalid="ignore"):
        first = int(np.flatnonzero(~(np.abs(values.reshape(-1)) <= np.float64(bound)))[0])
    point, field = divmod(first, len(names))
    return (f"point {point}, {names[field]}: expected a finite value within +-{bound:g}, got "
            f"{float(values.reshape(-1)[first])!r} (damaged bytes?)")


def coordinates_problem(points: np.ndarray | dict[str, np.ndarray], bound: float) -> str | None:
    """:func:`point_values_problem` of a cloud's ``x``, ``y`` and ``z`` (those it has), field by field.

    Args:
        points: a structured array or a mapping of field name -> (N,) column.
        bound: largest magnitude accepted.
    """
    names = (points.dtype.names or ()) if isinstance(points, np.ndarray) else tuple(points)
    for name in ("x", "y", "z"):
        if name in names and (problem := point_values_problem(points[name], (name,), bound)) is not None:
            return problem
    return None
