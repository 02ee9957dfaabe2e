"""The column-at-a-time check of nuScenes rows (``rows_valid``) never passes a row that ``row_problem`` objects to.

Real inputs: the Lyft tables in ../shared/realdata/nuscenes_schema/lyft (nuScenes schema, float-microsecond
timestamps). Every field of a real row of each checked table is replaced by values of each wrong kind;
whenever the chunk check passes a row, the row-by-row check must find neither an error nor a warning, and
every real row must pass it (so the fast path is the one the conversion takes).
"""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import pytest

from avdata.sources.nuscenes import NuScenesTables
from avdata.sources.nuscenes.rowcheck import OPTIONAL, SCHEMA, row_problem, rows_valid
from tests.realdata import REALDATA

LYFT = REALDATA / "nuscenes_schema" / "lyft" / "v1.01-train" / "v1.01-train"
_ABSENT = object()
#: Values of every kind a field can wrongly hold, plus near-misses of each check's bounds.
WRONG = [_ABSENT, None, "", "x", 0, 1, -1, -2, True, False, 1.5, float("nan"), float("inf"), -0.0, 10**400, 2**31,
         2**63, 9.3e15, 9_223_372_036_854_775, [], ["a"], [1, 2], [1, 2, 3], [1.0, 2.0, -3.0], [1, "2", 3],
         [1.0, float("nan"), 3.0], [10**400, 0, 0], [True, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [1.0, 1e-7, 0.0, 0.0],
         [1.0, 2e-3, 0.0, 0.0], [1.0, 0.5, 0.0, 0.0], [1, 0, 0, 0], [0.0, 0.0, 0.0, 0.0], {"a": 1},
         # Finite but beyond the writer's limits (box side 1 km, coordinate 1e7 m), and just within them.
         [1e30, 2.0, 1.5], [1000.5, 2.0, 1.5], [1000.0, 2.0, 1.5], [2e7, 0.0, 0.0], [-1e7, 0.0, 0.0]]


def real_rows(table: str) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = json.loads((LYFT / f"{table}.json").read_text())
    return rows


@pytest.mark.parametrize("table", sorted(SCHEMA))
def test_every_real_row_passes_the_chunk_check(table: str) -> None:
    rows = real_rows(table)
    clean = [row for row in rows if row_problem(table, row) == (None, None)]
    assert clean, f"no clean {table} row in the real sample"
    assert rows_valid(table, clean)
    assert rows_valid(table, rows) == (len(clean) == len(rows))


@pytest.mark.parametrize("table", sorted(SCHEMA))
def test_a_row_the_chunk_check_passes_has_no_problem(table: str) -> None:
    base = next(row for row in real_rows(table) if row_problem(table, row) == (None, None))
    fields = [*SCHEMA[table], *OPTIONAL.get(table, {})]
    n_refused = 0
    for field in fields:
        for value in WRONG:
            row = copy.deepcopy(base)
            if value is _ABSENT:
                row.pop(field, None)
            else:
                row[field] = value
            passed = rows_valid(table, [base, row])
            if passed:
                assert row_problem(table, row) == (None, None), (field, value)
            else:
                n_refused += 1
            if row_problem(table, row) != (None, None):
                assert not passed, (field, value)
    assert n_refused >= len(fields) * 10  # the wrong kinds are refused, not just tolerated
    assert not rows_valid(table, [base, ["not an object"]])


def test_tables_with_a_bad_row_in_a_chunk_report_it_and_keep_the_rest(tmp_path: Path) -> None:
    for path in LYFT.glob("*.json"):
        (tmp_path / path.name).write_text(path.read_text())
    rows = real_rows("sample_data")
    broken = copy.deepcopy(rows[3])
    broken["timestamp"] = "soon"
    (tmp_path / "sample_data.json").write_text(json.dumps(rows[:3] + [broken] + rows[4:]))
    good, bad = NuScenesTables(LYFT), NuScenesTables(tmp_path)
    assert len(bad.sample_data["time_ns"]) == len(good.sample_data["time_ns"]) - 1
    messages = [message for problems in bad.problems.values() for _, message in problems]
    assert any(f"sample_data {broken['token']}: field 'timestamp'" in m and '"soon"' in m for m in messages)
