"""PCD (PCL point cloud) files, read in one place: ASCII, binary and binary_compressed, any field types.

The decoding is ``pypcd4``'s (header parsing, PCL's column-wise LZF layout of binary_compressed, the
numpy dtype of every SIZE/TYPE pair); this module adds what a trustworthy reader needs on top: every
failure becomes one :class:`~avdata.errors.InputError` naming the file, the header field or the value;
the number of points must equal ``POINTS`` (= WIDTH x HEIGHT), a binary payload must not be short and a
binary_compressed block must hold exactly POINTS points, so neither a truncated file nor a damaged header
is read as a smaller cloud.

The real files this is tested against (``tests/sources/test_pcd.py``): DAIR-V2X vehicle side
(binary_compressed, ``x y z intensity timestamp`` as F4 F4 F4 U1 F8), DAIR-V2X infrastructure side
(binary_compressed, four F4) and OPV2V/V2XSet (ASCII, ``x y z rgb`` with the colour packed in a float);
nuScenes radar (binary, 18 fields of F4/I1/I2) in ``tests/converters/test_nuscenes.py``.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from pypcd4.pypcd4 import MetaData
from pypcd4.pypcd4 import PointCloud as _PypcdCloud

from avdata.errors import InputError, one_line
from avdata.inputs import read_regular_file
from avdata.schema.limits import MAX_COORDINATE_M
from avdata.sources._checks import coordinates_problem
from avdata.storage import Location

#: Header keys without which a PCD cannot be decoded (VERSION, COUNT, HEIGHT, VIEWPOINT have defaults).
_REQUIRED_KEYS = ("FIELDS", "SIZE", "TYPE", "WIDTH", "POINTS", "DATA")
_MAX_HEADER_LINES = 64


def read_pcd(path: str | Path | Location) -> np.ndarray:
    """The points of a PCD file as a structured array, one named field per PCD field (see :func:`decode_pcd`).

    Raises:
        InputError: the file is missing or unreadable, or :func:`decode_pcd` refuses its bytes.
    """
    path = path if isinstance(path, Location) else Path(path)
    try:
        raw = read_regular_file(path)  # a FIFO is refused, not waited on
    except OSError as error:
        raise InputError(f"{path}: cannot read PCD file ({error.strerror or error})") from None
    return decode_pcd(raw, str(path))


def decode_pcd(raw: bytes, source: str | Path) -> np.ndarray:
    """The points of a PCD file's bytes as a structured array, one named field per PCD field.

    Args:
        raw: the whole file (header and data).
        source: the file's name, first in every error message.

    Returns:
        (N,) structured array in the file's field order and types (little-endian); a field with
        COUNT k > 1 becomes k fields ``name__0000`` ... (pypcd4's naming).

    Raises:
        InputError: the header is malformed, the data does not hold exactly POINTS points, or an x, y
            or z is not finite or beyond the coordinate limit (a damaged value).
    """
    header_lines, data_start = _split_header(raw, source)
    try:
        metadata = MetaData.parse_header(header_lines)
    except ValueError as error:  # pydantic's ValidationError is a ValueError
        first = str(error).splitlines()
        raise InputError(f"{source}: malformed PCD header ({first[1] if len(first) > 1 else first[0]})") from None
    if metadata.width * metadata.height != metadata.points:
        raise InputError(f"{source}: header POINTS: expected WIDTH x HEIGHT = {metadata.width * metadata.height}, "
                         f"got {metadata.points}")
    try:
        # FIELDS x y z over SIZE/TYPE/COUNT of four fields read 16-byte binary points as 12-byte ones, without a word.
        if not len(metadata.fields) == len(metadata.size) == len(metadata.type) == len(metadata.count):
            raise ValueError("counts differ")
        dtype = metadata.build_dtype()
    except (KeyError, IndexError, ValueError) as error:  # SIZE 2 of TYPE F, 3 sizes of 4 fields, a name twice
        raise InputError(f"{source}: PCD header FIELDS {' '.join(metadata.fields)} SIZE {' '.join(map(str, metadata.size))} "
                         f"TYPE {' '.join(metadata.type)} COUNT {' '.join(map(str, metadata.count))}: expected one size, "
                         f"type and count per field, a known type and unique names ({one_line(error)})") from None
    payload = raw[data_start:]
    expected_bytes = metadata.points * dtype.itemsize
    if metadata.data.value == "binary" and len(payload) < expected_bytes:
        raise InputError(f"{source}: binary data: expected {metadata.points} points x {dtype.itemsize} bytes = "
                         f"{expected_bytes} bytes, got {len(payload)}")
    if metadata.data.value == "binary_compressed" and len(payload) >= 8:
        # PCL's block header: compressed and uncompressed sizes. A POINTS too small for the block would read
        # as a smaller (or empty) cloud without a word.
        uncompressed = int.from_bytes(payload[4:8], "little")
        compressed = int.from_bytes(payload[0:4], "little")
        if compressed > len(payload) - 8:  # a block past the end of the file: truncated, or a damaged size
            raise InputError(f"{source}: binary_compressed data: expected the compressed block of {compressed} bytes "
                             f"within the file, got {len(payload) - 8} bytes after its sizes")
        if uncompressed != expected_bytes:
            raise InputError(f"{source}: binary_compressed data: header POINTS {metadata.points} x {dtype.itemsize} "
                             f"bytes = {expected_bytes} bytes, but the compressed block holds {uncompressed}")
    try:
        cloud = _PypcdCloud.from_fileobj(io.BytesIO(raw))  # type: ignore[arg-type]  # pypcd4 types the file as BufferedReader, reads any binary file
        points = cloud.pc_data
    except (ValueError, RuntimeError, TypeError, OSError, IndexError) as error:
        raise InputError(f"{source}: cannot decode {metadata.data.value} PCD data ({error})") from None
    except Exception as error:  # python-neo-lzf raises its own error types for a corrupt stream
        raise InputError(f"{source}: cannot decode {metadata.data.value} PCD data ({type(error).__name__}: {error})") from None
    if len(points) != metadata.points:
        raise InputError(f"{source}: data: expected POINTS {metadata.points} points, got {len(points)}")
    points = np.ascontiguousarray(points)
    if (problem := coordinates_problem(points, MAX_COORDINATE_M)) is not None:
        raise InputError(f"{source}: {problem}")
    return points


def _split_header(raw: bytes, path: str | Path) -> tuple[list[str], int]:
    """(header lines, offset of the first data byte); the header ends with the DATA line."""
    lines: list[str] = []
    offset = 0
    for _ in range(_MAX_HEADER_LINES):
        end = raw.find(b"\n", offset)
        if end < 0:
            break
        try:
            line = raw[offset:end].decode("ascii").strip()
        except UnicodeDecodeError:
            raise InputError(f"{path}: PCD header line {len(lines) + 1}: expected ASCII text, got binary bytes") from None
        offset = end + 1
        lines.append(line)
        if line.upper().startswith("DATA"):
            present = {entry.split(maxsplit=1)[0].upper() for entry in lines if entry and not entry.startswith("#")}
            missing = [key for key in _REQUIRED_KEYS if key not in present]
            if missing:
                raise InputError(f"{path}: PCD header: expected fields {missing}, got none")
            return lines, offset
    raise InputError(f"{path}: PCD header: expected a DATA line within the first {_MAX_HEADER_LINES} lines, got none")
