"""Waymo lidars: calibrations (extrinsics, beam inclinations) and range images -> point clouds."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pyarrow as pa

from avdata.converters.waymo.segment import (
    LASER_KEY,
    Segment,
    as_int,
    file_rows,
    lidar_frame,
    matrices_4x4,
    reported_duplicates,
)
from avdata.errors import InputError
from avdata.frames import Transform
from avdata.schema.limits import MAX_COORDINATE_M
from avdata.sources import coordinates_problem
from avdata.sources.waymo import (
    LASER_NAMES,
    ComponentFile,
    beam_inclinations,
    range_image_points,
    range_image_points_lidar,
)
from avdata.sources.waymo.components import TIME_KEY, iter_component

#: A calibrated lidar: vehicle_T_lidar as stored, the same as a proper Transform, its beam inclination fields.
_Lidar = tuple[np.ndarray, Transform, dict[str, Any]]


def lidar_calibrations(seg: Segment, scene: Any) -> dict[int, _Lidar]:
    """Laser name -> (vehicle_T_lidar as stored, as a proper Transform, beam inclination fields)."""
    fields = ["extrinsic.transform", "beam_inclination.min", "beam_inclination.max", "beam_inclination.values"]
    table = seg.read("lidar_calibration", fields, (LASER_KEY,))
    if table is None:
        return {}
    file = seg.files["lidar_calibration"]
    result = {}
    names = as_int(table.column(LASER_KEY))
    try:
        extrinsics = matrices_4x4(table.column(file.column("extrinsic.transform")), file.column("extrinsic.transform"),
                                  file_rows(table))
    except InputError as error:
        seg.report.error(file.path, str(error))
        return {}
    twice = reported_duplicates(seg.report, file.path, names, LASER_KEY, "that laser is not converted")
    for k, laser in enumerate(names.tolist()):
        if laser in twice:
            continue
        if laser not in LASER_NAMES:
            seg.report.error(file.path, f"{LASER_KEY}: expected one of {sorted(LASER_NAMES)}, got {laser}")
            continue
        frame = lidar_frame(laser)
        try:
            vehicle_T_lidar = seg.transform(extrinsics[k], file.path, f"extrinsic of laser {laser}")
        except InputError as error:
            seg.report.error(file.path, str(error).removeprefix(f"{file.path}: "))
            continue
        values = table.column(file.column("beam_inclination.values"))[k].as_py()
        beams = {
            "min_rad": table.column(file.column("beam_inclination.min"))[k].as_py(),
            "max_rad": table.column(file.column("beam_inclination.max"))[k].as_py(),
            "values_rad": None if values is None else np.asarray(values, dtype=np.float64),
        }
        # Inclinations are angles within +-pi/2; a NaN one also made the scene's JSON metadata unwritable.
        angles = np.asarray([beams["min_rad"], beams["max_rad"]] if values is None else values, dtype=np.float64)
        if not np.all(np.abs(angles) <= np.pi / 2):
            bad = angles[~(np.abs(angles) <= np.pi / 2)][0]
            seg.report.error(file.path, f"laser {laser}: beam_inclination: expected angles within +-pi/2 rad, got "
                                         f"{bad}; that laser is not converted")
            continue
        scene.add_sensor(frame, "lidar", laser_name=LASER_NAMES[laser], beam_inclination_min_rad=beams["min_rad"],
                         beam_inclination_max_rad=beams["max_rad"],
                         beam_inclinations_rad=None if values is None else list(values))
        scene.add_static_transform("ego", frame, vehicle_T_lidar)
        result[laser] = (extrinsics[k], vehicle_T_lidar, beams)
    return result


def lidar_points(seg: Segment, scene: Any, lidars: dict[int, _Lidar], frame_of_time: dict[int, int], poses: np.ndarray,
                  sensor_times: list[dict[str, int]]) -> None:
    """Writes each frame's point cloud of every calibrated lidar; a bad row costs that lidar in that frame."""
    file = seg.files.get("lidar")
    if file is None:
        seg.report.error(seg.path("lidar"), f"missing component lidar of context {seg.context}")
        return
    if not lidars:  # no usable calibration: reported with lidar_calibration
        return
    returns = ("range_image_return1", "range_image_return2")
    columns = [TIME_KEY, LASER_KEY, *(file.column(f"{r}.{p}") for r in returns for p in ("values", "shape"))]
    pixel_poses = _KeyedRows(seg, seg.files.get("lidar_pose"), ["range_image_return1.values", "range_image_return1.shape"])
    if pixel_poses.file is None:
        seg.report.error(seg.path("lidar_pose"), f"missing component lidar_pose of context {seg.context}")
    seen: set[tuple[int, int]] = set()
    try:
        for row in _keyed_rows(seg, file, columns):
            key = (int(row[TIME_KEY]), int(row[LASER_KEY]))
            if key in seen:  # the first row was written; which one is right is unknown
                seg.report.error(file.path, f"frame {key[0]} laser {key[1]}: expected one row per frame and "
                                             "laser, got another; the later row is skipped")
                continue
            seen.add(key)
            try:
                _one_lidar(seg, scene, file, row, lidars, frame_of_time, poses, pixel_poses, sensor_times)
            except _ScanError as error:  # costs that lidar in that frame
                seg.report.error(error.path, f"{error}; the frame is written without this lidar")
    except InputError as error:
        seg.report.error(file.path, str(error).removeprefix(f"{file.path}: "))


def _one_lidar(seg: Segment, scene: Any, file: ComponentFile, row: dict[str, Any], lidars: dict[int, _Lidar],
               frame_of_time: dict[int, int], poses: np.ndarray, pixel_poses: _KeyedRows,
               sensor_times: list[dict[str, int]]) -> None:
    time_us, laser = int(row[TIME_KEY]), int(row[LASER_KEY])
    where = f"frame {time_us} laser {laser}"
    if time_us not in frame_of_time:
        if time_us not in seg.skipped_us:  # a skipped frame's rows go with it (its pose row was reported)
            seg.report.error(file.path, f"{where}: {TIME_KEY}: expected a time of vehicle_pose, got {time_us}")
        return
    if laser not in lidars:
        seg.report.error(file.path, f"{where}: {LASER_KEY}: expected a calibrated laser {sorted(lidars)}, got {laser}")
        return
    extrinsic, vehicle_T_lidar, beams = lidars[laser]
    frame_index = frame_of_time[time_us]
    pixel_pose = None
    if laser == 1:  # TOP: the rolling sweep needs each pixel's vehicle pose
        if pixel_poses.file is None:  # the missing component was reported once
            return
        pose_row = pixel_poses.take((time_us, laser))
        if pose_row is None:
            seg.report.error(seg.path("lidar_pose"), f"{where}: expected the top lidar's pixel poses, got none")
            return
        pixel_pose = _image(pose_row, pixel_poses.file.column("range_image_return1"), seg.path("lidar_pose"), where, 6)
    parts = []
    for index, name in enumerate(("range_image_return1", "range_image_return2")):
        image = _image(row, file.column(name), str(file.path), where, 4)
        if image is None:
            continue
        if np.isnan(image[..., 0]).any():  # range > 0 would drop a NaN pixel without a word
            pixel = np.argwhere(np.isnan(image[..., 0]))[0].tolist()
            raise _ScanError(str(file.path), f"{where}: {file.column(name)}.values: expected a range, got nan at pixel (row, "
                                             f"column) {tuple(pixel)}")
        if pixel_pose is not None and pixel_pose.shape[:2] != image.shape[:2]:
            raise _ScanError(str(file.path), f"{where}: {name}.shape: expected (H, W) as lidar_pose "
                                             f"{list(pixel_pose.shape[:2])}, got {list(image.shape)}")
        try:
            inclinations = beam_inclinations(image.shape[0], beams["min_rad"], beams["max_rad"], beams["values_rad"])
        except InputError as error:
            raise _ScanError(str(file.path), f"{where}: {error}") from None
        if pixel_pose is None:
            # Lidar-frame points: E_ortho @ p = Waymo's E @ p up to the float64 noise orthonormalising removed.
            points, pixels = range_image_points_lidar(image, extrinsic, inclinations)
        else:
            points_vehicle, pixels = range_image_points(image, extrinsic, inclinations, pixel_pose, poses[frame_index])
            points = vehicle_T_lidar.inverse().apply(points_vehicle)
        values = image[pixels[:, 0], pixels[:, 1]]
        parts.append({
            "x": points[:, 0].astype(np.float32),
            "y": points[:, 1].astype(np.float32),
            "z": points[:, 2].astype(np.float32),
            "range": values[:, 0].astype(np.float32),
            "intensity": values[:, 1].astype(np.float32),
            "elongation": values[:, 2].astype(np.float32),
            "no_label_zone": (values[:, 3] > 0).astype(np.uint8) if image.shape[-1] > 3 else np.zeros(len(values), np.uint8),
            "return_index": np.full(len(values), index, dtype=np.uint8),
            "laser_name": np.full(len(values), laser, dtype=np.uint8),
            "row": pixels[:, 0].astype(np.uint16),
            "column": pixels[:, 1].astype(np.uint16),
        })
    if not parts:
        seg.report.error(file.path, f"{where}: expected range images, got none")
        return
    cloud = {name: np.concatenate([p[name] for p in parts]) for name in parts[0]}
    # A damaged range value (these floats have no checksum) puts a point at infinity: the cloud is lost.
    if (problem := coordinates_problem(cloud, MAX_COORDINATE_M)) is not None:
        seg.report.error(file.path, f"{where}: {problem}; the frame is written without this lidar")
        return
    frame = lidar_frame(laser)
    scene.add_point_cloud(frame, time_us * 1000, cloud)
    sensor_times[frame_index][frame] = time_us * 1000


def _keyed_rows(seg: Segment, file: ComponentFile, columns: list[str]) -> Iterator[dict[str, Any]]:
    """The rows of a large lidar component (:func:`_rows`) whose time and laser keys are not null (those reported)."""
    row_number = 0
    for batch in iter_component(file, columns):
        for row in _rows(batch):
            null = next((key for key in (TIME_KEY, LASER_KEY) if row[key] is None), None)
            if null is not None:
                seg.report.error(file.path, f"row {row_number}: {null}: expected an integer, got null; that row is skipped")
            else:
                yield row
            row_number += 1


def _rows(batch: pa.RecordBatch) -> list[dict[str, Any]]:
    """The batch's rows as dicts; list columns (range images) as numpy arrays, zero-copy where Arrow allows."""
    columns: dict[str, list[Any]] = {}
    for name, column in zip(batch.schema.names, batch.columns, strict=True):
        if pa.types.is_list(column.type) or pa.types.is_fixed_size_list(column.type):
            columns[name] = [None if not column[i].is_valid else column[i].values.to_numpy(zero_copy_only=False)
                             for i in range(len(column))]
        else:
            columns[name] = column.to_pylist()
    return [{name: values[i] for name, values in columns.items()} for i in range(batch.num_rows)]


class _ScanError(Exception):
    """A range image that cannot be read: costs that lidar in that frame (the message names the file's row)."""

    def __init__(self, path: str, message: str):
        super().__init__(message)
        self.path = path


def _image(row: dict[str, Any], prefix: str, path: str, where: str, channels: int) -> np.ndarray | None:
    """(H, W, channels) float32 of a ``values``/``shape`` range-image column pair; None when the return is absent.

    Raises :class:`_ScanError` for a shape that is not (H > 0, W > 0, ``channels``) holding exactly the
    values given (Waymo's returns have 4 channels, range, intensity, elongation, no-label zone; pixel
    poses 6), values missing for a given shape, or values without a shape.
    """
    values, shape = row.get(f"{prefix}.values"), row.get(f"{prefix}.shape")
    if (values is None or not len(values)) and (shape is None or not len(shape)):
        return None
    size = 0 if values is None else len(values)
    shape_list = None if shape is None else [int(v) if np.isfinite(v) else None for v in shape]  # null elements: NaN
    dims = [v for v in shape_list or () if v is not None]
    if (shape_list is None or len(dims) != 3 or min(dims) <= 0 or dims[2] != channels or int(np.prod(dims)) != size):
        raise _ScanError(path, f"{where}: {prefix}.shape: expected (H, W, {channels}) holding the {size} values given, "
                               f"got {shape_list}")
    return np.asarray(values, dtype=np.float32).reshape(dims)


class _KeyedRows:
    """Rows of a large component taken by key, read a few rows at a time in file order.

    Rows read past the one asked for wait in a buffer until taken; when the file is in the same
    order as the lookups (Waymo writes frames in time order) the buffer stays a few rows long.
    """

    def __init__(self, seg: Segment, file: ComponentFile | None, fields: list[str]):
        self.file = file
        self.buffer: dict[tuple[int, int], dict[str, Any]] = {}
        self.rows: Iterator[dict[str, Any]] | None = None
        if file is not None:
            self.rows = _keyed_rows(seg, file, [TIME_KEY, LASER_KEY, *(file.column(f) for f in fields)])

    def take(self, key: tuple[int, int]) -> dict[str, Any] | None:
        if key in self.buffer:
            return self.buffer.pop(key)
        for row in self.rows or ():
            row_key = (int(row[TIME_KEY]), int(row[LASER_KEY]))
            if row_key == key:
                return row
            self.buffer[row_key] = row
        return None
