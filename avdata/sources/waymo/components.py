"""Waymo v2 component files: where they are, and reading them with pyarrow (no TensorFlow).

A v2 dataset folder holds one Parquet file per (component, context): ``<component>/<context>.parquet``,
optionally under split folders (``training/<component>/<context>.parquet``), on a disk or in an object store
(``s3://``, ``gs://``: found by one recursive listing, read by ranged requests of the columns asked for only,
each row group's selected column chunks fetched together). Columns are named
``key.<field>`` for the join keys and ``[<ComponentClass>].<field path>`` for values, as Waymo's
``v2.component`` writes them. Rows are not aligned across components: join on the key columns.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from avdata.errors import InputError, one_line
from avdata.inputs import refuse_special_file
from avdata.storage import FILE, SMALL_OBJECT_BYTES, Location, read_range, scrub

#: Component folder name -> the class name in its value columns (``[LiDARBoxComponent].box.center.x``).
COMPONENTS: dict[str, str] = {
    "vehicle_pose": "VehiclePoseComponent",
    "lidar": "LiDARComponent",
    "lidar_calibration": "LiDARCalibrationComponent",
    "lidar_pose": "LiDARPoseComponent",
    "lidar_box": "LiDARBoxComponent",
    "camera_image": "CameraImageComponent",
    "camera_calibration": "CameraCalibrationComponent",
    "camera_box": "CameraBoxComponent",
    "projected_lidar_box": "ProjectedLiDARBoxComponent",
    "stats": "StatsComponent",
}

#: ``v2.perception.lidar.LaserName``.
LASER_NAMES: dict[int, str] = {1: "TOP", 2: "FRONT", 3: "SIDE_LEFT", 4: "SIDE_RIGHT", 5: "REAR"}
#: ``v2.perception.camera_image.CameraName``.
CAMERA_NAMES: dict[int, str] = {1: "FRONT", 2: "FRONT_LEFT", 3: "FRONT_RIGHT", 4: "SIDE_LEFT", 5: "SIDE_RIGHT"}
#: ``v2.perception.box.BoxType``.
BOX_TYPES: dict[int, str] = {0: "TYPE_UNKNOWN", 1: "TYPE_VEHICLE", 2: "TYPE_PEDESTRIAN", 3: "TYPE_SIGN", 4: "TYPE_CYCLIST"}
#: Waymo box type -> unified class (Waymo's TYPE_VEHICLE covers cars, trucks and buses alike).
CLASS_MAP: dict[str, str] = {
    "TYPE_VEHICLE": "car",
    "TYPE_PEDESTRIAN": "pedestrian",
    "TYPE_CYCLIST": "cyclist",
    "TYPE_SIGN": "other",
    "TYPE_UNKNOWN": "other",
}

CONTEXT_KEY = "key.segment_context_name"
TIME_KEY = "key.frame_timestamp_micros"
#: The text columns of the components: keys by name, values by field name.
_TEXT_COLUMNS = (CONTEXT_KEY, "key.laser_object_id", "key.camera_object_id")
_TEXT_FIELDS = (".time_of_day", ".location", ".weather")


@dataclass(frozen=True, slots=True, kw_only=True)
class ComponentFile:
    """One ``<component>/<context>.parquet`` file.

    Attributes:
        component: the component folder name (a key of :data:`COMPONENTS`).
        context: the segment context name (the file's stem).
        path: the file (a :class:`~avdata.storage.Location` in an object store).
        split: the split folder it was found in ("" when the root holds the components directly).
    """

    component: str
    context: str
    path: Path | Location
    split: str = ""

    def column(self, field: str) -> str:
        """The full column name of a value field, e.g. ``box.center.x`` -> ``[LiDARBoxComponent].box.center.x``."""
        return f"[{COMPONENTS[self.component]}].{field}"


def find_component_files(root: Path | Location) -> dict[str, dict[str, ComponentFile]]:
    """Every component file under ``root``, grouped by context.

    Args:
        root: a folder (or a store prefix) holding ``<component>/`` folders, or split folders that hold them.

    Returns:
        context -> component -> file; contexts in sorted order.
    """
    found: dict[str, dict[str, ComponentFile]] = {}
    for split, component, path in _store_candidates(root) if isinstance(root, Location) else _local_candidates(Path(root)):
        by_component = found.setdefault(path.stem, {})
        if component in by_component:
            raise InputError(f"{path}: context {path.stem} also in {by_component[component].path}")
        by_component[component] = ComponentFile(component=component, context=path.stem, path=path, split=split)
    if not found:
        raise InputError(f"{root}: expected <component>/<context>.parquet files of {sorted(COMPONENTS)}, got none")
    return dict(sorted(found.items()))


def _missing_root(root: Path | Location) -> InputError:
    return InputError(f"{root}: expected a Waymo v2 folder of <component>/<context>.parquet files, got no folder")


def _local_candidates(root: Path) -> list[tuple[str, str, Path | Location]]:
    """(split, component, file) of every ``.parquet`` file in a component folder of a local ``root``."""
    if not root.is_dir():
        raise _missing_root(root)
    bases = [(root, "")] if any((root / c).is_dir() for c in COMPONENTS) else []
    bases += [(d, d.name) for d in sorted(root.iterdir()) if d.is_dir() and d.name not in COMPONENTS
              and any((d / c).is_dir() for c in COMPONENTS)]
    return [(split, component, path) for base, split in bases for component in COMPONENTS
            for path in sorted((base / component).glob("*.parquet"))]


def _store_candidates(root: Location) -> list[tuple[str, str, Path | Location]]:
    """:func:`_local_candidates` of a store prefix, from one recursive listing (one request per 1000 objects)."""
    listing = root.listing(recursive=True)
    if not listing:
        raise _missing_root(root)
    order = {component: k for k, component in enumerate(COMPONENTS)}
    candidates = []
    for name, info in listing.items():
        parts = name.split("/")  # [split,] component, file
        if (info.kind == FILE and len(parts) in (2, 3) and parts[-2] in COMPONENTS and parts[-1].endswith(".parquet")
                and not set(parts[:-2]) & set(COMPONENTS)):
            candidates.append(("/".join(parts[:-2]), parts[-2], name))
    candidates.sort(key=lambda c: (c[0], order[c[1]], c[2]))
    return [(split, component, root / name) for split, component, name in candidates]


def _open(file: ComponentFile) -> pq.ParquetFile:
    refuse_special_file(file.path)  # opening a FIFO waits for a writer
    stream = file.path.open_input() if isinstance(file.path, Location) else None  # one request: the object's size
    try:
        if stream is None:
            return pq.ParquetFile(file.path)
        if stream.size() <= SMALL_OBJECT_BYTES:
            return pq.ParquetFile(pa.BufferReader(read_range(stream, stream.size(), 0)))  # Arrow-owned bytes
        # Each read of the stream is one ranged request; pre-buffering fetches the selected column chunks of a row
        # group together (coalesced, in parallel) instead of one request per column chunk.
        return pq.ParquetFile(stream, pre_buffer=True)
    except Exception as error:  # noqa: BLE001 - damaged bytes make pyarrow raise SystemError, ... besides ArrowException
        raise InputError(f"{file.path}: expected a Parquet file, got an unreadable one ({scrub(one_line(error))})") from None


def _check_columns(file: ComponentFile, schema: pa.Schema, columns: Sequence[str]) -> None:
    missing = [c for c in columns if c not in schema.names]
    if missing:
        raise InputError(f"{file.path}: expected columns {missing} of component {file.component}, got none of them")
    # Waymo's keys are integers and its values numbers, lists or bytes, but for the few text columns: a column
    # of another type is refused here rather than failing as a TypeError deep in the conversion.
    for name in columns:
        kind = schema.field(name).type
        is_text = pa.types.is_string(kind) or pa.types.is_large_string(kind)
        if name in _TEXT_COLUMNS or name.endswith(_TEXT_FIELDS):
            if not is_text:  # an id of another type was an ArrowInvalid traceback
                raise InputError(f"{file.path}: column {name}: expected text, got type {kind}")
            continue
        if (name.startswith("key.") and not pa.types.is_integer(kind)) or is_text:
            raise InputError(f"{file.path}: column {name}: expected {'integers' if name.startswith('key.') else 'numbers'}"
                             f", got type {kind}")


def _check_context(file: ComponentFile, table: pa.Table | pa.RecordBatch) -> None:
    contexts = set(table.column(CONTEXT_KEY).to_pylist())
    if contexts - {file.context}:
        other = sorted(contexts - {file.context})
        raise InputError(f"{file.path}: {CONTEXT_KEY}: expected {file.context}, got {other[0]}")


def read_component(file: ComponentFile, columns: Sequence[str], optional: Sequence[str] = ()) -> pa.Table:
    """The named columns of a (small) component file, all rows, after checking every row's context.

    Args:
        file: the component file.
        columns: full column names; the context key is added.
        optional: full column names read too when the file has them (fields of later versions).
    """
    parquet = _open(file)
    present = set(parquet.schema_arrow.names)
    wanted = list(dict.fromkeys([CONTEXT_KEY, *columns, *(c for c in optional if c in present)]))
    _check_columns(file, parquet.schema_arrow, wanted)
    try:
        table = parquet.read(columns=wanted)
        table.validate(full=True)  # offsets and UTF-8 of damaged pages, which to_pylist would trip on later
    except Exception as error:  # noqa: BLE001 - damaged bytes make pyarrow raise SystemError, ... besides ArrowException
        raise InputError(f"{file.path}: expected a readable Parquet file, got ({scrub(one_line(error))})") from None
    _check_context(file, table)
    return table


def iter_component(file: ComponentFile, columns: Sequence[str], batch_rows: int = 4) -> Iterator[pa.RecordBatch]:
    """The named columns of a (large) component file, a few rows at a time (memory: one row group).

    Args:
        file: the component file.
        columns: full column names; the context key is added.
        batch_rows: rows per batch.
    """
    parquet = _open(file)
    wanted = list(dict.fromkeys([CONTEXT_KEY, *columns]))
    _check_columns(file, parquet.schema_arrow, wanted)
    try:
        for batch in parquet.iter_batches(batch_size=batch_rows, columns=wanted):
            batch.validate(full=True)  # offsets and UTF-8 of damaged pages, which to_pylist would trip on later
            _check_context(file, batch)
            yield batch
    except InputError:
        raise
    except Exception as error:  # noqa: BLE001 - damaged bytes make pyarrow raise SystemError, ... besides ArrowException
        raise InputError(f"{file.path}: expected a readable Parquet file, got ({scrub(one_line(error))})") from None
