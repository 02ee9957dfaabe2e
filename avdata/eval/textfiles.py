"""Numbers from text result files, with errors that name the file, line, field and value."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from avdata.errors import InputError
from avdata.inputs import c_floats

__all__ = ["parse_numbers", "require_finite", "require_integers", "require_within"]


def parse_numbers(path: Path, line: int, fields: list[str], names: tuple[str, ...]) -> list[float]:
    """The fields of one line as floats; a non-numeric one is an error naming file, line, field and value.

    Args:
        path: the file.
        line: 1-based line number.
        fields: (F,) field texts.
        names: (F,) field names.

    Returns:
        (F,) values.
    """
    values = []
    for text, name in zip(fields, names, strict=True):
        try:
            # As C readers (the KITTI devkit's sscanf) take numbers: '1_000' or non-ASCII digits are damage.
            values.extend(c_floats([text]))
        except ValueError:
            raise InputError(f"{path}:{line}: {name}: expected a number, got {text!r}") from None
    return values


def require_finite(path: Path, line_numbers: np.ndarray, values: np.ndarray, names: tuple[str, ...]) -> None:
    """Refuses NaN and infinite values, naming the file, line, field and value of the first one.

    Args:
        path: the file the values come from.
        line_numbers: (N,) 1-based line of each row.
        values: (N, F) parsed values.
        names: (F,) field names.
    """
    bad = ~np.isfinite(values)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise InputError(f"{path}:{line_numbers[row]}: {names[col]}: expected a finite number, got {values[row, col]}")


def require_integers(path: Path, line_numbers: np.ndarray, values: np.ndarray, names: tuple[str, ...]) -> None:
    """Refuses values that are not integers below 2^31 in magnitude, naming the file, line, field and value.

    A frame ``0.5`` or a track id ``1e300`` would otherwise be truncated or wrapped into another one.

    Args:
        path: the file the values come from.
        line_numbers: (N,) 1-based line of each row.
        values: (N, F) finite parsed values.
        names: (F,) field names.
    """
    bad = (values != np.round(values)) | (np.abs(values) >= 2**31)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise InputError(f"{path}:{line_numbers[row]}: {names[col]}: expected an integer, got {values[row, col]:g}")


def require_within(path: Path, line_numbers: np.ndarray, values: np.ndarray, names: tuple[str, ...],
                   limit: float) -> None:
    """Refuses finite values beyond ``limit`` in magnitude, naming the file, line, field and value of the first.

    Args:
        path: the file the values come from.
        line_numbers: (N,) 1-based line of each row.
        values: (N, F) finite parsed values.
        names: (F,) field names.
        limit: the largest magnitude allowed.
    """
    bad = np.abs(values) > limit
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise InputError(f"{path}:{line_numbers[row]}: {names[col]}: expected a value within {limit:g}, "
                         f"got {values[row, col]:g}")
