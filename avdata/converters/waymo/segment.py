"""One Waymo segment's component files, its vehicle poses and the helpers every component's reader shares."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from avdata.converters.base import Report
from avdata.errors import InputError
from avdata.frames import Transform
from avdata.frames.rotations import repaired_rotation
from avdata.schema.limits import MAX_COORDINATE_M
from avdata.sources.waymo import CAMERA_NAMES, LASER_NAMES, ComponentFile, read_component
from avdata.sources.waymo.components import TIME_KEY
from avdata.storage import Location

LASER_KEY = "key.laser_name"
CAMERA_KEY = "key.camera_name"
OBJECT_KEY = "key.laser_object_id"
#: The integer join keys: a row with a null one belongs to no frame, laser or camera.
_INTEGER_KEYS = (TIME_KEY, LASER_KEY, CAMERA_KEY)


def lidar_frame(laser_name: int) -> str:
    """``ego/lidar_top`` ... for a ``LaserName`` value."""
    return f"ego/lidar_{LASER_NAMES[laser_name].lower()}"


def camera_frame(camera_name: int) -> str:
    """``ego/cam_front`` ... for a ``CameraName`` value."""
    return f"ego/cam_{CAMERA_NAMES[camera_name].lower()}"


def as_int(values: pa.ChunkedArray | pa.Array) -> np.ndarray:
    """Integer key column (some files store camera/laser names as digit strings)."""
    return np.asarray([int(v) for v in values.to_pylist()], dtype=np.int64)


def matrix_4x4(value: list[float | None] | None, where: str) -> np.ndarray:
    """(4, 4) float64 from one 16-float row-major list; InputError naming ``where`` otherwise."""
    if value is None or len(value) != 16 or any(v is None for v in value):
        raise InputError(f"{where}: expected 16 numbers of a 4x4 transform, got {value}")
    return np.asarray(value, dtype=np.float64).reshape(4, 4)


def matrices_4x4(column: pa.ChunkedArray | pa.Array, where: str, rows: np.ndarray) -> np.ndarray:
    """(N, 4, 4) float64 from a column of 16-float row-major lists; InputError naming ``where`` and the row otherwise.

    ``rows``: each value's row number in its file (:func:`file_rows`), for that message.
    """
    return np.asarray([matrix_4x4(value, f"{where}: row {rows[k]}") for k, value in enumerate(column.to_pylist())],
                      dtype=np.float64).reshape(-1, 4, 4)


def column_numbers(column: pa.ChunkedArray) -> np.ndarray:
    """A numeric column as numpy (nulls -> NaN), without ChunkedArray.to_numpy's pandas import."""
    values: np.ndarray = column.combine_chunks().to_numpy(zero_copy_only=False)
    return values


def id_set(ids: np.ndarray | None) -> set[str]:
    """The object ids of a frame's boxes (none when the boxes carry no ids)."""
    return set() if ids is None else set(ids.tolist())


def float_column(table: pa.Table, name: str, n: int) -> np.ndarray:
    """A float column as float64, NaN for nulls; all NaN when the column is absent (optional fields)."""
    if name not in table.column_names:
        return np.full(n, np.nan)
    return np.asarray(column_numbers(table.column(name)), dtype=np.float64)


def reported_duplicates(report: Report, path: Path | Location, names: np.ndarray, key: str, cost: str) -> set[int]:
    """The key values given more than once (each reported as one error: which row is right is unknown)."""
    values, counts = np.unique(names, return_counts=True)
    for value, count in zip(values[counts > 1].tolist(), counts[counts > 1].tolist(), strict=True):
        report.error(path, f"{key}: {value} given {count} times; {cost}")
    return set(values[counts > 1].tolist())


#: The column :func:`without_null_keys` adds when it drops rows: each kept row's number in the file, for messages.
FILE_ROW = "avdata.file_row"


def without_null_keys(report: Report, path: Path | Location, table: pa.Table, keys: tuple[str, ...]) -> pa.Table:
    """``table`` without its rows whose time, laser or camera key is null, each reported (its record is unknown).

    Rows kept after a dropped one keep their file row numbers in column :data:`FILE_ROW` (see :func:`file_rows`).
    """
    null = np.zeros(table.num_rows, dtype=bool)
    for key in (k for k in keys if k in _INTEGER_KEYS and table.column(k).null_count):
        is_null = np.asarray(table.column(key).is_null(), dtype=bool)
        for row in np.flatnonzero(is_null & ~null).tolist():
            report.error(path, f"row {row}: {key}: expected an integer, got null; that row is skipped")
        null |= is_null
    if not null.any():
        return table
    return table.append_column(FILE_ROW, pa.array(np.arange(table.num_rows, dtype=np.int64))).filter(pa.array(~null))


def file_rows(table: pa.Table) -> np.ndarray:
    """Each row's number in its file (:func:`without_null_keys` may have dropped some), for messages."""
    if FILE_ROW in table.column_names:
        return np.asarray(table.column(FILE_ROW).to_numpy(), dtype=np.int64)
    return np.arange(table.num_rows, dtype=np.int64)


def is_time_s(value: float | None) -> bool:
    """Whether ``value`` seconds is a time avdata can store: int64 nanoseconds, not before 1970."""
    return value is not None and bool(np.isfinite(value)) and 0.0 <= value < 9.2e9


class Segment:
    """One context's files, report and what its readers learnt about it (kept as one object so its tables die with it)."""

    def __init__(self, context: str, files: dict[str, ComponentFile], report: Report):
        """Context ``context`` with its component files; problems of single records go to ``report``."""
        self.context = context
        self.files = files
        self.report = report
        split = next(iter(files.values())).split
        self.base = next(iter(files.values())).path.parent.parent
        self.split = split
        #: cameras whose calibration row was reported unusable (their images are skipped without a second line)
        self.reported_cameras: set[int] = set()
        #: frame times (µs) whose vehicle pose was unusable: reported once, their other rows skipped silently
        self.skipped_us: set[int] = set()
        #: image times (ns) whose stored pose was refused: reported once, their images skipped
        self.unposed_ns: set[int] = set()
        #: components found missing or unreadable by :meth:`_read`: reported once, their later reads skipped
        self.unreadable: set[str] = set()

    def path(self, component: str) -> str:
        """Where ``component``'s file of this context is (or would be)."""
        return str(self.base / component / f"{self.context}.parquet")

    def read(self, component: str, fields: list[str], keys: tuple[str, ...] = (),
             optional: tuple[str, ...] = ()) -> pa.Table | None:
        """A whole small component (``optional`` fields too when it has them), or None after reporting why not."""
        file = self.files.get(component)
        if file is None:
            self.report.error(self.path(component), f"missing component {component} of context {self.context}")
            self.unreadable.add(component)
            return None
        try:
            table = read_component(file, [*keys, *(file.column(f) for f in fields)], [file.column(f) for f in optional])
            return without_null_keys(self.report, file.path, table, keys)
        except InputError as error:
            self.report.error(file.path, str(error).removeprefix(f"{file.path}: "))
            self.unreadable.add(component)
            return None

    def poses(self) -> tuple[np.ndarray, np.ndarray, list[Transform]]:
        """(frame times in µs (F,), world_T_vehicle (F, 4, 4) as stored, the same as checked transforms), in time order.

        A pose row that is not a proper rigid transform within the limits costs its frame (every component row
        at that time is skipped, :attr:`skipped_us`), reported once; a time given twice costs both rows.
        """
        file = self.files.get("vehicle_pose")
        if file is None:
            raise InputError(f"{self.path('vehicle_pose')}: missing component vehicle_pose of context {self.context}")
        column = file.column("world_from_vehicle.transform")
        table = read_component(file, [TIME_KEY, column])
        if not table.num_rows:
            raise InputError(f"{file.path}: expected vehicle poses, got no rows")
        table = without_null_keys(self.report, file.path, table, (TIME_KEY,))
        times = column_numbers(table.column(TIME_KEY))
        unique, counts = np.unique(times, return_counts=True)
        for time_us in unique[counts > 1].tolist():
            self.report.error(file.path, f"frame at {int(time_us)} us: {TIME_KEY}: expected one pose per frame, got "
                                         f"{int(np.sum(times == time_us))}; the frame is skipped")
        keep = np.isin(times, unique[counts == 1])
        matrices = np.full((len(times), 4, 4), np.nan)
        transforms: dict[int, Transform] = {}
        for k, value in enumerate(table.column(column).to_pylist()):
            if not keep[k]:
                continue
            where = f"frame at {int(times[k])} us: {column}"
            try:
                matrices[k] = matrix_4x4(value, f"{file.path}: {where}")
                transforms[k] = self.transform(matrices[k], file.path, where)
            except InputError as error:
                self.report.error(file.path, f"{str(error).removeprefix(f'{file.path}: ')}; the frame is skipped")
                keep[k] = False
        self.skipped_us = {int(t) for t in times[~keep].tolist()}
        if not keep.any():
            raise InputError(f"{file.path}: expected vehicle poses, got no usable rows")
        order = np.flatnonzero(keep)[np.argsort(times[keep], kind="stable")]
        return times[order], matrices[order], [transforms[k] for k in order.tolist()]

    def transform(self, matrix: np.ndarray, file: str | Any, what: str) -> Transform:
        """A proper rigid transform from a stored 4x4, by the one tolerance rule of :mod:`avdata.frames.rotations`.

        Waymo stores float32 matrices (real poses are off orthonormality by up to ~1e-7): repaired silently up to
        1e-6, with a warning up to 1e-2, refused beyond, as are a non-finite value and a translation beyond the
        scene writer's limit.
        """
        rotation, warning = repaired_rotation(matrix[:3, :3], f"{file}: {what}")
        if not np.all(np.abs(matrix[:3, 3]) <= MAX_COORDINATE_M):
            raise InputError(f"{file}: {what}: expected a translation within {MAX_COORDINATE_M:g} m, got "
                             f"{matrix[:3, 3].tolist()}")
        if warning is not None:
            self.report.warn(file, warning.removeprefix(f"{file}: "))
        return Transform(rotation=rotation, translation=matrix[:3, 3])
