"""Argoverse 2 detection tables (the av2-api's 3D detection submission), read row by row.

A feather table with one row per box: ``log_id``, ``timestamp_ns`` (the lidar sweep's time),
``category`` (an AV2 category; the unified class via :func:`conventions.unified_class`), ``tx_m, ty_m,
tz_m`` (box centre in the ego frame at that time), ``length_m, width_m, height_m``, ``qw, qx, qy, qz``
(the box's rotation in the ego frame, scalar first) and ``score`` (a probability). These are already the
unified conventions: the boxes are in the AV2 converter's ``ego`` frame, size (l, w, h), quaternion (w, x, y, z).

A row with a null, a negative time, a non-finite or absurd number, a size <= 0, a quaternion off unit
norm beyond the tolerance of :mod:`avdata.frames.rotations` or a score outside [0, 1] costs that row, with
one line naming the file, the row, the column and the value; a missing column or an unreadable file is one
:class:`InputError`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from avdata.sources.argoverse2.files import Rows, _checked_rows, read_row_columns

__all__ = ["DETECTION_COLUMNS", "read_av2_detections"]

#: The columns read (name -> numpy type); other columns are ignored.
DETECTION_COLUMNS: dict[str, str] = {
    "log_id": "str", "timestamp_ns": "int64", "category": "str", "tx_m": "float64", "ty_m": "float64",
    "tz_m": "float64", "length_m": "float64", "width_m": "float64", "height_m": "float64", "qw": "float64",
    "qx": "float64", "qy": "float64", "qz": "float64", "score": "float64",
}


def read_av2_detections(path: Path | str) -> tuple[Rows, list[str]]:
    """Reads an AV2 detection table; each bad row costs itself.

    Args:
        path: the feather file.

    Returns:
        (the usable rows as :class:`Rows` (``columns`` of :data:`DETECTION_COLUMNS`, ``repaired`` warnings),
        one problem line per dropped row: file, row, column, value).

    Raises:
        InputError: the file is unreadable or lacks a column.
    """
    path = Path(path)
    columns, nulls = read_row_columns(path, DETECTION_COLUMNS)
    problem = list(nulls)
    score = columns["score"]
    for row in np.flatnonzero(~((score >= 0.0) & (score <= 1.0))).tolist():
        problem[row] = problem[row] or f"column 'score': expected a probability in [0, 1], got {score[row]}"
    rows = _checked_rows(columns, problem=problem)
    return rows, [f"{path}: {line}" for line in rows.dropped]
