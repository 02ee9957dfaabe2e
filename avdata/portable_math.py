"""Transcendental functions whose bits do not depend on the CPU: generated scenes and their index are made with them.

numpy picks its loops for ``arctan2``, ``arcsin``, ``arctan``, ``exp``, ``log``, ``tan``, ``power`` and complex
``exp`` by the instruction sets it finds at import (e.g. AVX-512 vs AVX2), and those loops differ in the last bits
(``docs/determinism.md``), so a scene generated from the same seed had other bytes on another CPU. These functions
are built only from operations IEEE 754 rounds exactly (``+ - * /``, ``sqrt``, ``floor``, ``ldexp``, comparisons)
and from numpy's float64 ``sin``/``cos``, which give the same bits under every x86-64 dispatch target. Each numpy call
is one rounded operation (numpy never fuses a multiply and an add across calls), so the result is the same on every
x86-64 CPU. The rational approximations are Cephes' (S. L. Moshier), accurate to about 2 ulp (tested against numpy).
"""

from __future__ import annotations

import numpy as np

_T3P8 = 2.41421356237309504880  # tan(3 pi / 8)
_MOREBITS = 6.123233995736765886130e-17  # pi / 2 - float64(pi / 2)
_ATAN_P = (-8.750608600031904122785e-01, -1.615753718733365076637e+01, -7.500855792314704667340e+01,
           -1.228866684490136173410e+02, -6.485021904942025371773e+01)
_ATAN_Q = (1.0, 2.485846490142306297962e+01, 1.650270098316988542046e+02, 4.328810604912902668951e+02,
           4.853903996359136964868e+02, 1.945506571482613964425e+02)
_EXP_P = (1.26177193074810590878e-4, 3.02994407707441961300e-2, 9.99999999999999999910e-1)
_EXP_Q = (3.00198505138664455042e-6, 2.52448340349684104192e-3, 2.27265548208155028766e-1, 2.00000000000000000009e0)
_LOG2E = 1.4426950408889634073599
_LN2_HI = 6.93145751953125e-1
_LN2_LO = 1.42860682030941723212e-6


def _polynomial(z: np.ndarray, coefficients: tuple[float, ...]) -> np.ndarray:
    """Horner's rule, highest power first, one rounding per operation."""
    result = np.full_like(z, coefficients[0])
    for c in coefficients[1:]:
        result = result * z + c
    return result


def arctan(x: np.ndarray) -> np.ndarray:
    """``np.arctan`` of float64 values, the same bits on every CPU."""
    x = np.asarray(x, dtype=np.float64)
    ax = np.abs(x)
    big = ax > _T3P8
    mid = (ax > 0.66) & ~big
    with np.errstate(divide="ignore", invalid="ignore"):
        # Arguments reduced to |r| <= 0.66 around 0, 1 and infinity: atan(x) = pi/4 + atan((x - 1) / (x + 1)),
        # = pi/2 - atan(1 / x).
        r = np.where(big, -1.0 / ax, np.where(mid, (ax - 1.0) / (ax + 1.0), ax))
    base = np.where(big, np.pi / 2, np.where(mid, np.pi / 4, 0.0))
    extra = np.where(big, _MOREBITS, np.where(mid, 0.5 * _MOREBITS, 0.0))
    z = r * r
    z = z * _polynomial(z, _ATAN_P) / _polynomial(z, _ATAN_Q)
    z = r * z + r
    return np.copysign(base + (z + extra), x)


def arctan2(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``np.arctan2`` of finite float64 values, the same bits on every CPU (0 for y = x = 0)."""
    y, x = np.broadcast_arrays(np.asarray(y, dtype=np.float64), np.asarray(x, dtype=np.float64))
    zero_x = x == 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        angle = arctan(y / np.where(zero_x, 1.0, x))
    angle = np.where(x < 0.0, angle + np.where(y >= 0.0, np.pi, -np.pi), angle)
    return np.where(zero_x, np.where(y == 0.0, 0.0, np.copysign(np.pi / 2, y)), angle)


def arcsin(x: np.ndarray) -> np.ndarray:
    """``np.arcsin`` of float64 values in [-1, 1], the same bits on every CPU."""
    x = np.asarray(x, dtype=np.float64)
    return arctan2(x, np.sqrt((1.0 - x) * (1.0 + x)))


def exp(x: np.ndarray) -> np.ndarray:
    """``np.exp`` of float64 values in about [-700, 700], the same bits on every CPU."""
    x = np.asarray(x, dtype=np.float64)
    n = np.floor(_LOG2E * x + 0.5)
    r = x - n * _LN2_HI - n * _LN2_LO
    rr = r * r
    p = r * _polynomial(rr, _EXP_P)
    e = 1.0 + 2.0 * (p / (_polynomial(rr, _EXP_Q) - p))
    return np.ldexp(e, n.astype(np.int32))


def wrap_angle(angle_rad: np.ndarray) -> np.ndarray:
    """Angles wrapped into [-pi, pi] (``np.angle(np.exp(1j * a))``), the same bits on every CPU."""
    angle_rad = np.asarray(angle_rad, dtype=np.float64)
    return arctan2(np.sin(angle_rad), np.cos(angle_rad))
