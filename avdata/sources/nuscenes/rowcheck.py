"""Checks of nuScenes-schema rows: the fields each table's rows must have, one row at a time or a chunk at once.

:func:`row_problem` names the first thing wrong with a row; :func:`rows_valid` is the same check a column at a
time, for the chunks (almost all) in which nothing is wrong.
"""

import itertools
import json
import math
import operator
from collections.abc import Callable
from typing import Any

import numpy as np

from avdata.frames.rotations import REPAIR_TOLERANCE, SILENT_TOLERANCE, quaternion_message, repaired_quaternions
from avdata.schema.limits import MAX_BOX_SIZE_M, MAX_COORDINATE_M
from avdata.sources.nuscenes.jsonio import RepeatedKeyRecord

__all__ = ["OPTIONAL", "SCHEMA", "repaired_rotation_field", "row_problem", "rows_valid"]

#: The fields each table's rows must have, and their kinds (checked record by record; others are optional).
SCHEMA: dict[str, dict[str, str]] = {
    "scene": {"token": "token", "name": "str", "log_token": "token"},
    "log": {"token": "token"},
    "sensor": {"token": "token", "channel": "str", "modality": "str"},
    "calibrated_sensor": {"token": "token", "sensor_token": "token", "translation": "vec3", "rotation": "quat"},
    "category": {"token": "token", "name": "str"},
    "attribute": {"token": "token", "name": "str"},
    "visibility": {"token": "token", "level": "str"},
    "instance": {"token": "token", "category_token": "token"},
    "sample": {"token": "token", "scene_token": "token", "timestamp": "time_us"},
    "ego_pose": {"token": "token", "translation": "vec3", "rotation": "quat"},
    "sample_data": {"token": "token", "sample_token": "token", "ego_pose_token": "token",
                    "calibrated_sensor_token": "token", "timestamp": "time_us", "is_key_frame": "bool",
                    "filename": "str"},
    "sample_annotation": {"token": "token", "sample_token": "token", "instance_token": "token",
                          "translation": "vec3", "size": "size3", "rotation": "quat", "attribute_tokens": "tokens"},
    "map": {"token": "token", "log_tokens": "tokens"},
}
#: Optional fields, checked when present (the converter turns them into integers).
OPTIONAL: dict[str, dict[str, str]] = {
    "sample_data": {"width": "size_px", "height": "size_px"},
    "sample_annotation": {"num_lidar_pts": "count", "num_radar_pts": "count"},
    "map": {"filename": "str"},
}
_EXPECTED = {
    "size_px": "null or an integer in 0 .. 2**31",
    "count": "an integer in -1 .. 2**31",
    "token": "a non-empty string",
    "str": "a string",
    "number": "a finite number",
    "time_us": "microseconds in 0 .. 9.2e15 (int64 nanoseconds)",
    "bool": "true or false",
    "vec3": f"3 finite numbers within {MAX_COORDINATE_M:g} m",
    "size3": f"3 finite numbers in 0 .. {MAX_BOX_SIZE_M:g} m",
    "quat": f"a unit quaternion (w, x, y, z) (| |q| - 1 | <= {REPAIR_TOLERANCE:g})",
    "tokens": "a list of strings",
}


_MAX_TIME_US = (2**63 - 1) // 1000


def _is_number(value: Any) -> bool:
    return (type(value) is float and math.isfinite(value)) or type(value) is int


def _is_token(value: Any) -> bool:
    return type(value) is str and value != ""


def _is_vector(value: Any, size: int) -> bool:
    return type(value) is list and len(value) == size and all(map(_is_number, value))


def _norm_deviation(quat: list[float]) -> float:
    """| |q| - 1 | in plain Python: this runs once per row of the big tables, where numpy's per-call cost dominates."""
    return abs(math.sqrt(sum(v * v for v in quat)) - 1.0)


#: kind -> check; plain Python, because it runs once per field of every row of the big tables.
_CHECKS: dict[str, Callable[[Any], bool]] = {
    "size_px": lambda value: value is None or (type(value) is int and 0 <= value < 2**31),
    "count": lambda value: type(value) is int and -1 <= value < 2**31,
    "token": _is_token,
    "str": lambda value: type(value) is str,
    "number": _is_number,
    # Times become int64 nanoseconds (x 1000): anything that cannot is refused here, not overflowed later.
    "time_us": lambda value: _is_number(value) and 0 <= value < _MAX_TIME_US,
    "bool": lambda value: type(value) is bool,
    "tokens": lambda value: type(value) is list and all(type(v) is str for v in value),
    # The scene writer's magnitude limits: a row beyond them is refused here, costing only that row.
    "vec3": lambda value: _is_vector(value, 3) and max(map(abs, value)) <= MAX_COORDINATE_M,
    "size3": lambda value: _is_vector(value, 3) and 0.0 <= min(value) and max(value) <= MAX_BOX_SIZE_M,
    "quat": lambda value: _is_vector(value, 4) and _norm_deviation(value) <= REPAIR_TOLERANCE,
}
_MISSING = object()


def row_problem(table: str, row: dict[str, Any]) -> tuple[str | None, str | None]:
    """(error, warning) of one row against :data:`SCHEMA`.

    The error names the first field missing or of the wrong kind; the warning a quaternion to be normalised
    beyond float noise (:func:`repaired_rotation_field` does it). Messages read
    ``<table> <token>: field 'x': expected ..., got ...``.
    """
    schema = SCHEMA[table]
    optional = OPTIONAL.get(table, {})
    if isinstance(row, RepeatedKeyRecord):
        key, first, other = row.repeated
        return (f"{_row_name(table, row)}: field {key!r}: expected it once, got it twice with different values "
                f"({json.dumps(first)[:40]} and {json.dumps(other)[:40]})"), None
    for field, kind in (*schema.items(), *optional.items()):
        value = row.get(field, _MISSING)
        if (value is _MISSING and field not in optional) or (value is not _MISSING and not _CHECKS[kind](value)):
            got = "none" if value is _MISSING else json.dumps(value)[:80]
            return f"{_row_name(table, row)}: field {field!r}: expected {_EXPECTED[kind]}, got {got}", None
    if schema.get("rotation") == "quat" and _norm_deviation(row["rotation"]) > _CHUNK_QUAT_DEVIATION:
        # Near the threshold the one rule decides, with its own measure (the plain-Python one only screens).
        quaternion = np.asarray(row["rotation"], dtype=np.float64)
        if repaired_quaternions(quaternion)[1][0]:
            return None, f"{table} {row['token']}: field 'rotation': {quaternion_message(quaternion, rejected=False)}"
    return None, None


def repaired_rotation_field(row: dict[str, Any]) -> None:
    """Normalises ``row["rotation"]`` in place by the one rule (:func:`~avdata.frames.rotations.repaired_quaternions`).

    Called for the rows whose :func:`row_problem` warning says "normalised", so that the value is repaired
    where it is reported and nothing downstream (``Boxes3D``) repairs and warns a second time.
    """
    unit, _, _ = repaired_quaternions(np.asarray(row["rotation"], dtype=np.float64))
    row["rotation"] = unit[0].tolist()


def _row_name(table: str, row: dict[str, Any]) -> str:
    """``<table> <token>`` for messages (``(no token)`` when the row has none)."""
    token = row.get("token")
    return f"{table} {token if isinstance(token, str) else '(no token)'}"


#: Rows whose | |q| - 1 | is below this pass the chunk check; the rest get :func:`row_problem`'s own
#: (a margin below :data:`SILENT_TOLERANCE`, so float-order differences cannot hide a warning).
_CHUNK_QUAT_DEVIATION = SILENT_TOLERANCE / 2
#: Times at or above this (near 2**53, where int -> float rounds) get :func:`row_problem`'s own check.
_CHUNK_MAX_TIME_US = 9.0e15
_NUMBER_TYPES = frozenset({int, float})


def rows_valid(table: str, rows: list[Any]) -> bool:
    """Whether every row of ``rows`` passes :func:`row_problem` with neither error nor warning.

    The same checks a column at a time (``set(map(type, ...))`` and numpy, C loops instead of a Python
    call per field of each row); False when anything is or might be off (then each row goes through
    :func:`row_problem`, which names the problem). True only when :func:`row_problem` would return
    (None, None) for every row.
    """
    if set(map(type, rows)) != {dict}:
        return False
    optional = OPTIONAL.get(table, {})
    try:
        for field, kind in SCHEMA[table].items():
            if not _column_valid(kind, list(map(operator.itemgetter(field), rows))):
                return False
        for field, kind in optional.items():
            values = map(operator.methodcaller("get", field, _MISSING), rows)
            if not _column_valid(kind, [value for value in values if value is not _MISSING]):
                return False
    except (KeyError, OverflowError, ValueError, TypeError):
        return False  # a field missing, an integer beyond float64 ...: row_problem decides
    return True


def _column_valid(kind: str, values: list[Any]) -> bool:
    """Whether every value passes ``_CHECKS[kind]`` (and a quaternion needs no warning), checked as a column."""
    if not values:
        return True
    types = set(map(type, values))
    if kind in ("token", "str"):
        return types == {str} and (kind == "str" or "" not in values)
    if kind == "bool":
        return types == {bool}
    if kind == "tokens":
        return types == {list} and set(map(type, itertools.chain.from_iterable(values))) <= {str}
    if kind in ("size_px", "count"):
        numbers = [value for value in values if value is not None] if kind == "size_px" else values
        if not set(map(type, numbers)) <= {int}:
            return False
        integers = np.asarray(numbers, dtype=np.int64)
        return bool(np.all((integers >= (0 if kind == "size_px" else -1)) & (integers < 2**31)))
    if kind == "time_us":
        if not types <= _NUMBER_TYPES:
            return False
        times = np.asarray(values, dtype=np.float64)
        return bool(np.all((times >= 0.0) & (times < _CHUNK_MAX_TIME_US)))
    size = {"vec3": 3, "size3": 3, "quat": 4}[kind]
    if types != {list} or set(map(len, values)) != {size}:
        return False
    flat = list(itertools.chain.from_iterable(values))
    if not set(map(type, flat)) <= _NUMBER_TYPES:
        return False
    array = np.asarray(flat, dtype=np.float64).reshape(-1, size)
    if not np.all(np.isfinite(array)):
        return False
    if kind == "vec3":
        return bool(np.all(np.abs(array) <= MAX_COORDINATE_M))
    if kind == "size3":
        return bool(np.all((array >= 0.0) & (array <= MAX_BOX_SIZE_M)))
    if kind == "quat":
        # The squares summed left to right, as _norm_deviation does.
        squares = array * array
        norms = np.sqrt(((squares[:, 0] + squares[:, 1]) + squares[:, 2]) + squares[:, 3])
        return bool(np.all(np.abs(norms - 1.0) <= _CHUNK_QUAT_DEVIATION))
    return True

