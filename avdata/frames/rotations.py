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
    # alone would add all of scipy to a conversion's peak memory. Tested against scipy. Loaders call this for
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

    Shepperd's method, vectorised (the per-call overhead of scipy's ``from_matrix`` dominated
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
    quat = terms[rows[:, None], _SHEPPERD_TERMS[case]] / s[:, None]
    quat[rows, case] = 0.25 * s
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    quat = np.where(quat[:, :1] < 0.0, -quat, quat)
    result: np.ndarray = quat.reshape(rotation.shape[:-2] + (4,))
    return result


def _quat_wxyz_single(rotation: np.ndarray) -> np.ndarray:
    """Shepperd's method for one matrix with Python floats.

    A small fraction of the array path's per-call overhead, which matters because writers convert one pose per
    message. The largest of the four candidates picks the divisor (the first on a tie, as the array path's argmax).
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


# The one rotation / quaternion rule for every source. Sources print rotations and quaternions with a
# few digits, so they are off by float noise; some (re-calibrated DAIR-V2X matrices) are off by more:
#
# ================================  ==================  ====================  ==================
# deviation                         below 1e-6          1e-6 .. 1e-2          above 1e-2
# ================================  ==================  ====================  ==================
# rotation: max |R^T R - I|         repaired silently   repaired, warning     rejected (error)
# quaternion: | |q| - 1 |           normalised silently normalised, warning   rejected (error)
# ================================  ==================  ====================  ==================
#
# A rotation is repaired to the nearest rotation (SVD polar factor); one with determinant <= 0 (a
# reflection or a singular matrix) and any non-finite value is rejected. Callers name the file, the
# key or token and pass the message on, so that only the record holding the value is lost.

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



def orthonormalize_checked(
    rotation: np.ndarray, *, where: str = "rotation", warn: Callable[[str], None] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The nearest rotations to (..., 3, 3) matrices, by the one rule (:func:`repaired_rotation`, vectorised).

    Args:
        rotation: (..., 3, 3) nearly orthonormal matrices.
        where: what the matrices are, for messages: file and field, e.g. "calib/000000.txt R0_rect".
        warn: receives the warning line (a converter passes its report's ``warn``); None issues a
            :class:`RepairWarning` through :mod:`warnings`.

    Returns:
        (..., 3, 3) rotations and (...,) deviations max |R^T R - I|.

    Raises:
        InputError: a deviation above :data:`REPAIR_TOLERANCE`, a non-finite entry, det <= 0 or a wrong shape.
    """
    rotation = np.asarray(rotation, dtype=np.float64)
    if rotation.shape[-2:] != (3, 3):
        raise InputError(f"{where}: expected rotation matrices of shape (..., 3, 3), got {rotation.shape}")
    deviation = rotation_deviation(rotation)
    _check_deviation(deviation, where, "a rotation (max |R^T R - I|", "rotation off orthonormality",
                     "replaced by the nearest rotation", warn)
    return orthonormalize(rotation), deviation


def normalize_quat_checked(
    quat_wxyz: np.ndarray, *, where: str = "quaternion", warn: Callable[[str], None] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Unit quaternions by the one rule (:func:`repaired_quaternions`): silent, warned or rejected on | |q| - 1 |.

    Args:
        quat_wxyz: (..., 4) quaternions (w, x, y, z).
        where: what the quaternions are, for messages (file and field).
        warn: receives the warning line; None issues a :class:`RepairWarning`.

    Returns:
        (..., 4) unit quaternions (signs kept) and (...,) deviations.

    Raises:
        InputError: a deviation above :data:`REPAIR_TOLERANCE`, a non-finite component or a wrong shape.
    """
    quat_wxyz = np.asarray(quat_wxyz, dtype=np.float64)
    if quat_wxyz.shape[-1:] != (4,):
        raise InputError(f"{where}: expected quaternions of shape (..., 4), got {quat_wxyz.shape}")
    deviation = quaternion_deviation(quat_wxyz)
    _check_deviation(deviation, where, "a unit quaternion (| |q| - 1 |", "quaternion off unit norm", "normalised", warn)
    return quat_wxyz / np.linalg.norm(quat_wxyz, axis=-1)[..., None], deviation


class RepairWarning(UserWarning):
    """An input was repaired beyond float noise (but within the stated tolerance)."""


def _check_deviation(
    deviation: np.ndarray, where: str, expected: str, off: str, repair: str, warn: Callable[[str], None] | None
) -> None:
    """Raises for the worst deviation above :data:`REPAIR_TOLERANCE`; warns for one above :data:`SILENT_TOLERANCE`."""
    if not deviation.size or deviation.max() <= SILENT_TOLERANCE:
        return
    worst = int(np.argmax(deviation))
    value = float(deviation.reshape(-1)[worst])
    index = tuple(int(i) for i in np.unravel_index(worst, deviation.shape))
    at = "" if not index else f" (entry {index[0] if len(index) == 1 else index})"
    if not value <= REPAIR_TOLERANCE:
        detail = "finite values with det > 0" if not np.isfinite(value) else f"deviation {value:.3g}"
        raise InputError(f"{where}{at}: expected {expected} <= {REPAIR_TOLERANCE:g}), got {detail}")
    message = f"{where}{at}: {off} by {value:.3g} (> {SILENT_TOLERANCE:g}); {repair}"
    if warn is None:
        warnings.warn(message, RepairWarning, stacklevel=3)
    else:
        warn(message)


#: Flattened entries of the three 2x2 minors of :func:`determinant` (index arrays made once: a list
#: index is converted to an array on every call).
_MINOR_A, _MINOR_B, _MINOR_C, _MINOR_D = (np.array(i) for i in ([4, 3, 3], [8, 8, 7], [5, 5, 4], [7, 6, 6]))


def determinant(matrix: np.ndarray) -> np.ndarray:
    """(...,) determinants of (..., 3, 3) matrices by cofactor expansion along the first row.

    A few array operations for all of them: ``np.linalg.det`` goes through LAPACK, whose per-call
    overhead dominates for the one transform or few boxes a loader item has.
    """
    m = matrix.reshape(matrix.shape[:-2] + (9,))
    # m00 (m11 m22 - m12 m21) - m01 (m10 m22 - m12 m20) + m02 (m10 m21 - m11 m20)
    minors = m[..., _MINOR_A] * m[..., _MINOR_B] - m[..., _MINOR_C] * m[..., _MINOR_D]
    terms = m[..., :3] * minors
    det: np.ndarray = terms[..., 0] - terms[..., 1] + terms[..., 2]
    return det


def _require_proper(rotation: np.ndarray) -> None:
    if rotation.shape[-2:] != (3, 3):
        raise AvdataError(f"expected rotation matrices of shape (..., 3, 3), got {rotation.shape}")
    if rotation.shape == (3, 3):
        # One matrix (a writer converts one pose per message): the cofactor expansion of
        # :func:`determinant` in Python floats, a small fraction of its array operations' per-call overhead.
        (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = rotation.tolist()
        improper = m00 * (m11 * m22 - m12 * m21) - m01 * (m10 * m22 - m12 * m20) + m02 * (m10 * m21 - m11 * m20) < 0.0
    else:
        improper = bool(np.any(determinant(rotation) < 0.0))
    if improper:
        raise AvdataError(
            "expected a proper rotation (det +1), got an improper one (det -1): a reflection has no "
            "quaternion or Euler angles; express it as a Transform"
        )
