"""Transcendental functions whose bits do not depend on the CPU: generated scenes and their index are made with them.

numpy picks its loops for ``arctan2``, ``arcsin``, ``arctan``, ``exp``, ``log``, ``tan``, ``power`` and complex
``exp`` by the instruction sets it finds at import (e.g. AVX-512 vs AVX2), and those loops differ in the last bits
(``docs/determinism.md``), so a scene generated from the same seed had other bytes on another CPU. These functions
are built only from operations IEEE 754 rounds exactly (``+ - * /``, ``sqrt``, ``floor``, ``ldexp``, comparisons)
and from numpy's float64 ``sin``/``cos``, which give the same bits under every x86-64 dispatch target. Each numpy call
is one rounded operation (numpy never fuses a multiply and an add across calls), so the result is the same on every
x86-64 CPU. The rational approximations are Cephes' (S. L. Moshier); the results are within 3 ulp of numpy's (tested).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

_F64 = npt.NDArray[np.float64]

_TAN_PI_8 = 0.41421356237309504880
_MOREBITS = 6.123233995736765886130e-17  # pi / 2 - float64(pi / 2)
_ATAN_P = (-8.750608600031904122785e-01, -1.615753718733365076637e+01, -7.500855792314704667340e+01,
           -1.228866684490136173410e+02, -6.485021904942025371773e+01)
_ATAN_Q_MONIC = (1.0, 2.485846490142306297962e+01, 1.650270098316988542046e+02, 4.328810604912902668951e+02,
                 4.853903996359136964868e+02, 1.945506571482613964425e+02)
_EXP_P = (1.26177193074810590878e-4, 3.02994407707441961300e-2, 9.99999999999999999910e-1)
_EXP_Q = (3.00198505138664455042e-6, 2.52448340349684104192e-3, 2.27265548208155028766e-1, 2.00000000000000000009e0)
_LOG2E = 1.4426950408889634073599
_LN2_HI = 6.93145751953125e-1
_LN2_LO = 1.42860682030941723212e-6


def _polynomial(z: _F64, coefficients: tuple[float, ...]) -> _F64:
    """Horner's rule, highest power first, one rounding per operation."""
    result = z * coefficients[0] + coefficients[1]
    for c in coefficients[2:]:
        result *= z
        result += c
    return result


def _arctan_unit(a: _F64) -> _F64:
    """Arctangent of float64 values in [0, 1], reduced to |t| <= tan(pi / 8): atan(a) = pi / 4 + atan((a - 1) / (a + 1))."""
    big = a > _TAN_PI_8
    t = np.where(big, (a - 1.0) / (a + 1.0), a)
    z = t * t
    p = _polynomial(z, _ATAN_P)
    p *= z
    p /= _polynomial(z, _ATAN_Q_MONIC)
    p *= t
    p += t
    return np.where(big, p + (0.5 * _MOREBITS) + np.pi / 4, p)


def arctan(x: npt.ArrayLike) -> _F64:
    """``np.arctan`` of float64 values, the same bits on every CPU."""
    x = np.asarray(x, dtype=np.float64)
    return arctan2(x, np.ones_like(x))


def arctan2(y: npt.ArrayLike, x: npt.ArrayLike) -> _F64:
    """``np.arctan2`` of float64 values, the same bits on every CPU (0 for y = x = 0).

    Folded into the first octant: a = min(|x|, |y|) / max(|x|, |y|) in [0, 1], then unfolded by the
    signs and which of |x|, |y| was larger.
    """
    y_f64: _F64 = np.asarray(y, dtype=np.float64)
    x_f64: _F64 = np.asarray(x, dtype=np.float64)
    if y_f64.shape != x_f64.shape:
        y_f64, x_f64 = np.broadcast_arrays(y_f64, x_f64)
    ax, ay = np.abs(x_f64), np.abs(y_f64)
    steep = ay > ax
    low, high = np.minimum(ax, ay), np.maximum(ax, ay)
    # high is 0 only where both are: 0 / 1 gives angle 0 there (two infinities give nan; no caller has them).
    folded = _arctan_unit(low / np.where(high == 0.0, 1.0, high))
    # Unfolded as a head and the tail that pi / 2 and pi lose in float64, added last.
    head: _F64 = np.where(steep, np.pi / 2 - folded, folded)
    tail: _F64 = np.where(steep, _MOREBITS, 0.0)
    behind = x_f64 < 0.0
    head = np.where(behind, np.pi - head, head)
    tail = np.where(behind, 2 * _MOREBITS - tail, tail)
    return np.copysign(head + tail, y_f64)


def arcsin(x: npt.ArrayLike) -> _F64:
    """``np.arcsin`` of float64 values in [-1, 1], the same bits on every CPU."""
    x = np.asarray(x, dtype=np.float64)
    return arctan2(x, np.sqrt((1.0 - x) * (1.0 + x)))


def exp(x: npt.ArrayLike) -> _F64:
    """``np.exp`` of float64 values in about [-700, 700], the same bits on every CPU."""
    x = np.asarray(x, dtype=np.float64)
    n = np.floor(_LOG2E * x + 0.5)
    r = x - n * _LN2_HI - n * _LN2_LO
    rr = r * r
    p = r * _polynomial(rr, _EXP_P)
    e = 1.0 + 2.0 * (p / (_polynomial(rr, _EXP_Q) - p))
    return np.ldexp(e, n.astype(np.int32))


def wrap_angle(angle_rad: npt.ArrayLike) -> _F64:
    """Angles wrapped into [-pi, pi] (``np.angle(np.exp(1j * a))``), the same bits on every CPU."""
    angle_rad = np.asarray(angle_rad, dtype=np.float64)
    return arctan2(np.sin(angle_rad), np.cos(angle_rad))
