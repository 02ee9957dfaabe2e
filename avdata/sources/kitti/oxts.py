"""KITTI oxts packets (30 values per line) and raw ``timestamps.txt`` files."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np

from avdata.errors import InputError


def read_oxts_lines(path: Path, lines: list[str]) -> np.ndarray:
    """(T, 30) oxts packets from text lines (lat, lon, alt, roll, pitch, yaw, vn, ve, vf, ...)."""
    out = np.empty((len(lines), 30), dtype=np.float64)
    for i, line in enumerate(lines):
        fields = line.split()
        if len(fields) != 30:
            raise InputError(f"{path}: line {i + 1}: expected 30 oxts values, got {len(fields)}")
        try:
            out[i] = [float(v) for v in fields]
        except ValueError as error:
            raise InputError(f"{path}: line {i + 1}: expected numbers, got {line.strip()!r}") from error
    return out


def read_timestamps(path: Path) -> np.ndarray:
    """(T,) int64 ns from a raw ``timestamps.txt`` ("2011-09-26 13:02:25.967790592"), read exactly.

    The files carry no time zone; they are read as UTC.
    """
    try:
        lines = [line.strip() for line in path.read_text().splitlines() if line.strip()]
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(f"{path}: unreadable ({error})") from error
    out = np.empty(len(lines), dtype=np.int64)
    for i, line in enumerate(lines):
        try:
            whole, _, fraction = line.partition(".")
            seconds = dt.datetime.strptime(whole, "%Y-%m-%d %H:%M:%S").replace(tzinfo=dt.timezone.utc).timestamp()
            if not fraction.isdigit() or len(fraction) > 9:
                raise ValueError(fraction)
        except ValueError as error:
            raise InputError(f"{path}: line {i + 1}: expected 'YYYY-MM-DD HH:MM:SS.fffffffff', got {line!r}") from error
        out[i] = int(seconds) * 1_000_000_000 + int(fraction.ljust(9, "0"))
    return out


