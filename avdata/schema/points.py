"""Point-cloud layouts: numpy dtypes <-> Foxglove ``PackedElementField`` types, and packing columns into points.

Shared by the scene writer (which packs clouds) and the scene reader (which maps them back to numpy).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField

from avdata.errors import AvdataError

#: numpy dtype -> Foxglove PackedElementField numeric type.
NUMERIC_TYPES: dict[np.dtype, Any] = {
    np.dtype(np.uint8): PackedElementField.UINT8,
    np.dtype(np.int8): PackedElementField.INT8,
    np.dtype(np.uint16): PackedElementField.UINT16,
    np.dtype(np.int16): PackedElementField.INT16,
    np.dtype(np.uint32): PackedElementField.UINT32,
    np.dtype(np.int32): PackedElementField.INT32,
    np.dtype(np.float32): PackedElementField.FLOAT32,
    np.dtype(np.float64): PackedElementField.FLOAT64,
}


def pack_points(fields: Mapping[str, np.ndarray] | np.ndarray) -> np.ndarray:
    """A packed little-endian structured array from named columns (or one already packed).

    Args:
        fields: ordered mapping name -> (N,) array, starting with x, y, z; or a structured array.

    Returns:
        (N,) structured array without padding, fields in the given order.
    """
    if isinstance(fields, np.ndarray) and fields.dtype.names:
        packed = fields
    else:
        names = list(fields)
        columns = [np.asarray(fields[name]) for name in names]
        n = columns[0].shape[0] if columns else 0
        packed = np.empty(n, dtype=[(name, col.dtype.newbyteorder("<")) for name, col in zip(names, columns, strict=True)])
        for name, column in zip(names, columns, strict=True):
            if column.shape != (n,):
                raise AvdataError(f"expected point field {name!r} of shape ({n},), got {column.shape}")
            packed[name] = column
    if packed.dtype not in _CHECKED_LAYOUTS:
        _check_layout(packed.dtype)
    return packed


#: Point layouts :func:`_check_layout` accepted: a scene's clouds share one or two, and checking costs a few
#: microseconds per cloud.
_CHECKED_LAYOUTS: set[np.dtype] = set()


def _check_layout(point_dtype: np.dtype) -> None:
    """Adds ``point_dtype`` to :data:`_CHECKED_LAYOUTS`: a point layout, x, y, z first, of little-endian numbers.

    Raises:
        AvdataError: it is not one.
    """
    packed_names = point_dtype.names or ()
    layout: Mapping[str, Any] = point_dtype.fields or {}
    if packed_names[:3] != ("x", "y", "z"):
        raise AvdataError(f"expected point fields to start with x, y, z, got {list(packed_names)}")
    for name in packed_names:
        dtype = layout[name][0]
        if dtype.newbyteorder("=") not in NUMERIC_TYPES or dtype.byteorder == ">":
            raise AvdataError(f"expected point field {name!r} of a little-endian numeric type, got {dtype}")
    _CHECKED_LAYOUTS.add(point_dtype)
