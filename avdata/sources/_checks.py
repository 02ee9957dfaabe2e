"""The one tolerance check for rotations and quaternions read from source files.

Sources print rotations and quaternions with a few digits, so they are off by float noise; some
(re-calibrated DAIR-V2X matrices) are off by more. One rule for every source:

================================  ==================  ====================  ==================
deviation                         below 1e-6          1e-6 .. 1e-2          above 1e-2
================================  ==================  ====================  ==================
rotation: max |R^T R - I|         repaired silently   repaired, warning     rejected (error)
quaternion: | |q| - 1 |           normalised silently normalised, warning   rejected (error)
================================  ==================  ====================  ==================

A rotation is repaired to the nearest rotation (SVD polar factor); one with determinant <= 0 (a
reflection or a singular matrix) and any non-finite value is rejected. Callers name the file, the
key or token and pass the message on, so that only the record holding the value is lost.
"""

from __future__ import annotations

import numpy as np

from avdata.errors import InputError
from avdata.frames.rotations import orthonormalize

#: Deviations up to this are float noise of printed values: repaired without a word.
SILENT_TOLERANCE = 1e-6
#: Deviations up to this are repaired with a warning; above it the value is rejected.
REPAIR_TOLERANCE = 1e-2


def rotation_deviation(rotation: np.ndarray) -> np.ndarray:
    """(...,) max |R^T R - I| of (..., 3, 3) matrices; +inf where a value is not finite or det <= 0."""
    rotation = np.asarray(rotation, dtype=np.float64)
    finite = np.all(np.isfinite(rotation), axis=(-2, -1))
    safe = np.where(finite[..., None, None], rotation, np.eye(3))
    gram = np.swapaxes(safe, -2, -1) @ safe
    deviation = np.max(np.abs(gram - np.eye(3)), axis=(-2, -1))
    return np.where(finite & (np.linalg.det(safe) > 0.0), deviation, np.inf)


def quaternion_deviation(quat_wxyz: np.ndarray) -> np.ndarray:
    """(...,) | |q| - 1 | of (..., 4) quaternions; +inf where a value is not finite."""
    quat_wxyz = np.asarray(quat_wxyz, dtype=np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        deviation = np.abs(np.linalg.norm(quat_wxyz, axis=-1) - 1.0)
    return np.where(np.isfinite(deviation), deviation, np.inf)


def repaired_rotation(rotation: np.ndarray, where: str) -> tuple[np.ndarray, str | None]:
    """The nearest rotation to a (3, 3) matrix read from a file, and a warning if the repair is beyond noise.

    Args:
        rotation: (3, 3) the matrix as read.
        where: file and key, for the messages (``".../calib/000000.txt: R0_rect"``).

    Raises:
        InputError: the matrix is off orthonormality by more than :data:`REPAIR_TOLERANCE`, not finite,
            or not proper (det <= 0).
    """
    rotation = np.asarray(rotation, dtype=np.float64).reshape(3, 3)
    deviation = float(rotation_deviation(rotation))
    if not deviation <= REPAIR_TOLERANCE:
        detail = "finite values with det > 0" if not np.isfinite(deviation) else f"deviation {deviation:.3g}"
        raise InputError(f"{where}: expected a rotation (max |R^T R - I| <= {REPAIR_TOLERANCE:g}), got "
                         f"{' '.join(f'{v:.6g}' for v in rotation.ravel())} ({detail})")
    warning = None
    if deviation > SILENT_TOLERANCE:
        warning = (f"{where}: rotation off orthonormality by {deviation:.3g} (> {SILENT_TOLERANCE:g}); "
                   f"replaced by the nearest rotation")
    return orthonormalize(rotation), warning


def repaired_quaternions(quat_wxyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit quaternions from (N, 4) read ones, vectorised: (unit (N, 4), warn (N,), reject (N,)).

    Rejected rows are returned as (1, 0, 0, 0); callers drop them and report :func:`quaternion_message`.
    """
    quat_wxyz = np.asarray(quat_wxyz, dtype=np.float64).reshape(-1, 4)
    deviation = quaternion_deviation(quat_wxyz)
    reject = ~(deviation <= REPAIR_TOLERANCE)
    warn = ~reject & (deviation > SILENT_TOLERANCE)
    safe = np.where(reject[:, None], [1.0, 0.0, 0.0, 0.0], quat_wxyz)
    return safe / np.linalg.norm(safe, axis=1, keepdims=True), warn, reject


def quaternion_message(quat_wxyz: np.ndarray, rejected: bool) -> str:
    """What is wrong with one (4,) quaternion, for a message that names file and token first."""
    quat_wxyz = np.asarray(quat_wxyz, dtype=np.float64)
    values = "[" + ", ".join(f"{v:.9g}" for v in quat_wxyz.tolist()) + "]"
    deviation = float(quaternion_deviation(quat_wxyz))
    if rejected:
        return f"expected a unit quaternion (| |q| - 1 | <= {REPAIR_TOLERANCE:g}), got {values}"
    return f"quaternion {values} off unit norm by {deviation:.3g} (> {SILENT_TOLERANCE:g}); normalised"


def point_values_problem(values: np.ndarray, names: tuple[str, ...], bound: float) -> str | None:
    """Why a point cloud's numbers cannot be measurements (None if they can): NaN, infinite or over ``bound``.

    Lidar formats without a checksum (KITTI and nuScenes ``.bin``, PCD) store a damaged float as another float;
    one in a high exponent bit makes it astronomically large or infinite. Two reductions over the values
    (about 60 µs for a 115k-point KITTI scan), so every cloud is checked.

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
