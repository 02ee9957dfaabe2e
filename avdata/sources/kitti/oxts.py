"""KITTI oxts packets (30 values per line) and raw ``timestamps.txt`` files."""

from __future__ import annotations

import datetime as dt
import math
from pathlib import Path

import numpy as np

from avdata.errors import InputError
from avdata.inputs import c_floats, read_text_bytes
from avdata.schema.limits import MAX_COORDINATE_M, MAX_SPEED_MPS, MAX_TIME_NS
from avdata.storage import Location

#: The 30 values of an oxts packet (KITTI raw devkit, dataformat.txt).
_OXTS_FIELDS = ("lat", "lon", "alt", "roll", "pitch", "yaw", "vn", "ve", "vf", "vl", "vu", "ax", "ay", "az", "af",
                "al", "au", "wx", "wy", "wz", "wf", "wl", "wu", "pos_accuracy", "vel_accuracy", "navstat",
                "numsats", "posmode", "velmode", "orimode")

#: Largest |value| of the values a pose or its extrapolation is made of (beyond: damage, not a position): the
#: ranges of dataformat.txt for the angles (rad; +1e-6 for the printed digits of pi), the globe for latitude and
#: longitude (deg), and avdata.schema.limits for altitude (m) and velocities (m/s).
_OXTS_LIMITS = {0: (90.0, "90 deg"), 1: (180.0, "180 deg"), 2: (MAX_COORDINATE_M, f"{MAX_COORDINATE_M:g} m"),
                3: (math.pi + 1e-6, "pi"), 4: (math.pi / 2 + 1e-6, "pi/2"), 5: (math.pi + 1e-6, "pi"),
                **{k: (MAX_SPEED_MPS, f"{MAX_SPEED_MPS:g} m/s") for k in range(6, 11)}}


def oxts_packet_problem(line: str) -> str | None:
    """Why one oxts text line is not a packet of 30 finite numbers (None if it is)."""
    fields = line.split()
    if len(fields) != 30:
        return f"expected 30 oxts values, got {len(fields)}"
    try:
        values = c_floats(fields)
    except ValueError:
        return f"expected numbers, got {line.strip()!r}"
    bad = [k for k, v in enumerate(values) if not math.isfinite(v)]
    if bad:
        return f"value {bad[0] + 1} ({_OXTS_FIELDS[bad[0]]}): expected a finite number, got {fields[bad[0]]!r}"
    for k, (limit, shown) in _OXTS_LIMITS.items():
        if abs(values[k]) > limit:
            return f"value {k + 1} ({_OXTS_FIELDS[k]}): expected a value within +-{shown}, got {fields[k]!r}"
    return None


def read_oxts_lines(path: Path | Location, lines: list[str]) -> np.ndarray:
    """(T, 30) oxts packets from text lines (lat, lon, alt, roll, pitch, yaw, vn, ve, vf, ...).

    Raises:
        InputError: a line is not 30 finite numbers (naming the file and line).
    """
    for i, line in enumerate(lines):
        problem = oxts_packet_problem(line)
        if problem is not None:
            raise InputError(f"{path}: line {i + 1}: {problem}")
    return np.array([[float(v) for v in line.split()] for line in lines], dtype=np.float64).reshape(-1, 30)


def read_oxts_file(path: Path | Location) -> tuple[np.ndarray, list[tuple[int, str]]]:
    """A tracking ``oxts/0001.txt``: one packet per non-blank line, each line checked on its own.

    Returns:
        (T, 30) packets, NaN rows for unreadable lines; and (line number, why) per unreadable line.

    Raises:
        InputError: the file cannot be read at all.
    """
    data = read_text_bytes(path)  # a FIFO or a 10 GB file is refused before reading
    rows: list[list[float]] = []
    problems: list[tuple[int, str]] = []
    for number, raw in enumerate(data.splitlines(), start=1):
        try:
            line = raw.decode("utf-8")
        except UnicodeDecodeError:
            line = ""
            problem: str | None = f"expected UTF-8 text, got {raw[:60]!r}"
        else:
            if not line.strip():
                continue
            problem = oxts_packet_problem(line)
        if problem is not None:
            problems.append((number, problem))
            rows.append([math.nan] * 30)
        else:
            rows.append([float(v) for v in line.split()])
    return np.array(rows, dtype=np.float64).reshape(-1, 30), problems


def read_timestamps(path: Path | Location) -> tuple[np.ndarray, dict[int, str]]:
    """(T,) int64 ns from a raw ``timestamps.txt`` ("2011-09-26 13:02:25.967790592"), read exactly, and its bad lines.

    The files carry no time zone; they are read as UTC. A line that does not parse costs its own frame:
    it is returned as line index -> message, and its time is the latest good time before it (int64 min
    when none), so that the times stay non-decreasing and the caller's order checks see no step there.

    Raises:
        InputError: the file is not UTF-8 text.
    """
    try:
        lines = [line.strip() for line in read_text_bytes(path).decode().splitlines() if line.strip()]
    except UnicodeDecodeError as error:
        raise InputError(f"{path}: unreadable ({error})") from error
    out = np.empty(len(lines), dtype=np.int64)
    bad: dict[int, str] = {}
    latest = np.iinfo(np.int64).min
    for i, line in enumerate(lines):
        try:
            whole, _, fraction = line.partition(".")
            seconds = dt.datetime.strptime(whole, "%Y-%m-%d %H:%M:%S").replace(tzinfo=dt.timezone.utc).timestamp()
            if not (fraction.isascii() and fraction.isdigit()) or len(fraction) > 9:
                raise ValueError(fraction)
        except ValueError:
            bad[i] = f"line {i + 1}: expected 'YYYY-MM-DD HH:MM:SS.fffffffff', got {line!r}"
            out[i] = latest
            continue
        time_ns = int(seconds) * 1_000_000_000 + int(fraction.ljust(9, "0"))
        if not 0 <= time_ns <= MAX_TIME_NS:  # int64 nanoseconds since 1970: 1677 or 2300 would overflow
            bad[i] = f"line {i + 1}: expected a time from 1970 to 2262, got {line!r}"
            out[i] = latest
            continue
        out[i] = time_ns
        latest = max(latest, int(out[i]))
    return out, bad
