"""Argoverse 2 sensor-dataset files: the log layout and one reader per file kind.

A log folder (``<split>/<log_id>/``) holds, as av2-api's ``AV2SensorDataLoader`` reads them::

    annotations.feather                     cuboids (val/train only), egovehicle frame at the sweep time
    city_SE3_egovehicle.feather             ego poses in the city frame (lidar and camera times)
    calibration/egovehicle_SE3_sensor.feather   sensor poses in the egovehicle frame
    calibration/intrinsics.feather          pinhole intrinsics + radial distortion k1, k2, k3
    sensors/lidar/<timestamp_ns>.feather    one motion-compensated sweep (two stacked lidars)
    sensors/cameras/<camera>/<timestamp_ns>.jpg
    map/log_map_archive_*.json, *_ground_height_surface____*.npy, *___img_Sim2_city.json

Every reader checks the columns it needs and their types and raises :class:`InputError` naming the
file, the column and what it found; a truncated or damaged feather file fails in pyarrow's own
checks and is reported the same way. Columns come back as numpy arrays (no pandas). A file may be an
object in a store (:class:`~avdata.storage.Location`): a feather object is then fetched whole when every
column of it is read, otherwise its footer and the buffers of the columns read only.
"""

from __future__ import annotations

import fnmatch
import re
from collections.abc import Collection
from dataclasses import dataclass

import numpy as np
import pyarrow as pa
import pyarrow.ipc as ipc

from avdata.errors import InputError, one_line
from avdata.frames.rotations import quaternion_message, repaired_quaternions
from avdata.inputs import Source, folder_entries, refuse_special_file
from avdata.schema.limits import MAX_BOX_SIZE_M, MAX_CAMERA_VALUE_PX, MAX_COORDINATE_M
from avdata.sources._checks import coordinates_problem
from avdata.storage import SMALL_OBJECT_BYTES, Location, read_range, scrub

#: Columns of ``annotations.feather`` and their numpy types (av2 ``CuboidList.from_feather``).
ANNOTATION_COLUMNS: dict[str, str] = {
    "timestamp_ns": "int64",
    "track_uuid": "str",
    "category": "str",
    "length_m": "float64",
    "width_m": "float64",
    "height_m": "float64",
    "qw": "float64",
    "qx": "float64",
    "qy": "float64",
    "qz": "float64",
    "tx_m": "float64",
    "ty_m": "float64",
    "tz_m": "float64",
    "num_interior_pts": "int64",
}

#: Columns of a pose table (``city_SE3_egovehicle``; ``egovehicle_SE3_sensor`` has ``sensor_name`` first).
POSE_COLUMNS: dict[str, str] = {
    "qw": "float64",
    "qx": "float64",
    "qy": "float64",
    "qz": "float64",
    "tx_m": "float64",
    "ty_m": "float64",
    "tz_m": "float64",
}

#: Columns of ``intrinsics.feather``.
INTRINSICS_COLUMNS: dict[str, str] = {
    "sensor_name": "str",
    "fx_px": "float64",
    "fy_px": "float64",
    "cx_px": "float64",
    "cy_px": "float64",
    "k1": "float64",
    "k2": "float64",
    "k3": "float64",
    "height_px": "int64",
    "width_px": "int64",
}

#: Columns of a lidar sweep, with the exact types AV2 stores (xyz are float16).
SWEEP_COLUMNS: dict[str, str] = {
    "x": "float16",
    "y": "float16",
    "z": "float16",
    "intensity": "uint8",
    "laser_number": "uint8",
    "offset_ns": "int32",
}

_TIMESTAMP_NAME = re.compile(r"^(\d+)\.(feather|jpg)$")


def read_table(path: Source, columns: Collection[str] | None = None) -> pa.Table:
    """A feather (v2) file as an Arrow table; InputError naming the file when it is missing or damaged.

    Args:
        path: the file, local (memory-mapped) or in a store.
        columns: read only these of its columns (those it has); None: every column.
    """
    refuse_special_file(path)  # mapping a FIFO waits for a writer
    try:
        # Feather v2 is the Arrow IPC file format; pyarrow.feather.read_table would import pandas, a start-up
        # cost for nothing.
        with path.open_input() if isinstance(path, Location) else pa.memory_map(str(path), "r") as stream:
            table = _ipc_reader(stream, isinstance(path, Location), columns).read_all()
            table.validate(full=True)  # offsets and UTF-8 of damaged bytes, which to_pylist would trip on later
            return table
    except FileNotFoundError:
        raise InputError(f"{path}: expected a feather file, got none") from None
    except InputError:
        raise
    except Exception as error:  # noqa: BLE001 - damaged bytes make pyarrow raise SystemError, ... besides ArrowException
        raise InputError(f"{path}: unreadable feather file ({scrub(one_line(error))})") from None


def _ipc_reader(stream: pa.NativeFile, remote: bool, columns: Collection[str] | None) -> ipc.RecordBatchFileReader:
    """A reader of ``columns`` (None: all) of the IPC file ``stream``; ``remote``: each read is a ranged request.

    An object in a store is fetched whole when it is small or every column of it is read (its footer, in its last
    :data:`_TAIL_BYTES`, says which it has: two requests after the size). Otherwise the store's own reader fetches
    the footer again and then the buffers of the columns read, one request each. Fetched bytes are Arrow's own
    (:func:`~avdata.storage.read_range`), never Python objects, as Arrow's thread pools decompress them.
    """
    if not remote:
        reader = ipc.open_file(stream)
        names = reader.schema.names
        if columns is None or set(names) <= set(columns):
            return reader
    else:
        size = stream.size()
        if columns is None or size <= SMALL_OBJECT_BYTES:
            return ipc.open_file(pa.BufferReader(read_range(stream, size, 0)))
        tail_start = size - _TAIL_BYTES
        tail = read_range(stream, _TAIL_BYTES, tail_start)
        try:  # the footer alone: opening a reader does not follow its record batch offsets
            names = ipc.open_file(pa.BufferReader(tail)).schema.names
        except (pa.ArrowException, OSError):  # a footer longer than the tail (or damaged: the full open says so)
            names = ipc.open_file(stream).schema.names
        if set(names) <= set(columns):
            whole = pa.allocate_buffer(size)
            view = memoryview(whole)
            view[:tail_start] = read_range(stream, tail_start, 0)
            view[tail_start:] = tail
            return ipc.open_file(pa.BufferReader(whole))
    wanted = [k for k, name in enumerate(names) if name in columns]
    return ipc.open_file(stream, options=ipc.IpcReadOptions(included_fields=wanted))


#: Bytes at the end of a feather object fetched first: its footer (the schema and where each record batch is; a
#: few kB in Argoverse 2's files) and the footer's length.
_TAIL_BYTES = 16 << 10


def read_columns(path: Source, columns: dict[str, str], exact: bool = False) -> dict[str, np.ndarray]:
    """Named columns of a feather file as numpy arrays; a null anywhere is an InputError for the file.

    Args:
        path: the feather file.
        columns: column name -> numpy type ("str" for strings).
        exact: require the stored type to be exactly that type (lidar sweeps); otherwise any
            type that converts without loss (e.g. uint16 image sizes into int64).

    Returns:
        column name -> (N,) array, in the order of ``columns``.
    """
    out, null_rows = read_row_columns(path, columns, exact)
    for row, problem in enumerate(null_rows):
        if problem is not None:
            raise InputError(f"{path}: row {row}: {problem}")
    return out


def read_row_columns(path: Source, columns: dict[str, str],
                     exact: bool = False) -> tuple[dict[str, np.ndarray], list[str | None]]:
    """Like :func:`read_columns`, for a table read row by row: a null costs its row, not the file.

    Returns:
        (column name -> (N,) array with nulls filled by "" or 0, one problem per row: None or the
        first null column of that row).
    """
    table = read_table(path, columns)
    missing = [name for name in columns if name not in table.column_names]
    if missing:
        raise InputError(f"{path}: expected columns {list(columns)}, missing {missing}")
    out: dict[str, np.ndarray] = {}
    null_rows: list[str | None] = [None] * table.num_rows
    try:
        for name, kind in columns.items():
            column = table.column(name)
            if column.null_count:
                for row in np.flatnonzero(np.asarray(column.is_null())).tolist():
                    null_rows[row] = null_rows[row] or f"column {name!r}: expected a value, got null"
                column = column.fill_null("" if kind == "str" else 0)
            if kind == "str":
                if not pa.types.is_string(column.type) and not pa.types.is_large_string(column.type):
                    raise InputError(f"{path}: column {name!r}: expected strings, got {column.type}")
                out[name] = np.asarray(column.to_pylist(), dtype=str)
                continue
            values = column.to_numpy()
            if exact and values.dtype != np.dtype(kind):
                raise InputError(f"{path}: column {name!r}: expected {kind}, got {column.type}")
            if not np.can_cast(values.dtype, kind, casting="safe"):
                raise InputError(f"{path}: column {name!r}: expected {kind}, got {column.type}")
            out[name] = values.astype(kind, copy=False)
    except InputError:
        raise
    except Exception as error:  # noqa: BLE001 - damaged bytes make pyarrow raise SystemError, UnicodeDecodeError, ...
        raise InputError(f"{path}: unreadable feather file ({type(error).__name__}: {scrub(one_line(error))})") from None
    return out, null_rows


@dataclass(frozen=True, slots=True)
class Rows:
    """The usable rows of a table read row by row: a bad value costs its own row, never the table.

    Attributes:
        columns: name -> (N,) values of the kept rows, in file order (quaternions off unit norm beyond
            float noise normalised).
        dropped: one message per dropped row, naming the row, the column and the value.
        repaired: one message per row whose quaternion was normalised beyond float noise (a warning).
    """

    columns: dict[str, np.ndarray]
    dropped: list[str]
    repaired: list[str]


def _checked_rows(columns: dict[str, np.ndarray], row_names: np.ndarray | None = None,
                  problem: list[str | None] | None = None) -> Rows:
    """Drops rows with a null, a negative timestamp, a bad coordinate, size or quaternion; normalises the others' quaternions.

    Timestamps (``timestamp_ns``) must be >= 0, coordinates (``t*_m``) within the scene writer's
    magnitude limits, sizes (``*_m`` of a cuboid) in (0, MAX_BOX_SIZE_M], quaternions (``qw..qz``)
    within the one tolerance rule of :mod:`avdata.frames.rotations`. ``row_names`` (e.g. sensor names)
    go into the messages beside the row; ``problem`` holds the rows already known bad (nulls).
    """
    n_rows = len(next(iter(columns.values())))
    problem = list(problem) if problem is not None else [None] * n_rows
    if "timestamp_ns" in columns:
        for row in np.flatnonzero(columns["timestamp_ns"] < 0).tolist():
            problem[row] = problem[row] or f"column 'timestamp_ns': expected a time >= 0, got {columns['timestamp_ns'][row]}"
    for name in columns:
        if columns[name].dtype != np.float64 or name.startswith("q"):
            continue
        values = columns[name]
        size = name in ("length_m", "width_m", "height_m")
        # The scene writer's magnitude limits: beyond them a row is damage (see README, tolerances).
        bad = ~((values > 0) & (values <= MAX_BOX_SIZE_M)) if size else ~(np.abs(values) <= MAX_COORDINATE_M)
        expected = (f"a finite positive size <= {MAX_BOX_SIZE_M:g} m" if size
                    else f"a finite number within {MAX_COORDINATE_M:g}")
        for row in np.flatnonzero(bad).tolist():
            problem[row] = problem[row] or f"column {name!r}: expected {expected}, got {values[row]}"
    quat = np.stack([columns[k] for k in ("qw", "qx", "qy", "qz")], axis=1)
    unit, warn, reject = repaired_quaternions(quat)
    for row in np.flatnonzero(reject).tolist():
        problem[row] = problem[row] or f"columns qw..qz: {quaternion_message(quat[row], rejected=True)}"

    def label(row: int) -> str:
        return f"row {row}" if row_names is None else f"row {row} ({row_names[row]})"

    repaired = [f"{label(row)}: columns qw..qz: {quaternion_message(quat[row], rejected=False)}"
                for row in np.flatnonzero(warn).tolist() if problem[row] is None]
    out = dict(columns)
    for i, k in enumerate(("qw", "qx", "qy", "qz")):  # rows within float noise keep their stored bits
        out[k] = np.where(warn, unit[:, i], quat[:, i])
    keep = np.asarray([p is None for p in problem], dtype=bool)
    dropped = [f"{label(row)}: {p}" for row, p in enumerate(problem) if p is not None]
    return Rows(columns={k: v[keep] for k, v in out.items()} if dropped else out, dropped=dropped, repaired=repaired)


def read_poses(path: Source) -> Rows:
    """``city_SE3_egovehicle.feather``: the usable rows, as timestamp_ns (N,) sorted and unique, quat_wxyz, translation_m.

    A row with a bad value is dropped (its time then has no ego pose: the frames at that time lose what
    needs one, nothing else); a time given twice drops every row of that time.
    """
    rows = _checked_rows(*_with_nulls(read_row_columns(path, {"timestamp_ns": "int64", **POSE_COLUMNS})))
    columns, dropped = rows.columns, list(rows.dropped)
    order = np.argsort(columns["timestamp_ns"], kind="stable")
    times = columns["timestamp_ns"][order]
    repeated = np.flatnonzero(times[1:] == times[:-1])
    if len(repeated):
        twice = np.unique(times[repeated])
        dropped += [f"column 'timestamp_ns': {int(t)} given {int(np.sum(times == t))} times; those rows dropped"
                    for t in twice.tolist()]
        order = order[~np.isin(times, twice)]
    return Rows(
        columns={
            "timestamp_ns": columns["timestamp_ns"][order],
            "quat_wxyz": np.stack([columns[k][order] for k in ("qw", "qx", "qy", "qz")], axis=1),
            "translation_m": np.stack([columns[k][order] for k in ("tx_m", "ty_m", "tz_m")], axis=1),
        },
        dropped=dropped,
        repaired=rows.repaired,
    )


def read_sensor_poses(path: Source) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], Rows]:
    """``egovehicle_SE3_sensor.feather``: sensor name -> (unit quat_wxyz (4,), translation_m (3,)) in ego.

    Returns:
        The usable sensors, and the :class:`Rows` whose ``dropped`` / ``repaired`` messages name the
        sensors whose row was bad (dropped: that sensor is not converted) or normalised.
    """
    columns, nulls = read_row_columns(path, {"sensor_name": "str", **POSE_COLUMNS})
    rows = _checked_rows(columns, row_names=columns["sensor_name"], problem=nulls)
    kept = rows.columns
    names, counts = np.unique(kept["sensor_name"], return_counts=True)
    if np.any(counts > 1):  # which row is right is unknown: the sensor is not converted
        twice = names[counts > 1]
        dropped = [*rows.dropped, *(f"column 'sensor_name': {str(n)!r} given {int(c)} times"
                                    for n, c in zip(twice.tolist(), counts[counts > 1].tolist(), strict=True))]
        keep = ~np.isin(kept["sensor_name"], twice)
        kept = {k: v[keep] for k, v in kept.items()}
        rows = Rows(columns=kept, dropped=dropped, repaired=rows.repaired)
    quat = np.stack([kept[k] for k in ("qw", "qx", "qy", "qz")], axis=1)
    translation = np.stack([kept[k] for k in ("tx_m", "ty_m", "tz_m")], axis=1)
    return {str(name): (quat[i], translation[i]) for i, name in enumerate(kept["sensor_name"])}, rows


@dataclass(frozen=True, slots=True, kw_only=True)
class Intrinsics:
    """One camera's pinhole intrinsics and radial distortion, as ``intrinsics.feather`` stores them."""

    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    k1: float
    k2: float
    k3: float
    width_px: int
    height_px: int

    @property
    def K(self) -> np.ndarray:  # noqa: N802 - the matrix's usual name
        """(3, 3) intrinsic matrix (av2 ``Intrinsics.K``: no skew)."""
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])

    @property
    def D_plumb_bob(self) -> np.ndarray:  # noqa: N802 - ROS/Foxglove's name
        """(5,) distortion in the plumb_bob order (k1, k2, p1, p2, k3); AV2 has no tangential terms."""
        return np.array([self.k1, self.k2, 0.0, 0.0, self.k3])


def read_intrinsics(path: Source) -> tuple[dict[str, Intrinsics], list[str]]:
    """``intrinsics.feather``: camera name -> :class:`Intrinsics`, and one message per camera dropped.

    A row with a null, a non-finite or absurd value, a non-positive focal length or image size costs
    that camera only; a camera given twice loses every row of it (which one is right is unknown).
    """
    columns, problem = read_row_columns(path, INTRINSICS_COLUMNS)
    floats = ("fx_px", "fy_px", "cx_px", "cy_px", "k1", "k2", "k3")
    for name in floats:
        for row in np.flatnonzero(~(np.abs(columns[name]) <= MAX_CAMERA_VALUE_PX)).tolist():
            problem[row] = problem[row] or (f"column {name!r}: expected a finite number within "
                                            f"{MAX_CAMERA_VALUE_PX:g}, got {columns[name][row]}")
    for name in ("fx_px", "fy_px", "width_px", "height_px"):
        for row in np.flatnonzero(~(columns[name] > 0)).tolist():
            problem[row] = problem[row] or f"column {name!r}: expected a positive value, got {columns[name][row]}"
    names, counts = np.unique(columns["sensor_name"], return_counts=True)
    for row in np.flatnonzero(np.isin(columns["sensor_name"], names[counts > 1])).tolist():
        problem[row] = problem[row] or f"column 'sensor_name': {columns['sensor_name'][row]!r} given more than once"
    bad_names = {str(columns["sensor_name"][row]) for row, p in enumerate(problem) if p is not None}
    dropped = [f"row {row} ({columns['sensor_name'][row]}): {p}; that camera is skipped"
               for row, p in enumerate(problem) if p is not None]
    return {
        str(camera): Intrinsics(
            **{k: float(columns[k][i]) for k in floats},
            width_px=int(columns["width_px"][i]),
            height_px=int(columns["height_px"][i]),
        )
        for i, camera in enumerate(columns["sensor_name"])
        if str(camera) not in bad_names
    }, dropped


def read_annotations(path: Source) -> Rows:
    """``annotations.feather`` as columns (see :data:`ANNOTATION_COLUMNS`), without its impossible rows.

    A row with a non-finite or absurd number, a size <= 0 or a quaternion off unit norm by more than the
    tolerance of :mod:`avdata.frames.rotations` is dropped; quaternions within it are normalised (beyond
    float noise with a message in ``repaired``).
    """
    return _checked_rows(*_with_nulls(read_row_columns(path, ANNOTATION_COLUMNS)))


def _with_nulls(read: tuple[dict[str, np.ndarray], list[str | None]]) -> tuple[dict[str, np.ndarray], None, list[str | None]]:
    """(columns, no row names, null problems): :func:`read_row_columns`'s result as :func:`_checked_rows` arguments."""
    return read[0], None, read[1]


def read_sweep(path: Source) -> dict[str, np.ndarray]:
    """One lidar sweep, every column in its stored type.

    x, y, z float16 (egovehicle frame), intensity uint8, laser_number uint8, offset_ns int32 (time after the
    sweep timestamp).

    Raises:
        InputError: the file is unreadable or lacks a column, or an x, y or z is NaN or infinite. An
            uncompressed feather file has no checksum, and a flipped exponent bit in a float16 gives such a
            value (the largest finite float16, 65504, is within the coordinate limit).
    """
    sweep = read_columns(path, SWEEP_COLUMNS, exact=True)
    if (problem := coordinates_problem(sweep, MAX_COORDINATE_M)) is not None:
        raise InputError(f"{path}: {problem}")
    return sweep


def timestamp_files(folder: Source, suffix: str) -> tuple[np.ndarray, list[Source], list[Source]]:
    """The ``<timestamp_ns>.<suffix>`` files of a folder (one listing in a store); none when there is no folder.

    Returns:
        (timestamps_ns (N,) sorted, their paths, other files that do not follow the naming scheme).
    """
    named: list[tuple[int, Source]] = []
    strays: list[Source] = []
    for path in folder_entries(folder):
        match = _TIMESTAMP_NAME.match(path.name)
        if match and match.group(2) == suffix and int(match.group(1)) < 2**63:  # int64 ns (a longer name: a stray)
            named.append((int(match.group(1)), path))
        else:
            strays.append(path)
    named.sort(key=lambda item: (item[0], item[1].name))
    return np.asarray([t for t, _ in named], dtype=np.int64), [p for _, p in named], strays


def city_name(log_dir: Source) -> str:
    """The city code in the vector map's name (``log_map_archive_<log>____PIT_city_47896.json`` -> ``PIT``), or ""."""
    for name in (p.name for p in folder_entries(log_dir / "map")):
        match = re.search(r"____([A-Z]+)_city_", name)
        if fnmatch.fnmatchcase(name, "log_map_archive_*.json") and match:
            return match.group(1)
    return ""
