"""Waymo v2 component files read from a store path: what pyarrow is given to parse."""

from __future__ import annotations

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from avdata.sources.waymo.components import ComponentFile, read_component
from avdata.storage import location
from tests.realdata import REALDATA

POSES = REALDATA / "waymo_v2" / "vehicle_pose" / "10023947602400723454_1120_000_1140_000.parquet"


def test_a_small_store_object_reaches_arrow_as_arrow_memory_never_python_bytes(monkeypatch: pytest.MonkeyPatch) -> None:
    # A small object is fetched whole and parsed from memory, on Arrow's thread pool: Python bytes there would be
    # released by a pool worker, which takes the GIL and aborts the process during interpreter exit. A file://
    # location takes the store path.
    sources = []
    buffer_reader = pa.BufferReader
    monkeypatch.setattr(pa, "BufferReader", lambda source: sources.append(type(source)) or buffer_reader(source))
    file = ComponentFile(component="vehicle_pose", context=POSES.stem, path=location(f"file://{POSES}"))
    column = file.column("world_from_vehicle.transform")
    table = read_component(file, [column])
    assert sources == [pa.Buffer]
    assert table.num_rows == 199 and table.column(column).equals(pq.read_table(POSES).column(column))
