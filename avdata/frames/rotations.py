"""Rotation conversions: the one place where avdata talks to scipy's Rotation (imported lazily).

avdata's API is scalar-first everywhere (quaternions are ``quat_wxyz``); scipy is always called
with ``scalar_first=True`` here and nowhere else, so no other module has to remember scipy's
(x, y, z, w) default. Euler sequences are passed through verbatim: uppercase letters are intrinsic
rotations, lowercase extrinsic, as scipy defines them.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable

import numpy as np

from avdata.errors import AvdataError, InputError


def matrix_from_quat_wxyz(quat_wxyz: np.ndarray) -> np.ndarray:
    """Rotation matrices from scalar-first quaternions.

    Args:
        quat_wxyz: (..., 4) quaternions (w, x, y, z); normalised here, must not be zero.

    Returns:
        (..., 3, 3) rotation matrices.
    """
    quat_wxyz = np.asarray(quat_wxyz, dtype=np.float64)
    if quat_wxyz.shape[-1:] != (4,):
        raise AvdataError(f"expected quaternions of shape (..., 4), got {quat_wxyz.shape}")
    norms = np.linalg.norm(quat_wxyz, axis=-1)
    if np.any(~np.isfinite(norms)) or np.any(norms < 1e-12):
        raise AvdataError("expected finite non-zero quaternions, got a zero or non-finite one")
    # The textbook formula in numpy: converters call this for every pose, and importing scipy for it
    # alone cost ~40 MB of a conversion's peak memory. Tested against scipy. Loaders call this for
    # every item's few boxes, where the per-call overhead is the cost, so the nine entries come from
    # a handful of array operations on all of them at once: entry k is
    # ``2 (q_a q_b + sign q_c q_d)`` (diagonal: 1 minus that), each product, sum and difference the
    # one of the textbook expression ``1 - 2 (yy + zz)``, ``2 (xy - wz)``, ...: the same bits.
    unit = quat_wxyz / norms[..., None]
    products = (unit[..., :, None] * unit[..., None, :]).reshape(unit.shape[:-1] + (16,))
    matrix = 2.0 * (products[..., _ENTRY_FIRST] + products[..., _ENTRY_SECOND] * _ENTRY_SIGN)
    matrix[..., _DIAGONAL] = 1.0 - matrix[..., _DIAGONAL]
    result: np.ndarray = matrix.reshape(quat_wxyz.shape[:-1] + (3, 3))
    return result


#: Row-major entries of the rotation matrix as ``2 (q_a q_b + sign q_c q_d)`` (diagonal: 1 minus that),
#: with q_a q_b at index 4 a + b of the flattened outer product of (w, x, y, z):
#: (yy + zz, xy - wz, xz + wy, xy + wz, xx + zz, yz - wx, xz - wy, yz + wx, xx + yy).
_ENTRY_FIRST = np.array([10, 6, 7, 6, 5, 11, 7, 11, 5])
_ENTRY_SECOND = np.array([15, 3, 2, 3, 15, 1, 2, 1, 10])
_ENTRY_SIGN = np.array([1.0, -1.0, 1.0, 1.0, 1.0, -1.0, -1.0, 1.0, 1.0])
_DIAGONAL = np.array([0, 4, 8])


#: Shepperd's method: for each case (largest of w, x, y, z), which of the terms (m21 - m12, m02 - m20,
#: m10 - m01, m01 + m10, m02 + m20, m12 + m21) gives w, x, y, z; the case's own component (0 here) is
#: 0.25 * s instead.
_SHEPPERD_TERMS = np.array([[0, 0, 1, 2], [0, 0, 3, 4], [1, 3, 0, 5], [2, 4, 5, 0]])
#: The terms as ``m[first] + sign * m[second]`` of the row-major flattened matrix.
_TERM_FIRST = np.array([7, 2, 3, 1, 2, 5])
_TERM_SECOND = np.array([5, 6, 1, 3, 6, 7])
_TERM_SIGN = np.array([-1.0, -1.0, -1.0, 1.0, 1.0, 1.0])
#: Signs of m00, m11, m22 in the four candidates (rows: m00, m11, m22; columns: w, x, y, z).
_CANDIDATE_SIGNS = np.array([[1.0, 1.0, -1.0, -1.0], [1.0, -1.0, 1.0, -1.0], [1.0, -1.0, -1.0, 1.0]])


def quat_wxyz_from_matrix(rotation: np.ndarray) -> np.ndarray:
    """Scalar-first unit quaternions from proper rotation matrices, with w >= 0.

    Shepperd's method, vectorised (scipy's ``from_matrix`` costs ~0.2 ms per call, which dominated
    writing per-frame poses); each row uses the largest of w, x, y, z as the divisor, so it is
    stable for every rotation. Tested against scipy. The sign is fixed (w >= 0) so the same rotation
    always gives the same bytes on disk.

    Args:
        rotation: (..., 3, 3) proper rotation matrices (det +1).

    Returns:
        (..., 4) quaternions (w, x, y, z).
    """
    rotation = np.asarray(rotation, dtype=np.float64)
    _require_proper(rotation)
    if rotation.shape == (3, 3):
        return _quat_wxyz_single(rotation)
    m = rotation.reshape(-1, 9)
    # 4 * (w^2, x^2, y^2, z^2) up to the matrix's deviation from orthonormality: 1 + m00 + m11 + m22,
    # 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22, summed left to right by columns.
    diagonal = m[:, _DIAGONAL]
    candidates = 1.0 + diagonal[:, :1] * _CANDIDATE_SIGNS[0]
    candidates = candidates + diagonal[:, 1:2] * _CANDIDATE_SIGNS[1]
    candidates = candidates + diagonal[:, 2:3] * _CANDIDATE_SIGNS[2]
    case = np.argmax(candidates, axis=1)
    rows = np.arange(len(m))
    s = 2.0 * np.sqrt(np.maximum(candidates[rows, case], 1e-300))
    # The other three components are (sum or difference of two entries) / s, picked per row by its
    # case from one table (no Python loop over cases: loaders convert a few boxes per item).
    terms = m[:, _TERM_FIRST] + m[:, _TERM_SECOND] * _TERM_SIGN
    quat = np.take_along_axis(terms, _SHEPPERD_TERMS[case], axis=1) / s[:, None]
    quat[rows, case] = 0.25 * s
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    quat = np.where(quat[:, :1] < 0.0, -quat, quat)
    result: np.ndarray = quat.reshape(rotation.shape[:-2] + (4,))
    return result


def _quat_wxyz_single(rotation: np.ndarray) -> np.ndarray:
    """Shepperd's method for one matrix with Python floats.

    ~40x less overhead than the array path, which matters because writers convert one pose per message. The
    largest of the four candidates picks the divisor (the first on a tie, as the array path's argmax).
    """
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = rotation.tolist()
    tw, tx, ty, tz = 1.0 + m00 + m11 + m22, 1.0 + m00 - m11 - m22, 1.0 - m00 + m11 - m22, 1.0 - m00 - m11 + m22
    if tw >= tx and tw >= ty and tw >= tz:
        s = 2.0 * math.sqrt(max(tw, 1e-300))
        w, x, y, z = 0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s
    elif tx >= ty and tx >= tz:
        s = 2.0 * math.sqrt(max(tx, 1e-300))
        w, x, y, z = (m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s
    elif ty >= tz:
        s = 2.0 * math.sqrt(max(ty, 1e-300))
        w, x, y, z = (m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s
    else:
        s = 2.0 * math.sqrt(max(tz, 1e-300))
        w, x, y, z = (m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:  # w >= 0: the same rotation always gives the same bytes
        norm = -norm
    return np.array((w / norm, x / norm, y / norm, z / norm))


def matrix_from_euler(seq: str, angles: np.ndarray, degrees: bool = False) -> np.ndarray:
    """Rotation matrices from Euler angles in an explicit axis sequence.

    Args:
        seq: scipy axis sequence, e.g. "ZYX" (intrinsic) or "xyz" (extrinsic).
        angles: (..., len(seq)) angles, radians unless ``degrees``.
        degrees: whether ``angles`` are in degrees.

    Returns:
        (..., 3, 3) rotation matrices.
    """
    angles = np.asarray(angles, dtype=np.float64)
    n_axes = len(seq)
    if angles.ndim == 0 and n_axes == 1:
        angles = angles[None]
    if angles.shape[-1:] != (n_axes,):
        raise AvdataError(f"expected angles of shape (..., {n_axes}) for sequence {seq!r}, got {angles.shape}")
    flat = angles.reshape(-1, n_axes)
    from scipy.spatial.transform import Rotation

    matrices = Rotation.from_euler(seq, flat, degrees=degrees).as_matrix()
    result: np.ndarray = matrices.reshape(angles.shape[:-1] + (3, 3))
    return result


def euler_from_matrix(rotation: np.ndarray, seq: str, degrees: bool = False) -> np.ndarray:
    """Euler angles of proper rotation matrices in an explicit axis sequence.

    Args:
        rotation: (..., 3, 3) proper rotation matrices.
        seq: scipy axis sequence of three axes.
        degrees: return degrees instead of radians.

    Returns:
        (..., 3) angles.
    """
    rotation = np.asarray(rotation, dtype=np.float64)
    _require_proper(rotation)
    flat = rotation.reshape(-1, 3, 3)
    from scipy.spatial.transform import Rotation

    angles = Rotation.from_matrix(flat).as_euler(seq, degrees=degrees)
    result: np.ndarray = angles.reshape(rotation.shape[:-2] + (len(seq),))
    return result


def rotvec_from_matrix(rotation: np.ndarray) -> np.ndarray:
    """Axis-angle vectors (..., 3) of proper rotation matrices (..., 3, 3)."""
    rotation = np.asarray(rotation, dtype=np.float64)
    flat = rotation.reshape(-1, 3, 3)
    from scipy.spatial.transform import Rotation

    result: np.ndarray = Rotation.from_matrix(flat).as_rotvec().reshape(rotation.shape[:-2] + (3,))
    return result


def matrix_from_rotvec(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from axis-angle vectors (..., 3)."""
    rotvec = np.asarray(rotvec, dtype=np.float64)
    flat = rotvec.reshape(-1, 3)
    from scipy.spatial.transform import Rotation

    result: np.ndarray = Rotation.from_rotvec(flat).as_matrix().reshape(rotvec.shape[:-1] + (3, 3))
    return result


def orthonormalize(rotation: np.ndarray) -> np.ndarray:
    """The nearest orthonormal matrices (polar decomposition via SVD), keeping the determinant's sign.

    Calibration files print rotations to ~7 digits, so they are orthonormal only to ~1e-7; storing
    them as quaternions requires an exact rotation, and the nearest one (in Frobenius norm) moves
    points the least.

    Args:
        rotation: (..., 3, 3) nearly orthonormal matrices.

    Returns:
        (..., 3, 3) orthonormal matrices with the same determinant sign.
    """
    rotation = np.asarray(rotation, dtype=np.float64)
    u, _, vt = np.linalg.svd(rotation)
    result: np.ndarray = u @ vt
    return result


#: Residual (largest entry moved) up to which a repair is float noise and stays silent: calibration
#: files print 7 to 9 significant digits (KITTI's R0_rect is orthonormal to ~4e-8, DAIR-V2X's
#: lidar_i2v to ~2e-7).
SILENT_TOL = 1e-6
#: Residual up to which a repair is made with a warning; beyond it the input is not a rounded
#: rotation (or quaternion) at all and is rejected. 1e-2 lets through the visibly skewed matrices some
#: datasets ship (DESIGN.md: DAIR-V2X, "orthonormalise and warn") while refusing e.g. a scaled matrix.
WARN_TOL = 1e-2


def orthonormalise_checked(
    rotation: np.ndarray,
    *,
    silent_tol: float = SILENT_TOL,
    warn_tol: float = WARN_TOL,
    where: str = "rotation",
    warn: Callable[[str], None] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The nearest orthonormal matrices, after checking that the repair is small.

    The residual of a matrix is the largest absolute change of one of its entries by the repair
    (``max |R - R_repaired|``); a point at distance d moves by at most ``3 * residual * d``.
    Residual <= ``silent_tol``: float noise, repaired silently. ``silent_tol`` < residual <=
    ``warn_tol``: repaired, and ``warn`` is called with one line naming ``where`` and the residual.
    Residual > ``warn_tol`` (or a non-finite entry): rejected.

    Args:
        rotation: (..., 3, 3) nearly orthonormal matrices (proper or improper).
        silent_tol: largest residual repaired without a word (default :data:`SILENT_TOL`).
        warn_tol: largest residual repaired at all (default :data:`WARN_TOL`).
        where: what the matrices are, for messages: file and field, e.g. "calib/000000.txt R0_rect".
        warn: receives the warning line (a converter passes its report's ``warn``); None issues a
            :class:`RepairWarning` through :mod:`warnings`.

    Returns:
        (..., 3, 3) orthonormal matrices with the same determinant signs, and (...,) residuals.

    Raises:
        InputError: a residual above ``warn_tol``, a non-finite entry or a wrong shape.
    """
    rotation = np.asarray(rotation, dtype=np.float64)
    if rotation.shape[-2:] != (3, 3):
        raise InputError(f"{where}: expected rotation matrices of shape (..., 3, 3), got {rotation.shape}")
    if not np.all(np.isfinite(rotation)):
        raise InputError(f"{where}: expected a finite rotation matrix, got {_first_bad(rotation, rotation.shape[:-2])}")
    repaired = orthonormalize(rotation)
    residual = np.abs(repaired - rotation).max(axis=(-2, -1))
    _check_residual(residual, silent_tol, warn_tol, where, "rotation matrix", "orthonormalised", warn)
    return repaired, residual


def normalise_quat_checked(
    quat_wxyz: np.ndarray,
    *,
    silent_tol: float = SILENT_TOL,
    warn_tol: float = WARN_TOL,
    where: str = "quaternion",
    warn: Callable[[str], None] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Unit quaternions, after checking that their norms were already close to 1.

    The residual is ``|norm - 1|``; the tolerances act as in :func:`orthonormalise_checked`
    (silent up to ``silent_tol``, a warning up to ``warn_tol``, rejected beyond).

    Args:
        quat_wxyz: (..., 4) quaternions (w, x, y, z).
        silent_tol: largest residual normalised without a word.
        warn_tol: largest residual normalised at all.
        where: what the quaternions are, for messages (file and field).
        warn: receives the warning line; None issues a :class:`RepairWarning`.

    Returns:
        (..., 4) unit quaternions (signs kept) and (...,) residuals.

    Raises:
        InputError: a residual above ``warn_tol``, a non-finite component or a wrong shape.
    """
    quat_wxyz = np.asarray(quat_wxyz, dtype=np.float64)
    if quat_wxyz.shape[-1:] != (4,):
        raise InputError(f"{where}: expected quaternions of shape (..., 4), got {quat_wxyz.shape}")
    if not np.all(np.isfinite(quat_wxyz)):
        raise InputError(f"{where}: expected a finite quaternion, got {_first_bad(quat_wxyz, quat_wxyz.shape[:-1])}")
    norms = np.linalg.norm(quat_wxyz, axis=-1)
    residual = np.abs(norms - 1.0)
    _check_residual(residual, silent_tol, warn_tol, where, "quaternion", "normalised", warn)
    return quat_wxyz / norms[..., None], residual


class RepairWarning(UserWarning):
    """An input was repaired beyond float noise (but within the stated tolerance)."""


def _check_residual(
    residual: np.ndarray,
    silent_tol: float,
    warn_tol: float,
    where: str,
    what: str,
    repair: str,
    warn: Callable[[str], None] | None,
) -> None:
    if not residual.size or residual.max() <= silent_tol:
        return
    worst = int(np.argmax(residual))
    value = float(residual.reshape(-1)[worst])
    index = tuple(int(i) for i in np.unravel_index(worst, residual.shape))
    at = "" if not index else f" (entry {index[0] if len(index) == 1 else index})"
    if value > warn_tol:
        raise InputError(f"{where}{at}: expected a {what} within {warn_tol:g} of unit, got a residual of {value:.3g}")
    if value > silent_tol:
        message = f"{where}{at}: {what} {repair} (residual {value:.3g} > {silent_tol:g}, tolerance {warn_tol:g})"
        if warn is None:
            warnings.warn(message, RepairWarning, stacklevel=3)
        else:
            warn(message)


def _first_bad(values: np.ndarray, batch_shape: tuple[int, ...]) -> str:
    """The first non-finite matrix or vector of ``values``, for an error message."""
    flat = values.reshape((-1,) + values.shape[len(batch_shape):])
    bad = int(np.flatnonzero(~np.all(np.isfinite(flat.reshape(len(flat), -1)), axis=1))[0])
    return str(flat[bad].tolist())


def determinant(matrix: np.ndarray) -> np.ndarray:
    """(...,) determinants of (..., 3, 3) matrices by cofactor expansion along the first row.

    A few array operations for all of them: ``np.linalg.det`` goes through LAPACK, whose per-call
    overhead dominates for the one transform or few boxes a loader item has.
    """
    m = matrix.reshape(matrix.shape[:-2] + (9,))
    # m00 (m11 m22 - m12 m21) - m01 (m10 m22 - m12 m20) + m02 (m10 m21 - m11 m20)
    minors = m[..., [4, 3, 3]] * m[..., [8, 8, 7]] - m[..., [5, 5, 4]] * m[..., [7, 6, 6]]
    terms = m[..., :3] * minors
    det: np.ndarray = terms[..., 0] - terms[..., 1] + terms[..., 2]
    return det


def _require_proper(rotation: np.ndarray) -> None:
    if rotation.shape[-2:] != (3, 3):
        raise AvdataError(f"expected rotation matrices of shape (..., 3, 3), got {rotation.shape}")
    if rotation.shape == (3, 3):
        # One matrix (a writer converts one pose per message): the cofactor expansion of
        # :func:`determinant` in Python floats, ~20x less overhead than its array operations.
        (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = rotation.tolist()
        improper = m00 * (m11 * m22 - m12 * m21) - m01 * (m10 * m22 - m12 * m20) + m02 * (m10 * m21 - m11 * m20) < 0.0
    else:
        improper = bool(np.any(determinant(rotation) < 0.0))
    if improper:
        raise AvdataError(
            "expected a proper rotation (det +1), got an improper one (det -1): a reflection has no "
            "quaternion or Euler angles; express it as a Transform"
        )
