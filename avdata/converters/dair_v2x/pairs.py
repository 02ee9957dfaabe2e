"""DAIR-V2X-C cooperative pairs: a pair's fields, calibrations and source times, read and checked.

The sides' ``data_info.json`` rows give each pair its batch (the sequence it belongs to) and its
timestamps; the pose calibrations place it in ``world``. Nothing here reads sensor data.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Any

import numpy as np

from avdata.converters.base import Report
from avdata.errors import InputError
from avdata.frames import Transform
from avdata.frames.rotations import SILENT_TOLERANCE
from avdata.inputs import Source, is_present
from avdata.sources.dair_v2x import Calibration, read_calibration, read_json
from avdata.storage import Location

#: Point-cloud timestamps beyond this (µs, year 2262) would overflow int64 ns.
MAX_TIMESTAMP_US = 9_223_372_036_854_775


#: The fields of a cooperative pair that name files, relative to the source root.
PAIR_PATHS = ("vehicle_pointcloud_path", "infrastructure_pointcloud_path", "cooperative_label_path")


def frame_id(path: str) -> str:
    """The frame id a DAIR-V2X path names: its file name without the suffix (``velodyne/017314.pcd`` -> ``017314``)."""
    return Path(path).stem


@dataclass(frozen=True, slots=True, kw_only=True)
class Side:
    """One side of a pair: its folder, its agent and the names of its camera fields and files."""

    name: str
    folder: str
    agent: str
    image_field: str
    extrinsic: str


SIDES = (
    Side(name="vehicle", folder="vehicle-side", agent="ego", image_field="vehicle_image_path",
          extrinsic="lidar_to_camera"),
    Side(name="infrastructure", folder="infrastructure-side", agent="infra", image_field="infrastructure_image_path",
          extrinsic="virtuallidar_to_camera"),
)


@dataclass(frozen=True, slots=True, kw_only=True)
class Pair:
    """One cooperative pair, its fields, calibrations and source times read and checked (no sensor data)."""

    entry: dict[str, Any]
    vehicle_id: str
    infra_id: str
    offset_xy: tuple[float, float]
    calibrations: dict[str, Calibration]
    rows: dict[str, dict[str, Any] | None]
    #: µs by ``vehicle``, ``infrastructure``, ``vehicle_image``, ``infrastructure_image`` (those present)
    source_times: dict[str, int]
    #: the frame's time: the vehicle sweep's (0 without one, a lone pair only)
    time_ns: int
    cloud_times: dict[str, int]

    def image_time_ns(self, side: Side) -> int:
        """The side's ``image_timestamp`` when the scene time is absolute, else its sweep's time."""
        own_us = self.source_times.get(f"{side.name}_image") if "vehicle" in self.source_times else None
        return self.cloud_times[f"{side.agent}/lidar"] if own_us is None else own_us * 1000

    @property
    def world_T_infra(self) -> Transform:
        """The infrastructure's pose in ``world`` (``virtuallidar_to_world`` with ``system_error_offset``)."""
        return self.calibrations["infrastructure virtuallidar_to_world"].transform


def read_pair(root: Source, scene: str, entry: dict[str, Any], report: Report) -> Pair:
    """A pair's fields, calibrations and source times, checked.

    Raises:
        InputError: a pair field or a pose calibration (lidar_to_novatel, novatel_to_world,
            virtuallidar_to_world) is unusable: the pair cannot be placed in ``world``.
    """
    info_file = entry["_file"]
    try:
        offset = entry.get("system_error_offset")  # absent: no offset; [] or 0 is not one (was read as none)
        offset = {"delta_x": 0.0, "delta_y": 0.0} if offset is None else offset
        offset_xy = (float(offset["delta_x"]), float(offset["delta_y"]))
        paths = {key: entry[key] for key in PAIR_PATHS}
    except (KeyError, TypeError, ValueError) as error:
        raise InputError(f"{info_file}: {scene}: expected {', '.join(PAIR_PATHS)} and numeric "
                         f"system_error_offset delta_x / delta_y, got {type(error).__name__} {error}") from None
    for key, value in [*paths.items(), *zip(("delta_x", "delta_y"), offset_xy, strict=True)]:
        # A path must be text without NUL (1e308 was a TypeError traceback, a NUL a ValueError) and inside the
        # source folder (as DAIR writes them: '/etc/hostname' or '../x' read a file of another tree), an offset a number.
        if not (_inside_relative_path(value) if key in PAIR_PATHS else np.isfinite(value)):
            raise InputError(f"{info_file}: {scene}: field {key}: expected "
                             f"{'a relative path' if key in PAIR_PATHS else 'a finite number'}, got {value!r:.80}")
    vehicle_id = frame_id(paths["vehicle_pointcloud_path"])
    infra_id = frame_id(paths["infrastructure_pointcloud_path"])
    vehicle, infra = root / "vehicle-side", root / "infrastructure-side"
    calibration_paths = {
        "vehicle lidar_to_novatel": vehicle / "calib" / "lidar_to_novatel" / f"{vehicle_id}.json",
        "vehicle novatel_to_world": vehicle / "calib" / "novatel_to_world" / f"{vehicle_id}.json",
        "infrastructure virtuallidar_to_world": infra / "calib" / "virtuallidar_to_world" / f"{infra_id}.json",
    }
    calibrations = {
        name: read_calibration(path, offset_xy if name.startswith("infrastructure") else (0.0, 0.0))
        for name, path in calibration_paths.items()
    }
    for name, calibration in calibrations.items():
        warn_residual(report, calibration_paths[name], calibration)
    rows = {side.name: data_info_row(root / side.folder / "data_info.json", frame, report)
            for side, frame in zip(SIDES, (vehicle_id, infra_id), strict=True)}
    vehicle_row, infra_row = rows["vehicle"], rows["infrastructure"]
    if vehicle_row is not None and infra_row is not None and "batch_id" in infra_row \
            and str(infra_row["batch_id"]) != str(vehicle_row.get("batch_id")):
        report.warn(infra / "data_info.json", f"frame {infra_id}: field batch_id: expected {vehicle_row.get('batch_id')!r} "
                                              f"(its vehicle frame {vehicle_id}'s), got {infra_row['batch_id']!r:.40}; "
                                              "the pair follows its vehicle frame's batch")
    source_times = _timestamps(root, rows, (vehicle_id, infra_id), report)
    time_ns = source_times.get("vehicle", 0) * 1000
    # The infrastructure sweep and both images keep their own capture times (pairs are matched within
    # ~100 ms) when the scene time is absolute. The infrastructure is fixed; the vehicle image gets the
    # frame's one ego pose stamped at its time too.
    cloud_times = {"ego/lidar": time_ns, "infra/lidar": time_ns}
    if "vehicle" in source_times and "infrastructure" in source_times:
        cloud_times["infra/lidar"] = source_times["infrastructure"] * 1000
    return Pair(entry=entry, vehicle_id=vehicle_id, infra_id=infra_id, offset_xy=offset_xy, calibrations=calibrations,
                 rows=rows, source_times=source_times, time_ns=time_ns, cloud_times=cloud_times)


def usable_rows(path: Source) -> dict[str, dict[str, Any]]:
    """A side's data_info.json rows by frame id, or none when the file is absent or unusable (reported per pair)."""
    if not is_present(path):
        return {}
    version = _version(path)
    if version is None:
        return {}
    rows = _data_info_rows(path, *version)
    return {} if isinstance(rows, str) else rows


def _version(path: Source) -> tuple[int, int] | None:
    """(modification time in ns, size) of the file or object at ``path``; None when a local one cannot be stat'ed."""
    if isinstance(path, Location):
        info = path.info()
        return info.mtime_ns, info.size
    try:
        status = path.stat()
    except OSError:
        return None
    return status.st_mtime_ns, status.st_size


#: A ``batch_id`` becomes part of a scene (file) name: these characters only.
BATCH_ID = re.compile(r"^[0-9A-Za-z_-]{1,64}$")


def row_batch_id(row: dict[str, Any] | None) -> tuple[str | None, str | None]:
    """(the row's ``batch_id`` as a name, or None; a warning line when it is present but unusable)."""
    if row is None or row.get("batch_id") is None:
        return None, None
    value = row["batch_id"]
    name = str(value) if isinstance(value, str | int) and not isinstance(value, bool) else ""
    if not BATCH_ID.match(name):
        return None, (f"frame {frame_id(str(row.get('pointcloud_path')))}: field batch_id: expected a batch name "
                      f"(1 to 64 letters, digits, _ or -), got {value!r:.40}; the pair is its own scene")
    return name, None


def lenient_time_us(row: dict[str, Any] | None) -> int | None:
    """A row's ``pointcloud_timestamp`` when it reads as an integer (for spans only; ``_timestamps`` checks it)."""
    try:
        return int(row["pointcloud_timestamp"]) if row is not None else None
    except (KeyError, TypeError, ValueError, OverflowError):
        return None


def max_difference(a: Transform, b: Transform) -> float:
    """The largest difference between two transforms' matching entries (rotation and translation)."""
    return float(max(np.abs(a.rotation - b.rotation).max(), np.abs(a.translation - b.translation).max()))


def warn_residual(report: Report, path: Source, calibration: Calibration) -> None:
    """A warning naming the calibration file when its rotation was repaired beyond float noise."""
    if calibration.residual > SILENT_TOLERANCE:
        report.warn(path, f"field rotation: not orthonormal (max |RᵀR - I| = {calibration.residual:.3g} > "
                          f"{SILENT_TOLERANCE}); replaced by the nearest rotation")


def data_info_row(path: Source, frame: str, report: Report) -> dict[str, Any] | None:
    """The entry of a side's data_info.json whose ``pointcloud_path`` is ``frame``; None (reported) if none.

    A missing data_info.json is no problem (the scene time is then flagged scene-relative); an unusable one
    is an error, a file without the frame a warning: either costs the frame's timestamps, and the camera
    files are then found by the image's frame id.
    """
    if not is_present(path):
        return None
    consequence = f"(frame {frame}: no timestamps; camera files by frame id)"
    rows = _data_info_rows(path, *(_version(path) or (0, -1)))  # a broken link: the read names why
    if isinstance(rows, str):
        report.error(path, f"{rows} {consequence}")
        return None
    row = rows.get(frame)
    if row is None:
        report.warn(path, f"no entry with pointcloud_path of frame {frame} {consequence}")
    return row


@functools.lru_cache(maxsize=2)
def _data_info_rows(path: Source, mtime_ns: int, size: int) -> dict[str, dict[str, Any]] | str:
    """A side's data_info.json entries by point-cloud frame id (the first of each), or why the file is unusable.

    Read once per process and version of the file (``mtime_ns``, ``size``; the two sides are the two entries):
    a pair needs one row of each, and reading the whole list again for every pair would be quadratic in the
    number of frames. The rows are shared: callers only read them.
    """
    try:
        entries = read_json(path)
    except InputError as error:
        return str(error).removeprefix(f"{path}: ")
    if not isinstance(entries, list):
        return f"expected a JSON list of frames, got {type(entries).__name__}"
    rows: dict[str, dict[str, Any]] = {}
    for entry in entries:
        if isinstance(entry, dict):
            rows.setdefault(frame_id(str(entry.get("pointcloud_path", ""))), entry)
    return rows


def _timestamps(root: Source, rows: dict[str, dict[str, Any] | None], frames: tuple[str, str],
                report: Report) -> dict[str, int]:
    """Source timestamps in µs by side (``vehicle``, ``infrastructure``) and image (``vehicle_image`` …).

    ``pointcloud_timestamp`` must be in a side's row; ``image_timestamp`` is optional (the image then
    takes its sweep's time). A bad value is an error and costs that timestamp.
    """
    times = {}
    for side, frame in zip(SIDES, frames, strict=True):
        row = rows[side.name]
        if row is None:
            continue
        path = root / side.folder / "data_info.json"
        for key, field in ((side.name, "pointcloud_timestamp"), (f"{side.name}_image", "image_timestamp")):
            if field == "image_timestamp" and field not in row:
                continue
            value = row.get(field)
            try:
                times[key] = int(value)  # type: ignore[arg-type]  # a value of another type is reported below
            except (TypeError, ValueError, OverflowError):  # OverflowError: int(inf)
                report.error(path, f"frame {frame}: field {field}: expected integer µs, got {value!r:.80}")
                continue
            if not 0 <= times[key] <= MAX_TIMESTAMP_US or (isinstance(value, float) and not value.is_integer()):
                del times[key]
                report.error(path, f"frame {frame}: field {field}: expected integer µs since 1970 "
                                   f"(0 .. {MAX_TIMESTAMP_US}), got {value!r:.80}")
    return times


def _inside_relative_path(value: object) -> bool:
    """Whether ``value`` is a path DAIR-V2X writes: non-empty text without NUL, relative, never above its folder."""
    if not (isinstance(value, str) and value and "\x00" not in value):
        return False
    path = PurePosixPath(value)
    return not path.is_absolute() and ".." not in path.parts and not PureWindowsPath(value).drive
