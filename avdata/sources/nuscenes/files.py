"""nuScenes sensor files: lidar ``.pcd.bin`` sweeps (5 float32 per point) and binary radar ``.pcd`` files."""



import numpy as np

from avdata.errors import InputError
from avdata.schema.scene_writer import MAX_COORDINATE_M
from avdata.sources._checks import coordinates_problem, point_values_problem

_PCD_TYPES = {
    ("F", 4): "<f4",
    ("F", 8): "<f8",
    ("I", 1): "i1",
    ("I", 2): "<i2",
    ("I", 4): "<i4",
    ("U", 1): "u1",
    ("U", 2): "<u2",
    ("U", 4): "<u4",
}



def read_pcd(data: bytes, source: str) -> np.ndarray:
    """Every field of a binary PCD file (nuScenes radar) as a packed little-endian structured array.

    Args:
        data: the file's bytes.
        source: file name for error messages.

    Returns:
        (N,) structured array with the header's FIELDS in order (x, y, z first in nuScenes radar);
        a field with COUNT k > 1 becomes k fields ``name_0 .. name_{k-1}``. A read-only view of
        ``data`` (no copy).
    """
    header: dict[str, list[str]] = {}
    offset = 0
    while True:
        end = data.find(b"\n", offset)
        if end < 0:
            raise InputError(f"{source}: expected a PCD header ending in a DATA line, got none")
        line = data[offset:end].decode("ascii", errors="replace").strip()
        offset = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        header[key.upper()] = values
        if key.upper() == "DATA":
            break
    if header["DATA"] != ["binary"]:
        raise InputError(f"{source}: expected PCD 'DATA binary', got 'DATA {' '.join(header['DATA'])}'")
    names = header.get("FIELDS", [])
    sizes = header.get("SIZE", [])
    types = header.get("TYPE", [])
    counts = header.get("COUNT", ["1"] * len(names))
    if not names or not (len(names) == len(sizes) == len(types) == len(counts)):
        raise InputError(f"{source}: expected FIELDS, SIZE, TYPE, COUNT of equal length, got {header}")
    dtype = []
    for name, size, kind, count in zip(names, sizes, types, counts, strict=True):
        code = _PCD_TYPES.get((kind.upper(), _header_int(size, source, "SIZE")))
        if code is None:
            raise InputError(f"{source}: field {name!r}: expected a PCD TYPE/SIZE among {sorted(_PCD_TYPES)}, got {kind}/{size}")
        n = _header_int(count, source, "COUNT")
        dtype.extend([(name, code)] if n == 1 else [(f"{name}_{i}", code) for i in range(n)])
    record = np.dtype(dtype)
    n_points = _header_int(header.get("POINTS", header.get("WIDTH", ["0"]))[0], source, "POINTS")
    if len(data) - offset < n_points * record.itemsize:
        raise InputError(f"{source}: expected {n_points} points of {record.itemsize} bytes, got {len(data) - offset} bytes")
    points: np.ndarray = np.frombuffer(data, dtype=record, count=n_points, offset=offset)
    if (problem := coordinates_problem(points, MAX_COORDINATE_M)) is not None:
        raise InputError(f"{source}: {problem}")
    return points


def _header_int(text: str, source: str, key: str) -> int:
    """A PCD header number (ASCII digits, as PCL writes them), else an InputError naming the key."""
    if not (text.isascii() and text.isdigit()) or len(text) > 12:
        raise InputError(f"{source}: PCD header {key}: expected a non-negative integer, got {text!r}")
    return int(text)


#: A nuScenes ``.pcd.bin`` / Lyft ``.bin`` point: 5 little-endian float32.
LIDAR_BIN_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("ring", "<f4")])


def read_lidar_bin(data: bytes, source: str) -> np.ndarray:
    """A ``.pcd.bin`` / Lyft ``.bin`` sweep: 5 float32 per point (x, y, z, intensity, ring).

    Returns:
        (N,) structured float32 x, y, z, intensity, ring: a read-only view of ``data`` (no copy), exactly as stored.
    """
    if len(data) % LIDAR_BIN_DTYPE.itemsize:
        raise InputError(f"{source}: expected a multiple of 20 bytes (5 float32 per point), got {len(data)} bytes")
    points = np.frombuffer(data, dtype=LIDAR_BIN_DTYPE)
    # x, y, z in metres, intensity 0..255, ring 0..31: all within the coordinate limit.
    problem = point_values_problem(points.view("<f4").reshape(-1, 5), LIDAR_BIN_DTYPE.names or (), MAX_COORDINATE_M)
    if problem is not None:
        raise InputError(f"{source}: {problem}")
    return points
