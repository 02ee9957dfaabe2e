"""overlapping_pairs against a brute-force search, on both sorting paths."""

import numpy as np
import pytest

from avdata.eval.matching import overlapping_pairs, stable_int_order


def _brute_force(g_frame, g_box, d_frame, d_box):
    same = g_frame[:, None] == d_frame[None, :]
    x = (d_box[None, :, 0] <= g_box[:, None, 2]) & (d_box[None, :, 2] >= g_box[:, None, 0])
    y = (d_box[None, :, 1] <= g_box[:, None, 3]) & (d_box[None, :, 3] >= g_box[:, None, 1])
    return set(zip(*np.nonzero(same & x & y), strict=True))


def _boxes(rng, n, n_frames):
    frame = np.sort(rng.integers(0, n_frames, n))
    x0y0 = rng.uniform(0, 300, (n, 2)).round(0)  # whole numbers: boxes that touch, shared edges
    size = rng.uniform(-5, 60, (n, 2)).round(0)  # some degenerate (zero or negative width)
    return frame, np.c_[x0y0, x0y0 + size]


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("n_frames", [1, 7, 70_000])  # 70k frames: the wide-key sort path
def test_pairs_equal_brute_force(seed, n_frames):
    rng = np.random.default_rng(seed)
    g_frame, g_box = _boxes(rng, 300, n_frames)
    d_frame, d_box = _boxes(rng, 350, n_frames)
    if n_frames == 70_000:  # put many boxes into few frames so that pairs exist
        g_frame, d_frame = g_frame % 5 * 14_000 + 69_000 // 5, d_frame % 5 * 14_000 + 69_000 // 5
        g_order, d_order = np.argsort(g_frame, kind="stable"), np.argsort(d_frame, kind="stable")
        g_frame, g_box, d_frame, d_box = g_frame[g_order], g_box[g_order], d_frame[d_order], d_box[d_order]
        d_frame[-1] = 69_999
    pg, pd = overlapping_pairs(g_frame, g_box, d_frame, d_box)
    found = list(zip(pg.tolist(), pd.tolist(), strict=True))
    assert len(found) == len(set(found))
    assert np.all(np.diff(pg) >= 0)
    # The search may add pairs apart by less than 1e-6 of the x extent; these whole-number boxes have none.
    assert set(found) == _brute_force(g_frame, g_box, d_frame, d_box)


@pytest.mark.parametrize("bound", [3, 65_536, 65_537, 1 << 40])
def test_stable_int_order_is_numpys_stable_argsort(bound):
    keys = np.random.default_rng(0).integers(0, min(bound, 1 << 40), 5000)
    np.testing.assert_array_equal(stable_int_order(keys, bound), np.argsort(keys, kind="stable"))
