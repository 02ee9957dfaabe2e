"""``avdata.portable_math``: numpy's values to within 3 ulp, and the same bits under every numpy dispatch target."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from avdata import portable_math

ROOT = Path(__file__).resolve().parents[1]
RNG = np.random.default_rng(7)
X = np.concatenate([RNG.uniform(-4.0, 4.0, 50_000), RNG.normal(0.0, 1e4, 5_000), RNG.normal(0.0, 1e-6, 5_000),
                    [0.0, -0.0, 0.66, -0.66, 2.414213562373095, 1.0, -1.0, 1e300, -1e300]])
Y = RNG.permutation(X)


def ulps(got: np.ndarray, want: np.ndarray) -> float:
    return float(np.max(np.abs(got - want) / np.spacing(np.abs(want))))


def test_values_are_numpys_within_three_ulp():
    assert ulps(portable_math.arctan(X), np.arctan(X)) <= 3
    finite = (X != 0.0) | (Y != 0.0)
    assert ulps(portable_math.arctan2(Y[finite], X[finite]), np.arctan2(Y[finite], X[finite])) <= 3
    u = np.clip(X / 4.0, -1.0, 1.0)
    assert ulps(portable_math.arcsin(u), np.arcsin(u)) <= 3
    e = RNG.uniform(-700.0, 700.0, 50_000)
    assert ulps(portable_math.exp(e), np.exp(e)) <= 3
    angle = X[np.abs(X) < 1e3]
    np.testing.assert_allclose(portable_math.wrap_angle(angle), np.angle(np.exp(1j * angle)), rtol=0, atol=4e-13)


def test_quadrants_and_axes_are_numpys():
    y = np.array([0.0, 1.0, -1.0, 0.0, 1.0, -1.0, 1.0, -1.0, 3.0])
    x = np.array([1.0, 0.0, 0.0, -1.0, -1.0, -1.0, 1.0, 1.0, -1e-300])
    np.testing.assert_array_equal(portable_math.arctan2(y, x), np.arctan2(y, x))
    assert portable_math.arctan2(0.0, 0.0) == 0.0
    assert portable_math.arcsin(np.array([1.0, -1.0])).tolist() == [np.pi / 2, -np.pi / 2]
    assert portable_math.exp(np.array([0.0]))[0] == 1.0


def test_the_same_bits_with_numpys_avx512_and_avx2_loops_turned_off():
    script = ("import hashlib, numpy as np; from avdata import portable_math as m; from tests.test_portable_math import X, Y;"
              "print(hashlib.sha256(b''.join(f(*a).tobytes() for f, a in ((m.arctan2, (Y, X)), (m.arcsin, (np.clip(X, -1, 1),)),"
              " (m.exp, (np.clip(X, -700, 700),)), (m.wrap_angle, (X,))))).hexdigest())")
    digests = set()
    for disabled in ("", "AVX512_SPR AVX512_ICL X86_V4", "AVX512_SPR AVX512_ICL X86_V4 X86_V3"):
        env = {**os.environ, "PYTHONPATH": str(ROOT), "NPY_DISABLE_CPU_FEATURES": disabled}
        digests.add(subprocess.run([sys.executable, "-c", script], env=env, check=True, capture_output=True,
                                   text=True).stdout)
    assert len(digests) == 1
