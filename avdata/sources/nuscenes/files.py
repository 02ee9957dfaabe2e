"""nuScenes lidar sweeps: ``.pcd.bin`` (Lyft: ``.bin``), 5 float32 per point.

Radar ``.pcd`` files are PCD files like any other: :func:`avdata.sources.pcd.decode_pcd` reads them.
"""

import numpy as np

from avdata.errors import InputError
from avdata.schema.limits import MAX_COORDINATE_M
from avdata.sources._checks import point_values_problem

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
