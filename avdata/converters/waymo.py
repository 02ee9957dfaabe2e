"""Waymo Open Dataset v2 (Parquet components) -> the unified format.

``avdata convert waymo WAYMO_V2_ROOT DST``: the root holds ``<component>/<context>.parquet`` files
(optionally under split folders); each context (segment) becomes one scene. Read with pyarrow only.

The source's rows of DESIGN.md §2, and what this module does with each:

=================  ==========================================================================
Waymo v2           how it is converted
=================  ==========================================================================
world              Waymo's global frame of the segment (``vehicle_pose.world_from_vehicle``), z up,
                   not re-centred. Poses are float32 in the files (real ones off orthonormality by up
                   to ~1e-7): repaired silently up to 1e-6, with a warning up to 1e-2, refused beyond
ego                Waymo's vehicle frame (x forward, y left, z up; origin at the rear axle centre)
                   -> ``ego``; ``world -> ego`` on ``/tf`` at every frame time and at every camera
                   image's ``pose_timestamp`` (the SDC pose Waymo stores with the image)
frame of labels    vehicle frame at the frame time -> boxes stay in ``ego``, unchanged
box                centre, size (length along heading, width, height), heading about +z ->
                   ``Boxes3D.from_waymo``; ``speed`` -> velocity and ``acceleration`` (ego axes);
                   ``num_lidar_points_in_box``, ``num_top_lidar_points_in_box``, detection and
                   tracking difficulty levels -> extras; ``TYPE_*`` verbatim as source class
lidar              range images (both returns) -> points with Waymo's formulas
                   (:mod:`avdata.sources.waymo.lidar`): beam inclinations uniform or per beam, the
                   extrinsic's azimuth correction, and for the top lidar the per-pixel vehicle pose
                   (rolling sweep), so the points are Waymo's vehicle-frame points at the frame
                   time. They are stored in each lidar's own axes (``lidar_T_ego`` applied; the
                   extrinsic is on ``/tf_static``), with fields range, intensity, elongation,
                   no_label_zone, return_index (0, 1), laser_name (1..5), row, column
cameras            Waymo's camera frame is x forward, y left, z up -> the optical frame through
                   ``XFWD_T_OPTICAL`` on ``/tf_static``; intrinsics f_u, f_v, c_u, c_v and
                   distortion (k1, k2, p1, p2, k3: OpenCV's plumb_bob order); JPEG bytes untouched,
                   stamped with ``pose_timestamp``; rolling-shutter direction and per-image
                   parameters (shutter, trigger and readout-done times) in the scene metadata
projected boxes    ``projected_lidar_box`` -> each camera's ``/visibility`` 2D boxes (pixels)
time               UTC epoch: ``frame_timestamp_micros`` x 1000; image times from seconds, rounded
=================  ==========================================================================

Native camera boxes (``camera_box``, 2D labels with their own ids) have no place in the unified
format yet; their count is in the scene metadata. Memory: one context at a time; the large
components (lidar, lidar_pose, camera_image) are read a few rows at a time and joined on their
keys through a buffer that holds only rows not yet used (a few when both files are in frame order).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from avdata.converters.base import ConvertConfig, Converter, Report
from avdata.errors import InputError
from avdata.frames import XFWD_T_OPTICAL, Boxes3D, Transform
from avdata.frames.rotations import repaired_rotation
from avdata.schema import DatasetWriter, ObjectLabels, VisibilityLabels
from avdata.schema.limits import MAX_BOX_SIZE_M, MAX_CAMERA_VALUE_PX, MAX_COORDINATE_M
from avdata.sources._checks import coordinates_problem
from avdata.sources.jpeg import jpeg_problem
from avdata.sources.waymo import (
    BOX_TYPES,
    CAMERA_NAMES,
    COMPONENTS,
    LASER_NAMES,
    ComponentFile,
    beam_inclinations,
    find_component_files,
    range_image_points,
    range_image_points_lidar,
    read_component,
)
from avdata.sources.waymo.components import TIME_KEY, iter_component

#: Waymo box type -> unified class (Waymo's TYPE_VEHICLE covers cars, trucks and buses alike).
CLASS_MAP: dict[str, str] = {
    "TYPE_VEHICLE": "car",
    "TYPE_PEDESTRIAN": "pedestrian",
    "TYPE_CYCLIST": "cyclist",
    "TYPE_SIGN": "other",
    "TYPE_UNKNOWN": "other",
}

_LASER_KEY = "key.laser_name"
_CAMERA_KEY = "key.camera_name"
_OBJECT_KEY = "key.laser_object_id"


def lidar_frame(laser_name: int) -> str:
    """``ego/lidar_top`` ... for a ``LaserName`` value."""
    return f"ego/lidar_{LASER_NAMES[laser_name].lower()}"


def camera_frame(camera_name: int) -> str:
    """``ego/cam_front`` ... for a ``CameraName`` value."""
    return f"ego/cam_{CAMERA_NAMES[camera_name].lower()}"


def _as_int(values: pa.ChunkedArray | pa.Array) -> np.ndarray:
    """Integer key column (some files store camera/laser names as digit strings)."""
    return np.asarray([int(v) for v in values.to_pylist()], dtype=np.int64)


def _matrix(value: list[float | None] | None, where: str) -> np.ndarray:
    """(4, 4) float64 from one 16-float row-major list; InputError naming ``where`` otherwise."""
    if value is None or len(value) != 16 or any(v is None for v in value):
        raise InputError(f"{where}: expected 16 numbers of a 4x4 transform, got {value}")
    return np.asarray(value, dtype=np.float64).reshape(4, 4)


def _matrices(column: pa.ChunkedArray | pa.Array, where: str) -> np.ndarray:
    """(N, 4, 4) float64 from a column of 16-float row-major lists; InputError naming ``where`` and the row otherwise."""
    return np.asarray([_matrix(value, f"{where}: row {k}") for k, value in enumerate(column.to_pylist())],
                      dtype=np.float64).reshape(-1, 4, 4)


def _numbers(column: pa.ChunkedArray) -> np.ndarray:
    """A numeric column as numpy (nulls -> NaN), without ChunkedArray.to_numpy's pandas import."""
    return column.combine_chunks().to_numpy(zero_copy_only=False)


def _id_set(ids: np.ndarray | None) -> set[str]:
    """The object ids of a frame's boxes (none when the boxes carry no ids)."""
    return set() if ids is None else set(ids.tolist())


def _floats(table: pa.Table, name: str, n: int) -> np.ndarray:
    """A float column as float64, NaN for nulls; all NaN when the column is absent (optional fields)."""
    if name not in table.column_names:
        return np.full(n, np.nan)
    return np.asarray(_numbers(table.column(name)), dtype=np.float64)


class WaymoConverter(Converter):
    """Waymo Open Dataset v2 (Parquet components; one scene per context)."""

    name = "waymo"
    source = "Waymo Open Dataset"
    licence = "Waymo Dataset License Agreement for Non-Commercial Use"

    def __init__(self, config: ConvertConfig):
        super().__init__(config)
        self._files: dict[str, dict[str, ComponentFile]] | None = None

    def __getstate__(self) -> dict[str, Any]:
        # Without the file map: a worker finds it once (``files``). Pickled with every task, the map of every
        # segment's files went to the workers once per segment.
        return {**self.__dict__, "_files": None}

    def source_version(self) -> str:
        """The source's version, for the manifest."""
        return "v2 (Parquet components)"

    def files(self) -> dict[str, dict[str, ComponentFile]]:
        """Context -> component -> file, found once per process."""
        if self._files is None:
            self._files = find_component_files(self.config.src)
        return self._files

    def release(self) -> None:
        """Drops the cached source tables before the index is built."""
        self._files = None

    def list_scenes(self) -> list[str]:
        """Every scene of the source, in a stable order."""
        return list(self.files())

    def source_files(self, scene: str) -> list[Path]:
        """The context's component files."""
        return sorted(f.path for f in self.files()[scene].values())

    def convert_scene(self, scene: str, writer: DatasetWriter, report: Report) -> None:
        """Converts one scene into writer; problems of single records go to report."""
        _SceneConversion(scene, self.files()[scene], report).write(writer)


class _SceneConversion:
    """Converts one context (kept as one object so its tables die with it)."""

    def __init__(self, context: str, files: dict[str, ComponentFile], report: Report):
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
        #: components found missing or unreadable by :meth:`_read`: reported once, their later reads skipped
        self.unreadable: set[str] = set()

    # ----------------------------------------------------------------- reading
    def _path(self, component: str) -> str:
        return str(self.base / component / f"{self.context}.parquet")

    def _read(self, component: str, fields: list[str], keys: tuple[str, ...] = ()) -> pa.Table | None:
        """A whole small component, or None after reporting why it is missing or unreadable."""
        file = self.files.get(component)
        if file is None:
            self.report.error(self._path(component), f"missing component {component} of context {self.context}")
            self.unreadable.add(component)
            return None
        try:
            return read_component(file, [*keys, *(file.column(f) for f in fields)])
        except InputError as error:
            self.report.error(file.path, str(error).removeprefix(f"{file.path}: "))
            self.unreadable.add(component)
            return None

    def _poses(self) -> tuple[np.ndarray, np.ndarray, list[Transform]]:
        """(frame times in µs (F,), world_T_vehicle (F, 4, 4) as stored, the same as checked transforms), in time order.

        A pose row that is not a proper rigid transform within the limits costs its frame (every component row
        at that time is skipped, :attr:`skipped_us`), reported once; a time given twice costs both rows.
        """
        file = self.files.get("vehicle_pose")
        if file is None:
            raise InputError(f"{self._path('vehicle_pose')}: missing component vehicle_pose of context {self.context}")
        column = file.column("world_from_vehicle.transform")
        table = read_component(file, [TIME_KEY, column])
        times = _numbers(table.column(TIME_KEY))
        if not len(times):
            raise InputError(f"{file.path}: expected vehicle poses, got no rows")
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
                matrices[k] = _matrix(value, f"{file.path}: {where}")
                transforms[k] = self._transform(matrices[k], file.path, where)
            except InputError as error:
                self.report.error(file.path, f"{str(error).removeprefix(f'{file.path}: ')}; the frame is skipped")
                keep[k] = False
        self.skipped_us = {int(t) for t in times[~keep].tolist()}
        if not keep.any():
            raise InputError(f"{file.path}: expected vehicle poses, got no usable rows")
        order = np.flatnonzero(keep)[np.argsort(times[keep], kind="stable")]
        return times[order], matrices[order], [transforms[k] for k in order.tolist()]

    def _transform(self, matrix: np.ndarray, file: str | Any, what: str) -> Transform:
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

    # ----------------------------------------------------------------- scene
    def write(self, writer: DatasetWriter) -> None:
        times_us, poses, world_T_ego = self._poses()
        frame_of_time = {int(t): i for i, t in enumerate(times_us.tolist())}
        metadata: dict[str, Any] = {
            "context": self.context,
            "split": self.split,
            "world": "Waymo's global frame of the segment (vehicle_pose world_from_vehicle), z up; not re-centred",
            "ego_origin": "Waymo vehicle frame: centre of the rear axle, x forward, y left, z up",
            "time": "UTC epoch (Waymo microseconds x 1000)",
            "labels_frame": "ego (Waymo's vehicle frame at the frame time)",
        }
        metadata.update(self._stats())
        metadata["camera_rolling_shutter"], camera_poses = self._camera_poses()
        metadata["camera_box_count"] = self._camera_box_count()
        with writer.scene(self.context, metadata) as scene:
            scene.add_agent("ego", "vehicle", metadata["ego_origin"])
            # Frame poses and the poses stored with camera images, in time order (a frame pose wins a tie).
            stamped = {t * 1000: pose for t, pose in zip(times_us.tolist(), world_T_ego, strict=True)}
            for time_ns, matrix in sorted(camera_poses.items()):
                if time_ns in stamped:
                    continue
                path = self.files["camera_image"].path
                try:
                    stamped[time_ns] = self._transform(matrix, path, f"image pose at {time_ns} ns")
                except InputError as error:  # the image keeps the frame pose
                    self.report.error(path, str(error).removeprefix(f"{path}: "))
            for time_ns, pose in sorted(stamped.items()):
                scene.add_transform("world", "ego", time_ns, pose)
            sensor_times: list[dict[str, int]] = [{} for _ in times_us]
            lidars = self._lidar_calibrations(scene)
            cameras = self._camera_calibrations(scene, int(times_us[0]) * 1000)
            self._lidar_points(scene, lidars, frame_of_time, poses, sensor_times)
            self._camera_images(scene, cameras, frame_of_time, sensor_times)
            labels = self._labels(frame_of_time)
            written: dict[int, int] = {}  # frame of the segment -> its index in the scene
            for i, time_us in enumerate(times_us.tolist()):
                frame_labels = labels[i] if labels is not None else ObjectLabels.empty("ego")
                try:  # a frame the index could not place costs that frame only
                    scene.add_frame(scene.n_frames, time_us * 1000, frame_labels,
                                    sensor_timestamps_ns=dict(sorted(sensor_times[i].items())), annotated=labels is not None)
                except InputError as error:
                    self.report.error(self.files["vehicle_pose"].path, f"frame at {time_us} us: {error}")
                    continue
                written[i] = scene.n_frames - 1
            boxed_ids = None if labels is None else {
                t: _id_set(labels[i].boxes.ids) for t, i in frame_of_time.items()}
            self._projected_boxes(scene, {t: written[i] for t, i in frame_of_time.items() if i in written},
                                  boxed_ids, set(cameras))

    def _stats(self) -> dict[str, Any]:
        table = self._read("stats", ["time_of_day", "location", "weather"])
        if table is None or not table.num_rows:
            return {}
        row = table.slice(0, 1).to_pylist()[0]
        return {name: row[self.files["stats"].column(name)] for name in ("time_of_day", "location", "weather")}

    def _lidar_calibrations(self, scene: Any) -> dict[int, tuple[np.ndarray, Transform, dict[str, Any]]]:
        """Laser name -> (vehicle_T_lidar as stored, as a proper Transform, beam inclination fields)."""
        fields = ["extrinsic.transform", "beam_inclination.min", "beam_inclination.max", "beam_inclination.values"]
        table = self._read("lidar_calibration", fields, (_LASER_KEY,))
        if table is None:
            return {}
        file = self.files["lidar_calibration"]
        result = {}
        names = _as_int(table.column(_LASER_KEY))
        try:
            extrinsics = _matrices(table.column(file.column("extrinsic.transform")), file.column("extrinsic.transform"))
        except InputError as error:
            self.report.error(file.path, str(error))
            return {}
        twice = _reported_duplicates(self.report, file.path, names, _LASER_KEY, "that laser is not converted")
        for k, laser in enumerate(names.tolist()):
            if laser in twice:
                continue
            if laser not in LASER_NAMES:
                self.report.error(file.path, f"{_LASER_KEY}: expected one of {sorted(LASER_NAMES)}, got {laser}")
                continue
            frame = lidar_frame(laser)
            try:
                vehicle_T_lidar = self._transform(extrinsics[k], file.path, f"extrinsic of laser {laser}")
            except InputError as error:
                self.report.error(file.path, str(error).removeprefix(f"{file.path}: "))
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
                self.report.error(file.path, f"laser {laser}: beam_inclination: expected angles within +-pi/2 rad, got "
                                             f"{bad}; that laser is not converted")
                continue
            scene.add_sensor(frame, "lidar", laser_name=LASER_NAMES[laser], beam_inclination_min_rad=beams["min_rad"],
                             beam_inclination_max_rad=beams["max_rad"],
                             beam_inclinations_rad=None if values is None else list(values))
            scene.add_static_transform("ego", frame, vehicle_T_lidar)
            result[laser] = (extrinsics[k], vehicle_T_lidar, beams)
        return result

    def _camera_calibrations(self, scene: Any, first_time_ns: int) -> dict[int, dict[str, Any]]:
        intrinsic = [f"intrinsic.{n}" for n in ("f_u", "f_v", "c_u", "c_v", "k1", "k2", "p1", "p2", "k3")]
        fields = [*intrinsic, "extrinsic.transform", "width", "height", "rolling_shutter_direction"]
        table = self._read("camera_calibration", fields, (_CAMERA_KEY,))
        if table is None:
            return {}
        file = self.files["camera_calibration"]
        rows = table.to_pylist()
        result = {}
        names = _as_int(table.column(_CAMERA_KEY))
        twice = _reported_duplicates(self.report, file.path, names, _CAMERA_KEY, "that camera is not converted")
        self.reported_cameras |= twice
        for row, camera in zip(rows, names.tolist(), strict=True):
            if camera in twice:
                continue
            if camera not in CAMERA_NAMES:
                self.report.error(file.path, f"{_CAMERA_KEY}: expected one of {sorted(CAMERA_NAMES)}, got {camera}")
                continue
            value = {name: row[file.column(name)] for name in fields}
            empty = [name for name, v in value.items() if v is None or (isinstance(v, list) and (len(v) != 16 or None in v))
                     or (name in intrinsic and not math.isfinite(v)) or (name in _POSITIVE_CALIBRATION and v <= 0)]
            if empty:
                self.report.error(file.path, f"camera {camera}: expected finite numbers (positive focal length and size) "
                                             f"in {empty}, got {[value[n] for n in empty]}")
                self.reported_cameras.add(camera)
                continue
            frame = camera_frame(camera)
            try:
                vehicle_T_camera = self._transform(np.asarray(value["extrinsic.transform"], dtype=np.float64).reshape(4, 4),
                                                   file.path, f"extrinsic of camera {camera}")
            except InputError as error:
                self.report.error(file.path, str(error).removeprefix(f"{file.path}: "))
                self.reported_cameras.add(camera)
                continue
            fu, fv, cu, cv, k1, k2, p1, p2, k3 = (float(value[n]) for n in intrinsic)
            scene.add_sensor(frame, "camera", camera_name=CAMERA_NAMES[camera],
                             rolling_shutter_direction=int(value["rolling_shutter_direction"]),
                             width=int(value["width"]), height=int(value["height"]))
            scene.add_static_transform("ego", frame, vehicle_T_camera @ XFWD_T_OPTICAL)
            scene.add_camera_calibration(frame, first_time_ns, np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]]),
                                         int(value["width"]), int(value["height"]), D=np.array([k1, k2, p1, p2, k3]))
            result[camera] = value
        return result

    def _lidar_points(self, scene: Any, lidars: dict, frame_of_time: dict[int, int], poses: np.ndarray,
                      sensor_times: list[dict[str, int]]) -> None:
        file = self.files.get("lidar")
        if file is None:
            self.report.error(self._path("lidar"), f"missing component lidar of context {self.context}")
            return
        if not lidars:  # no usable calibration: reported with lidar_calibration
            return
        returns = ("range_image_return1", "range_image_return2")
        columns = [TIME_KEY, _LASER_KEY, *(file.column(f"{r}.{p}") for r in returns for p in ("values", "shape"))]
        pixel_poses = _KeyedRows(self.files.get("lidar_pose"), ["range_image_return1.values", "range_image_return1.shape"])
        if pixel_poses.file is None:
            self.report.error(self._path("lidar_pose"), f"missing component lidar_pose of context {self.context}")
        seen: set[tuple[int, int]] = set()
        try:
            for batch in iter_component(file, columns):
                for row in _rows(batch):
                    key = (int(row[TIME_KEY]), int(row[_LASER_KEY]))
                    if key in seen:  # the first row was written; which one is right is unknown
                        self.report.error(file.path, f"frame {key[0]} laser {key[1]}: expected one row per frame and "
                                                     "laser, got another; the later row is skipped")
                        continue
                    seen.add(key)
                    try:
                        self._one_lidar(scene, file, row, lidars, frame_of_time, poses, pixel_poses, sensor_times)
                    except _ScanError as error:  # costs that lidar in that frame
                        self.report.error(error.path, f"{error}; the frame is written without this lidar")
        except InputError as error:
            self.report.error(file.path, str(error).removeprefix(f"{file.path}: "))

    def _one_lidar(self, scene: Any, file: ComponentFile, row: dict, lidars: dict, frame_of_time: dict[int, int],
                   poses: np.ndarray, pixel_poses: _KeyedRows, sensor_times: list[dict[str, int]]) -> None:
        time_us, laser = int(row[TIME_KEY]), int(row[_LASER_KEY])
        where = f"frame {time_us} laser {laser}"
        if time_us not in frame_of_time:
            if time_us not in self.skipped_us:  # a skipped frame's rows go with it (its pose row was reported)
                self.report.error(file.path, f"{where}: {TIME_KEY}: expected a time of vehicle_pose, got {time_us}")
            return
        if laser not in lidars:
            self.report.error(file.path, f"{where}: {_LASER_KEY}: expected a calibrated laser {sorted(lidars)}, got {laser}")
            return
        extrinsic, vehicle_T_lidar, beams = lidars[laser]
        frame_index = frame_of_time[time_us]
        pixel_pose = None
        if laser == 1:  # TOP: the rolling sweep needs each pixel's vehicle pose
            if pixel_poses.file is None:  # the missing component was reported once
                return
            pose_row = pixel_poses.take((time_us, laser))
            if pose_row is None:
                self.report.error(self._path("lidar_pose"), f"{where}: expected the top lidar's pixel poses, got none")
                return
            pixel_pose = _image(pose_row, pixel_poses.file.column("range_image_return1"), self._path("lidar_pose"), where, 6)  # type: ignore[union-attr]
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
            self.report.error(file.path, f"{where}: expected range images, got none")
            return
        cloud = {name: np.concatenate([p[name] for p in parts]) for name in parts[0]}
        # A damaged range value (these floats have no checksum) puts a point at infinity: the cloud is lost.
        if (problem := coordinates_problem(cloud, MAX_COORDINATE_M)) is not None:
            self.report.error(file.path, f"{where}: {problem}; the frame is written without this lidar")
            return
        frame = lidar_frame(laser)
        scene.add_point_cloud(frame, time_us * 1000, cloud)
        sensor_times[frame_index][frame] = time_us * 1000

    def _camera_images(self, scene: Any, cameras: dict, frame_of_time: dict[int, int],
                       sensor_times: list[dict[str, int]]) -> None:
        file = self.files.get("camera_image")
        # Reported once already (by _camera_poses, _camera_calibrations): not again for every image.
        if file is None or {"camera_image", "camera_calibration"} & self.unreadable:
            return
        fields = ["image", "pose_timestamp"]
        seen: set[tuple[int, int]] = set()
        try:
            for batch in iter_component(file, [TIME_KEY, _CAMERA_KEY, *(file.column(f) for f in fields)]):
                for row in batch.to_pylist():
                    time_us, camera = int(row[TIME_KEY]), int(row[_CAMERA_KEY])
                    where = f"frame {time_us} camera {camera}"
                    if (time_us, camera) in seen:  # the first row was written; which one is right is unknown
                        self.report.error(file.path, f"{where}: expected one image per frame and camera, got another; "
                                                     "the later row is skipped")
                        continue
                    seen.add((time_us, camera))
                    if time_us not in frame_of_time:
                        if time_us not in self.skipped_us:
                            self.report.error(file.path, f"{where}: {TIME_KEY}: expected a time of vehicle_pose, got {time_us}")
                        continue
                    if camera in self.reported_cameras:  # its calibration error was reported
                        continue
                    if camera not in cameras:
                        self.report.error(file.path, f"{where}: {_CAMERA_KEY}: expected a calibrated camera "
                                                     f"{sorted(cameras)}, got {camera}")
                        continue
                    pose_s = row[file.column("pose_timestamp")]
                    if not _is_time_s(pose_s):
                        self.report.error(file.path, f"{where}: pose_timestamp: expected seconds in 0 .. 9.2e9 "
                                                     f"(int64 nanoseconds), got {pose_s}")
                        continue
                    time_ns = round(pose_s * 1e9)
                    image = row[file.column("image")]
                    problem, _ = jpeg_problem(image)
                    if problem is not None:
                        self.report.error(file.path, f"{where}: image: {problem}")
                        continue
                    frame = camera_frame(camera)
                    scene.add_image(frame, time_ns, image, "jpeg")
                    sensor_times[frame_of_time[time_us]][frame] = time_ns
        except InputError as error:
            self.report.error(file.path, str(error).removeprefix(f"{file.path}: "))

    def _camera_poses(self) -> tuple[dict[str, list[dict[str, float]]], dict[int, np.ndarray]]:
        """Camera timing and poses, images left unread.

        Returns (camera frame -> per image its frame time, pose time and rolling-shutter parameters;
        image time in ns -> the SDC pose ``world_T_vehicle`` stored with the image).
        """
        fields = ["pose_timestamp", "rolling_shutter_params.shutter", "rolling_shutter_params.camera_trigger_time",
                  "rolling_shutter_params.camera_readout_done_time"]
        table = self._read("camera_image", [*fields, "pose.transform"], (TIME_KEY, _CAMERA_KEY))
        if table is None:
            return {}, {}
        file = self.files["camera_image"]
        shutter: dict[str, list[dict[str, float]]] = {}
        poses: dict[int, np.ndarray] = {}
        for row, camera in zip(table.to_pylist(), _as_int(table.column(_CAMERA_KEY)).tolist(), strict=True):
            pose_s = row[file.column("pose_timestamp")]
            if camera not in CAMERA_NAMES or not _is_time_s(pose_s):
                continue  # reported with the image
            entry = {"frame_timestamp_us": row[TIME_KEY]}
            entry.update({name.rpartition(".")[2] + "_s": row[file.column(name)] for name in fields})
            shutter.setdefault(camera_frame(camera), []).append(entry)
            pose = row[file.column("pose.transform")]
            if pose is None or len(pose) != 16 or any(v is None for v in pose):
                self.report.error(file.path, f"frame {row[TIME_KEY]} camera {camera}: pose.transform: expected 16 numbers, "
                                             f"got {pose}")
                continue
            poses[round(pose_s * 1e9)] = np.asarray(pose, dtype=np.float64).reshape(4, 4)
        return shutter, poses

    def _labels(self, frame_of_time: dict[int, int]) -> list[ObjectLabels] | None:
        fields = ["box.center.x", "box.center.y", "box.center.z", "box.size.x", "box.size.y", "box.size.z",
                  "box.heading", "type", "num_lidar_points_in_box", "num_top_lidar_points_in_box"]
        table = self._read("lidar_box", fields, (TIME_KEY, _OBJECT_KEY))
        if table is None:
            return None
        file = self.files["lidar_box"]
        optional = [file.column(f"{group}.{axis}") for group in ("speed", "acceleration") for axis in "xyz"]
        optional += [file.column("difficulty_level.detection"), file.column("difficulty_level.tracking")]
        parquet_names = set(_schema_names(file))
        extra = [c for c in optional if c in parquet_names]
        if extra:
            table = read_component(file, [*table.column_names, *extra])
        n = table.num_rows
        col = file.column
        times = _numbers(table.column(TIME_KEY))
        known = np.asarray([int(t) in frame_of_time for t in times.tolist()], dtype=bool)
        unknown = ~known & ~np.isin(times, list(self.skipped_us))  # a skipped frame's boxes go with it
        for t in sorted(set(times[unknown].tolist()))[:1]:
            self.report.error(file.path, f"{TIME_KEY}: expected times of vehicle_pose, got {t} "
                                         f"({int(unknown.sum())} boxes skipped)")
        center = np.stack([_floats(table, col(f"box.center.{a}"), n) for a in "xyz"], axis=1)
        size = np.stack([_floats(table, col(f"box.size.{a}"), n) for a in "xyz"], axis=1)
        heading = _floats(table, col("box.heading"), n)
        speed = np.stack([_floats(table, col(f"speed.{a}"), n) for a in "xyz"], axis=1)
        accel = np.stack([_floats(table, col(f"acceleration.{a}"), n) for a in "xyz"], axis=1)
        types = _numbers(table.column(col("type")))
        id_column = table.column(_OBJECT_KEY)
        null_id = np.asarray(id_column.is_null(), dtype=bool)
        ids = np.asarray(id_column.fill_null("").to_pylist(), dtype=str)
        for k in np.flatnonzero(null_id & known).tolist():
            self.report.error(file.path, f"row {k} at {int(times[k])}: {_OBJECT_KEY}: expected an object id, got null; "
                                         "that box is skipped")
        # The scene writer's limits: a centre of 1e30 m refused there cost the segment.
        bad = ~(np.all(np.abs(center) <= MAX_COORDINATE_M, axis=1) & np.all((size >= 0) & (size <= MAX_BOX_SIZE_M), axis=1)
                & np.isfinite(heading))
        bad |= ~np.isin(types, list(BOX_TYPES))
        for k in np.flatnonzero(bad & known & ~null_id)[:5]:
            self.report.error(file.path, f"object {ids[k]} at {times[k]}: expected a box within {MAX_COORDINATE_M:g} m of "
                                         f"size 0 .. {MAX_BOX_SIZE_M:g} m and a known type, got centre {center[k].tolist()} "
                                         f"size {size[k].tolist()} heading {heading[k]} type {types[k]}; that box is skipped")
        bad |= null_id
        # An object given twice in one frame: which row is right is unknown, so neither is kept.
        pairs = np.asarray([f"{int(t)}/{i}" for t, i in zip(times.tolist(), ids.tolist(), strict=True)])
        unique_pairs, counts = np.unique(pairs[~null_id], return_counts=True)
        repeated = np.isin(pairs, unique_pairs[counts > 1]) & ~null_id
        for pair in unique_pairs[counts > 1].tolist():
            time_text, object_id = pair.split("/", 1)
            self.report.error(file.path, f"object {object_id} at {time_text}: expected one box per frame, got "
                                         f"{int(np.sum(pairs == pair))}; those boxes are skipped")
        keep = known & ~bad & ~repeated
        source = np.asarray([BOX_TYPES[int(t)] if int(t) in BOX_TYPES else "" for t in types])
        box_extras = {name: _floats(table, col(name), n) for name in ("num_lidar_points_in_box", "num_top_lidar_points_in_box")}
        # An unset difficulty is UNKNOWN (0), the proto default that Waymo's metrics count at both levels.
        box_extras["detection_difficulty_level"] = np.nan_to_num(_floats(table, col("difficulty_level.detection"), n), nan=0.0)
        box_extras["tracking_difficulty_level"] = np.nan_to_num(_floats(table, col("difficulty_level.tracking"), n), nan=0.0)
        frames = np.asarray([frame_of_time.get(int(t), -1) for t in times.tolist()])
        labels = []
        for i in range(len(frame_of_time)):
            rows = np.flatnonzero(keep & (frames == i))
            if not len(rows):
                labels.append(ObjectLabels.empty("ego"))
                continue
            boxes = Boxes3D.from_waymo(center[rows], size[rows], heading[rows], "ego", ids=ids[rows],
                                       classes=np.asarray([CLASS_MAP[s] for s in source[rows]]), velocity=speed[rows])
            extras = [{name: float(values[k]) for name, values in box_extras.items()} for k in rows.tolist()]
            labels.append(ObjectLabels(boxes=boxes, source_classes=source[rows], acceleration=accel[rows], extras=extras))
        return labels

    def _projected_boxes(self, scene: Any, frame_of_time: dict[int, int], boxed_ids: dict[int, set[str]] | None,
                         cameras_written: set[int]) -> None:
        """Each written camera's 2D boxes of the objects that have a 3D box in that frame.

        A camera whose calibration was refused takes its visibility labels with it (reported with the calibration),
        and a 2D box of an object without a 3D box is left out with a warning. ``boxed_ids`` (frame time in µs ->
        ids of its 3D boxes) is None when lidar_box is missing or unreadable (reported): no 2D box is written.
        """
        fields = ["box.center.x", "box.center.y", "box.size.x", "box.size.y", "type"]
        table = self._read("projected_lidar_box", fields, (TIME_KEY, _CAMERA_KEY, _OBJECT_KEY))
        if table is None or boxed_ids is None:
            return
        file = self.files["projected_lidar_box"]
        n = table.num_rows
        times = _numbers(table.column(TIME_KEY))
        cameras = _as_int(table.column(_CAMERA_KEY))
        ids = np.asarray(table.column(_OBJECT_KEY).to_pylist(), dtype=str)
        cx, cy, sx, sy = (_floats(table, file.column(f), n) for f in fields[:4])
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow (inf) or NaN fails the same test
            xyxy = np.stack([cx - sx / 2, cy - sy / 2, cx + sx / 2, cy + sy / 2], axis=1)
            bad = ~(np.all(np.abs(xyxy) <= MAX_CAMERA_VALUE_PX, axis=1) & (sx >= 0) & (sy >= 0))
        if bad.any():  # one line for all of them; each costs only its own 2D box
            first = int(np.flatnonzero(bad)[0])
            self.report.error(file.path, f"box.center / box.size: expected corners within {MAX_CAMERA_VALUE_PX:g} px and "
                                         f"sizes >= 0, got {int(bad.sum())} "
                                         f"row(s), first row {first} (object {ids[first]}): center ({cx[first]}, {cy[first]}), "
                                         f"size ({sx[first]}, {sy[first]}); those 2D boxes are left out")
            times, cameras, ids, xyxy = times[~bad], cameras[~bad], ids[~bad], xyxy[~bad]
        for time_us in sorted(set(times.tolist())):
            if int(time_us) not in frame_of_time:
                if int(time_us) not in self.skipped_us:
                    self.report.error(file.path, f"{TIME_KEY}: expected a time of vehicle_pose, got {time_us}")
                continue
            in_frame = times == time_us
            orphans = in_frame & ~np.isin(ids, list(boxed_ids[int(time_us)]))
            if orphans.any():
                self.report.warn(file.path, f"frame {int(time_us)}: {_OBJECT_KEY}: expected objects with a 3D box, got "
                                            f"{sorted(set(ids[orphans].tolist()))[:5]} ({int(orphans.sum())} 2D boxes); "
                                            "those 2D boxes are left out")
            for camera in sorted(set(cameras[in_frame].tolist())):
                if camera not in CAMERA_NAMES:
                    self.report.error(file.path, f"{_CAMERA_KEY}: expected one of {sorted(CAMERA_NAMES)}, got {camera}")
                    continue
                if camera not in cameras_written:  # its calibration was refused (reported there)
                    continue
                rows = np.flatnonzero(in_frame & (cameras == camera) & ~orphans)
                visibility = VisibilityLabels(object_ids=ids[rows], in_fov=np.ones(len(rows), dtype=bool), box2d_xyxy=xyxy[rows])
                scene.add_visibility(camera_frame(camera), frame_of_time[int(time_us)], int(time_us) * 1000, visibility)

    def _camera_box_count(self) -> int:
        table = self._read("camera_box", ["type"], (TIME_KEY,))
        return 0 if table is None else table.num_rows


#: Camera calibration fields that must be positive (focal lengths in pixels, image size).
_POSITIVE_CALIBRATION = ("intrinsic.f_u", "intrinsic.f_v", "width", "height")


def _schema_names(file: ComponentFile) -> list[str]:
    return pq.read_schema(file.path).names


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


def _image(row: dict, prefix: str, path: str, where: str, channels: int) -> np.ndarray | None:
    """(H, W, channels) float32 of a ``values``/``shape`` range-image column pair; None when the return is absent.

    Raises :class:`_ScanError` for a shape that is not (H > 0, W > 0, ``channels``) holding exactly the
    values given (Waymo's returns have 4 channels, range, intensity, elongation, no-label zone; pixel
    poses 6), values missing for a given shape, or values without a shape.
    """
    values, shape = row.get(f"{prefix}.values"), row.get(f"{prefix}.shape")
    if (values is None or not len(values)) and (shape is None or not len(shape)):
        return None
    size = 0 if values is None else len(values)
    shape_list = None if shape is None else [int(v) for v in shape]
    if (shape_list is None or len(shape_list) != 3 or min(shape_list) <= 0 or shape_list[2] != channels
            or int(np.prod(shape_list)) != size):
        raise _ScanError(path, f"{where}: {prefix}.shape: expected (H, W, {channels}) holding the {size} values given, "
                               f"got {shape_list}")
    return np.asarray(values, dtype=np.float32).reshape(shape_list)


def _reported_duplicates(report: Report, path: Path, names: np.ndarray, key: str, cost: str) -> set[int]:
    """The key values given more than once (each reported as one error: which row is right is unknown)."""
    values, counts = np.unique(names, return_counts=True)
    for value, count in zip(values[counts > 1].tolist(), counts[counts > 1].tolist(), strict=True):
        report.error(path, f"{key}: {value} given {count} times; {cost}")
    return set(values[counts > 1].tolist())


class _KeyedRows:
    """Rows of a large component taken by key, read a few rows at a time in file order.

    Rows read past the one asked for wait in a buffer until taken; when the file is in the same
    order as the lookups (Waymo writes frames in time order) the buffer stays a few rows long.
    """

    def __init__(self, file: ComponentFile | None, fields: list[str]):
        self.file = file
        self.buffer: dict[tuple[int, int], dict] = {}
        self.rows: Iterator[dict] | None = None
        if file is not None:
            columns = [TIME_KEY, _LASER_KEY, *(file.column(f) for f in fields)]
            self.rows = (row for batch in iter_component(file, columns) for row in _rows(batch))

    def take(self, key: tuple[int, int]) -> dict | None:
        if key in self.buffer:
            return self.buffer.pop(key)
        for row in self.rows or ():
            row_key = (int(row[TIME_KEY]), int(row[_LASER_KEY]))
            if row_key == key:
                return row
            self.buffer[row_key] = row
        return None


__all__ = ["CLASS_MAP", "COMPONENTS", "WaymoConverter", "camera_frame", "lidar_frame"]


def _is_time_s(value: float | None) -> bool:
    """Whether ``value`` seconds is a time avdata can store: int64 nanoseconds, not before 1970."""
    return value is not None and bool(np.isfinite(value)) and 0.0 <= value < 9.2e9
