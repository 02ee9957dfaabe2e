"""``avdata.sources.nuscenes``: the devkit's ``box_velocity`` and the row schema checks."""

from __future__ import annotations

import json
import math

import numpy as np

from avdata.sources.nuscenes import box_velocity
from avdata.sources.nuscenes.rowcheck import SCHEMA, row_problem
from tests.realdata import REALDATA

LYFT_TABLES = (REALDATA / "nuscenes_schema" / "lyft"
               / "v1.01-train" / "v1.01-train")


def devkit_box_velocity(first: dict, last: dict, current_has_prev: bool, current_has_next: bool) -> np.ndarray:
    """nuscenes-devkit 1.2.0 ``NuScenes.box_velocity`` body, written out for one annotation."""
    if not current_has_prev and not current_has_next:
        return np.array([np.nan, np.nan, np.nan])
    pos_last = np.array(last["translation"])
    pos_first = np.array(first["translation"])
    pos_diff = pos_last - pos_first
    time_last = 1e-6 * last["timestamp"]
    time_first = 1e-6 * first["timestamp"]
    time_diff = time_last - time_first
    max_time_diff = 1.5 * (2 if current_has_prev and current_has_next else 1)
    if time_diff > max_time_diff:
        return np.array([np.nan, np.nan, np.nan])
    return pos_diff / time_diff


def test_box_velocity_matches_the_devkit_body_bit_for_bit():
    rng = np.random.default_rng(7)
    n = 400
    first = rng.normal(scale=50.0, size=(n, 3))
    last = first + rng.normal(scale=2.0, size=(n, 3))
    t_first = 1532402927647951 + rng.integers(0, 10**7, size=n)
    t_last = t_first + rng.integers(1, 4 * 10**6, size=n)
    has_prev = rng.random(n) < 0.6
    has_next = rng.random(n) < 0.6
    got = box_velocity(first, last, t_first, t_last, has_prev, has_next)
    for i in range(n):
        expected = devkit_box_velocity({"translation": first[i].tolist(), "timestamp": int(t_first[i])},
                                       {"translation": last[i].tolist(), "timestamp": int(t_last[i])},
                                       bool(has_prev[i]), bool(has_next[i]))
        np.testing.assert_array_equal(got[i], expected)
    assert np.isnan(got[~has_prev & ~has_next]).all()
    assert np.isfinite(got[(has_prev & has_next) & (t_last - t_first <= 3 * 10**6)]).all()


def test_real_lyft_rows_pass_the_schema():
    for table in SCHEMA:
        for row in json.loads((LYFT_TABLES / f"{table}.json").read_text()):
            assert row_problem(table, row) == (None, None), (table, row["token"])


def test_row_problems_name_token_field_and_value():
    row = json.loads((LYFT_TABLES / "sample_annotation.json").read_text())[0]
    token = row["token"]
    assert row_problem("sample_annotation", {**row, "size": [1.0, -2.0, 3.0]})[0] == (
        f"sample_annotation {token}: field 'size': expected 3 finite numbers in 0 .. 1000 m, got [1.0, -2.0, 3.0]")
    assert row_problem("sample_annotation", {**row, "translation": [1, 2]})[0] == (
        f"sample_annotation {token}: field 'translation': expected 3 finite numbers within 1e+07 m, got [1, 2]")
    assert row_problem("sample_annotation", {**row, "attribute_tokens": None})[0] == (
        f"sample_annotation {token}: field 'attribute_tokens': expected a list of strings, got null")
    error, warning = row_problem("sample_annotation", {**row, "rotation": [v * (1 + 1e-4) for v in row["rotation"]]})
    assert error is None and warning is not None and "off unit norm by 0.0001" in warning
    assert row_problem("sample", {"token": "x", "scene_token": "s", "timestamp": math.inf})[0] == (
        "sample x: field 'timestamp': expected microseconds in 0 .. 9.2e15 (int64 nanoseconds), got Infinity")
    assert row_problem("sample", {"token": "x", "scene_token": "s", "timestamp": 1e300})[0] == (
        "sample x: field 'timestamp': expected microseconds in 0 .. 9.2e15 (int64 nanoseconds), got 1e+300")
