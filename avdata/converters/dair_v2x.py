"""DAIR-V2X-C (vehicle + infrastructure cooperative pairs) -> multi-agent unified scenes.

One scene per pair of ``cooperative/data_info.json`` (``selected_data_info.json`` when that is the
file present), named ``coop_<vehicle frame id>``. The source's rows of DESIGN.md §2:

==================  ==================================================================================
DAIR-V2X-C          how it is converted
==================  ==================================================================================
world               DAIR's world (map) frame, right-handed, z up; not re-centred
ego (vehicle)       agent ``ego``, body = the NovAtel (INS) frame: ``world -> ego`` =
                    ``novatel_to_world``; ``ego/lidar`` = ``lidar_to_novatel`` on /tf_static, so the
                    lidar's world pose is ``novatel_to_world @ lidar_to_novatel`` (devkit). The frame's
                    one pose is stamped at the sweep's and the vehicle image's times (the devkit uses it
                    for both)
infrastructure      agent ``infra`` (fixed): ``world -> infra`` = ``virtuallidar_to_world`` with
                    ``system_error_offset`` added to its x, y translation (devkit); ``infra/lidar`` = identity
rotations           orthonormalised (SVD); residual max |RᵀR - I| recorded per file in the metadata,
                    warned above 1e-6, refused above 1e-2
points              PCDs (binary_compressed, mixed types: vehicle ``intensity`` u8, ``timestamp`` f8)
                    stored untouched in each lidar's frame, every field kept
objects             ``cooperative/label_world`` boxes (centre, l w h, yaw about z) in ``world``;
                    ids ``0 .. N-1`` in file order (DAIR-V2X-C has no track ids)
per-side labels     ``label/lidar`` (vehicle) and ``label/virtuallidar`` (infra): visibility hints of
                    each lidar: a cooperative object is ``in_fov`` when a side box's centre, moved to
                    world, lies inside it (grown by 0.5 m)
time                ``pointcloud_timestamp`` (µs) of the vehicle side's data_info when present, else 0
                    (flagged scene-relative); the infrastructure sweep at its own ``pointcloud_timestamp``
cameras             ``ego/camera``, ``infra/camera``: DAIR's camera frames are optical (x right, y down,
                    z forward), so nothing is rotated. The pair's ``vehicle_image_path`` /
                    ``infrastructure_image_path``, JPEG bytes untouched (checked whole, size from its
                    frame header), at the side row's ``image_timestamp`` (µs) when the scene time is
                    absolute, else at that side's sweep time. ``/tf_static`` ``<agent>/lidar ->
                    <agent>/camera`` = the inverse of ``lidar_to_camera`` / ``virtuallidar_to_camera``
                    (which map lidar points into the camera), rotation orthonormalised as above.
                    CameraCalibration: K = ``cam_K``, D = ``cam_D`` (plumb_bob), P = [K | 0], so P
                    projects as the devkit does (``cam_K @ (R @ p + t)``; it never applies ``cam_D``).
                    Calibration files as the side's data_info row names them (``calib_camera_intrinsic_path``,
                    ``calib_[virtual]lidar_to_camera_path``), by the image's frame id without a row
==================  ==================================================================================

A missing image costs that camera with a warning (its calibration is not read); a damaged image or
camera calibration costs that camera with an error.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from avdata.converters.base import Converter, Report
from avdata.converters.opv2v import count_points_in_boxes
from avdata.errors import InputError
from avdata.frames import Boxes3D, Transform
from avdata.frames.rotations import SILENT_TOLERANCE
from avdata.inputs import is_present, read_regular_file
from avdata.schema import DatasetWriter, ObjectLabels, VisibilityLabels
from avdata.sources.dair_v2x import (
    DISTORTION_MODEL,
    Calibration,
    CameraIntrinsic,
    Labels3D,
    read_calibration,
    read_camera_intrinsic,
    read_json,
    read_labels,
    unified_class,
)
from avdata.sources.jpeg import jpeg_problem
from avdata.sources.pcd import read_pcd

HINT_MARGIN_M = 0.5
#: Point-cloud timestamps beyond this (µs, year 2262) would overflow int64 ns.
MAX_TIMESTAMP_US = 9_223_372_036_854_775
#: The fields of a cooperative pair that name files, relative to the source root.
PAIR_PATHS = ("vehicle_pointcloud_path", "infrastructure_pointcloud_path", "cooperative_label_path")


def _frame_id(path: str) -> str:
    return Path(path).stem


@dataclass(frozen=True, slots=True, kw_only=True)
class _Side:
    """One side of a pair: its folder, its agent and the names of its camera fields and files."""

    name: str
    folder: str
    agent: str
    image_field: str
    extrinsic: str


SIDES = (
    _Side(name="vehicle", folder="vehicle-side", agent="ego", image_field="vehicle_image_path",
          extrinsic="lidar_to_camera"),
    _Side(name="infrastructure", folder="infrastructure-side", agent="infra", image_field="infrastructure_image_path",
          extrinsic="virtuallidar_to_camera"),
)


@dataclass(frozen=True, slots=True, kw_only=True)
class _Camera:
    """One side's camera, read and checked before the scene opens (its ``/tf_static`` entry goes first)."""

    frame: str
    lidar: str
    source: str
    lidar_T_camera: Transform
    #: the extrinsic's name in the metadata's ``calibration_residuals`` and its residual there
    calibration: str
    residual: float
    intrinsic: CameraIntrinsic
    image: bytes
    width: int
    height: int
    time_ns: int


class DairV2xConverter(Converter):
    """DAIR-V2X-C cooperative pairs (cooperative/data_info.json, vehicle-side/, infrastructure-side/)."""

    name = "dair-v2x"
    source = "DAIR-V2X-C"
    licence = "research use only (DAIR-V2X terms)"

    def __init__(self, config: Any):
        super().__init__(config)
        self._pairs: dict[str, dict] | None = None

    def __getstate__(self) -> dict[str, Any]:
        # Without the pairs: a worker reads them once (``_info``). Pickled with every task, all ~6,600 of
        # DAIR-V2X-C's pairs went to the workers once per pair.
        return {**self.__dict__, "_pairs": None}

    def _info(self) -> dict[str, dict]:
        if self._pairs is None:
            root = Path(self.config.src)
            path = root / "cooperative" / "data_info.json"
            selected = root / "cooperative" / "selected_data_info.json"
            # exists() rather than is_file(): a folder or FIFO there is reported as itself, not as a missing file.
            if not is_present(path) and is_present(selected):
                path = selected
            entries = read_json(path)
            if not isinstance(entries, list) or not entries:
                got = "an empty list" if isinstance(entries, list) else type(entries).__name__
                raise InputError(f"{path}: expected a JSON list of cooperative pairs, got {got}")
            pairs = {}
            for index, entry in enumerate(entries):
                try:
                    pairs[f"coop_{_frame_id(entry['vehicle_pointcloud_path'])}"] = {**entry, "_file": str(path)}
                except (KeyError, TypeError):
                    raise InputError(f"{path}: entry [{index}]: expected vehicle_pointcloud_path, got {entry!r:.80}") from None
            self._pairs = pairs
        return self._pairs

    def release(self) -> None:
        """Drops the cached source tables before the index is built."""
        self._pairs = None

    def list_scenes(self) -> list[str]:
        """Every scene of the source, in a stable order."""
        return sorted(self._info())

    def convert_scene(self, scene: str, writer: DatasetWriter, report: Report) -> None:
        """Converts one scene into writer; problems of single records go to report."""
        root = Path(self.config.src)
        pair = self._info()[scene]
        info_file = pair["_file"]
        try:
            offset = pair.get("system_error_offset") or {"delta_x": 0.0, "delta_y": 0.0}
            offset_xy = (float(offset["delta_x"]), float(offset["delta_y"]))
            paths = {key: pair[key] for key in PAIR_PATHS}
        except (KeyError, TypeError, ValueError) as error:
            raise InputError(f"{info_file}: {scene}: expected {', '.join(PAIR_PATHS)} and numeric "
                             f"system_error_offset delta_x / delta_y, got {type(error).__name__} {error}") from None
        for key, value in [*paths.items(), *zip(("delta_x", "delta_y"), offset_xy, strict=True)]:
            if not (isinstance(value, str) and value) and not (isinstance(value, float) and np.isfinite(value)):
                raise InputError(f"{info_file}: {scene}: field {key}: expected a relative path or a finite number, "
                                 f"got {value!r:.80}")
        vehicle_id = _frame_id(paths["vehicle_pointcloud_path"])
        infra_id = _frame_id(paths["infrastructure_pointcloud_path"])
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
            _warn_residual(report, calibration_paths[name], calibration)
        rows = {side.name: _data_info_row(root / side.folder / "data_info.json", frame, report)
                for side, frame in zip(SIDES, (vehicle_id, infra_id), strict=True)}
        source_times = _timestamps(root, rows, (vehicle_id, infra_id), report)
        time_ns = source_times.get("vehicle", 0) * 1000
        # The infrastructure sweep and both images keep their own capture times (pairs are matched within
        # ~100 ms) when the scene time is absolute. The infrastructure is fixed; the vehicle image gets the
        # frame's one ego pose stamped at its time too (pose_times_ns).
        absolute = "vehicle" in source_times
        cloud_times = {"ego/lidar": time_ns, "infra/lidar": time_ns}
        if absolute and "infrastructure" in source_times:
            cloud_times["infra/lidar"] = source_times["infrastructure"] * 1000
        cameras = []
        for side in SIDES:
            own_us = source_times.get(f"{side.name}_image") if absolute else None
            image_time_ns = cloud_times[f"{side.agent}/lidar"] if own_us is None else own_us * 1000
            camera = _read_camera(root, side, pair, rows[side.name], image_time_ns, report)
            if camera is not None:
                cameras.append(camera)
        novatel_T_lidar = calibrations["vehicle lidar_to_novatel"].transform
        world_T_novatel = calibrations["vehicle novatel_to_world"].transform
        world_T_infra = calibrations["infrastructure virtuallidar_to_world"].transform
        residuals = {name: c.residual for name, c in calibrations.items()}
        residuals.update({camera.calibration: camera.residual for camera in cameras})
        metadata = {
            "vehicle_frame": vehicle_id,
            "infrastructure_frame": infra_id,
            "system_error_offset_m": list(offset_xy),
            "calibration_residuals": residuals,
            "source_timestamps_us": source_times,
            "world_origin": "DAIR-V2X world (map) frame, z up",
            "time": "vehicle pointcloud_timestamp (UTC)" if source_times.get("vehicle") else "scene-relative: 0",
            "ego_pose": "the frame's one novatel_to_world, stamped at the vehicle sweep's time and at the vehicle "
                        "image's when there is one (the devkit uses it for both: "
                        "v2x/dataset/dataset_utils/frame.py VICFrame.transform)",
        }
        pose_times_ns = sorted({time_ns, *(camera.time_ns for camera in cameras if camera.lidar == "ego/lidar")})
        with writer.scene(scene, metadata) as out:
            out.add_agent("ego", kind="vehicle", origin="the NovAtel INS (novatel_to_world)", source_id=vehicle_id)
            out.add_agent("infra", kind="infrastructure", origin="the infrastructure (virtual) LiDAR", source_id=infra_id)
            out.add_sensor("ego/lidar", kind="lidar", source="vehicle-side/velodyne")
            out.add_sensor("infra/lidar", kind="lidar", source="infrastructure-side/velodyne")
            out.add_static_transform("ego", "ego/lidar", novatel_T_lidar)
            out.add_static_transform("world", "infra", world_T_infra)
            out.add_static_transform("infra", "infra/lidar", Transform.identity())
            for camera in cameras:
                out.add_sensor(camera.frame, kind="camera", width=camera.width, height=camera.height,
                               source=camera.source)
                out.add_static_transform(camera.lidar, camera.frame, camera.lidar_T_camera)
            for pose_time_ns in pose_times_ns:
                out.add_transform("world", "ego", pose_time_ns, world_T_novatel)
            sensor_times = {}
            clouds = {}
            sides = (("ego/lidar", pair["vehicle_pointcloud_path"], vehicle / "label" / "lidar" / f"{vehicle_id}.json",
                      world_T_novatel @ novatel_T_lidar),
                     ("infra/lidar", pair["infrastructure_pointcloud_path"],
                      infra / "label" / "virtuallidar" / f"{infra_id}.json", world_T_infra))
            for sensor, cloud_path, _, world_T_lidar in sides:
                try:
                    points = read_pcd(root / cloud_path)
                    out.add_point_cloud(sensor, cloud_times[sensor], points)
                    sensor_times[sensor] = cloud_times[sensor]
                    xyz = np.stack([points["x"], points["y"], points["z"]], axis=1).astype(np.float64)
                    clouds[sensor] = world_T_lidar.apply(xyz)
                except InputError as error:
                    report.error(root / cloud_path, str(error))
            for camera in cameras:
                out.add_camera_calibration(camera.frame, camera.time_ns, K=camera.intrinsic.K, width=camera.width,
                                           height=camera.height, D=camera.intrinsic.D,
                                           distortion_model=DISTORTION_MODEL)
                out.add_image(camera.frame, camera.time_ns, camera.image, "jpeg")
                sensor_times[camera.frame] = camera.time_ns
            objects = self._objects(root / pair["cooperative_label_path"], report)
            out.add_frame(0, time_ns, objects, sensor_timestamps_ns=sensor_times)
            for sensor, _, label_path, world_T_lidar in sides:
                if sensor in clouds:
                    out.add_visibility(sensor, 0, time_ns,
                                       self._hints(label_path, world_T_lidar, objects, clouds[sensor], report))

    def _objects(self, path: Path, report: Report) -> ObjectLabels:
        try:
            labels, errors = read_labels(path)
        except InputError as error:
            report.error(path, str(error))
            return ObjectLabels.empty("world")
        for line in errors:
            report.error(path, line.removeprefix(f"{path}: "))
        ids = np.arange(len(labels.yaw_rad)).astype(str)
        classes = np.array([unified_class(c) for c in labels.source_classes], dtype=str).reshape(len(ids))
        boxes = Boxes3D.from_yaw(labels.center, labels.size_lwh, labels.yaw_rad, "world", ids=ids, classes=classes)
        return ObjectLabels(boxes=boxes, source_classes=labels.source_classes)

    def _hints(self, path: Path, world_T_lidar: Transform, objects: ObjectLabels, points_world: np.ndarray,
               report: Report) -> VisibilityLabels:
        """``in_fov``: a side label's centre lies in the object's box (grown by HINT_MARGIN_M); ``n_points``: returns in it."""
        ids = objects.boxes.ids if objects.boxes.ids is not None else np.zeros(0, dtype=str)
        n_points = count_points_in_boxes(objects.boxes, points_world)
        if not is_present(path):  # (a folder, a broken link or a FIFO there is damage: read_labels names it)
            report.warn(path, "per-side label file missing: no visibility hints for this lidar")
            return VisibilityLabels(object_ids=ids, in_fov=np.zeros(len(ids), bool), n_points=n_points)
        try:
            side, errors = read_labels(path)
        except InputError as error:
            report.error(path, str(error))
            side = Labels3D(source_classes=np.zeros(0, str), center=np.zeros((0, 3)), size_lwh=np.zeros((0, 3)),
                            yaw_rad=np.zeros(0))
            errors = []
        for line in errors:
            report.error(path, line.removeprefix(f"{path}: "))
        centres_world = world_T_lidar.apply(side.center)
        seen = np.asarray(objects.boxes.contains(centres_world, margin_m=HINT_MARGIN_M).any(axis=1), dtype=bool)
        return VisibilityLabels(object_ids=ids, in_fov=seen, n_points=n_points)


def _warn_residual(report: Report, path: Path, calibration: Calibration) -> None:
    """A warning naming the calibration file when its rotation was repaired beyond float noise."""
    if calibration.residual > SILENT_TOLERANCE:
        report.warn(path, f"field rotation: not orthonormal (max |RᵀR - I| = {calibration.residual:.3g} > "
                          f"{SILENT_TOLERANCE}); replaced by the nearest rotation")


def _data_info_row(path: Path, frame: str, report: Report) -> dict[str, Any] | None:
    """The entry of a side's data_info.json whose ``pointcloud_path`` is ``frame``; None (reported) if none.

    A missing data_info.json is no problem (the scene time is then flagged scene-relative); an unusable one
    is an error, a file without the frame a warning: either costs the frame's timestamps, and the camera
    files are then found by the image's frame id.
    """
    if not is_present(path):
        return None
    consequence = f"(frame {frame}: no timestamps; camera files by frame id)"
    try:
        status = path.stat()
        version = (status.st_mtime_ns, status.st_size)
    except OSError:
        version = (0, -1)  # a broken link: the read names why
    rows = _data_info_rows(path, *version)
    if isinstance(rows, str):
        report.error(path, f"{rows} {consequence}")
        return None
    row = rows.get(frame)
    if row is None:
        report.warn(path, f"no entry with pointcloud_path of frame {frame} {consequence}")
    return row


@functools.lru_cache(maxsize=2)
def _data_info_rows(path: Path, mtime_ns: int, size: int) -> dict[str, dict[str, Any]] | str:
    """A side's data_info.json entries by point-cloud frame id (the first of each), or why the file is unusable.

    Read once per process and version of the file (``mtime_ns``, ``size``; the two sides are the two entries):
    a pair needs one row of each, and reading the whole list again for every pair was quadratic (DAIR-V2X-C:
    ~6,600 pairs, a data_info.json of ~10k frames per side). The rows are shared: callers only read them.
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
            rows.setdefault(_frame_id(str(entry.get("pointcloud_path", ""))), entry)
    return rows


def _timestamps(root: Path, rows: dict[str, dict[str, Any] | None], frames: tuple[str, str],
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
                times[key] = int(value)  # type: ignore[arg-type]
            except (TypeError, ValueError):
                report.error(path, f"frame {frame}: field {field}: expected integer µs, got {value!r:.80}")
                continue
            if not 0 <= times[key] <= MAX_TIMESTAMP_US or (isinstance(value, float) and not value.is_integer()):
                del times[key]
                report.error(path, f"frame {frame}: field {field}: expected integer µs since 1970 "
                                   f"(0 .. {MAX_TIMESTAMP_US}), got {value!r:.80}")
    return times


def _read_camera(root: Path, side: _Side, pair: dict[str, Any], row: dict[str, Any] | None, time_ns: int,
                 report: Report) -> _Camera | None:
    """One side's image and calibration, checked; None (reported) when the camera cannot be converted."""
    frame = f"{side.agent}/camera"
    image_rel = pair.get(side.image_field)
    if not (isinstance(image_rel, str) and image_rel):
        report.warn(pair["_file"], f"field {side.image_field}: expected a relative path, got {image_rel!r:.80}; "
                                   f"camera {frame} not converted")
        return None
    image_path = root / image_rel
    if not is_present(image_path):  # a folder or FIFO there is an error below
        report.warn(image_path, f"image missing: camera {frame} not converted")
        return None
    try:
        image = read_regular_file(image_path)  # a FIFO is refused, not waited on
    except OSError as error:
        report.error(image_path, f"cannot read ({error.strerror or error}); camera {frame} not converted")
        return None
    except InputError as error:
        report.error(image_path, f"{error}; camera {frame} not converted")
        return None
    problem, (width, height) = jpeg_problem(image)
    if problem is not None:
        report.error(image_path, f"{problem}; camera {frame} not converted")
        return None
    try:
        intrinsic_path, extrinsic_path = _camera_files(root / side.folder, side, image_rel, row)
    except InputError as error:
        report.error(root / side.folder / "data_info.json", f"{error}; camera {frame} not converted")
        return None
    try:
        intrinsic = read_camera_intrinsic(intrinsic_path)
    except InputError as error:
        report.error(intrinsic_path, f"{error}; camera {frame} not converted")
        return None
    try:
        camera_T_lidar = read_calibration(extrinsic_path)
    except InputError as error:
        report.error(extrinsic_path, f"{error}; camera {frame} not converted")
        return None
    _warn_residual(report, extrinsic_path, camera_T_lidar)
    # DAIR's lidar_to_camera maps lidar points into the camera (camera_T_lidar); /tf_static wants the
    # camera's pose in the lidar.
    return _Camera(frame=frame, lidar=f"{side.agent}/lidar", source=image_rel,
                   lidar_T_camera=camera_T_lidar.transform.inverse(), calibration=f"{side.name} {side.extrinsic}",
                   residual=camera_T_lidar.residual, intrinsic=intrinsic, image=image, width=width, height=height,
                   time_ns=time_ns)


def _camera_files(side_root: Path, side: _Side, image_rel: str, row: dict[str, Any] | None) -> tuple[Path, Path]:
    """(camera_intrinsic, [virtual]lidar_to_camera) files: as the side's row names them, else by frame id.

    Raises:
        InputError: the row names another image than the pair, or a calibration path that is not a string.
    """
    image_frame = _frame_id(image_rel)
    files = {"calib_camera_intrinsic_path": f"calib/camera_intrinsic/{image_frame}.json",
             f"calib_{side.extrinsic}_path": f"calib/{side.extrinsic}/{image_frame}.json"}
    if row is not None:
        where = f"{side_root / 'data_info.json'}: frame {_frame_id(str(row.get('pointcloud_path')))}"
        named = row.get("image_path", image_rel.removeprefix(f"{side.folder}/"))
        if not (isinstance(named, str) and Path(side.folder, named) == Path(image_rel)):
            raise InputError(f"{where}: field image_path: expected {image_rel.removeprefix(side.folder + '/')!r} "
                             f"(the pair's {side.image_field}), got {named!r:.80}")
        files = {field: row.get(field, default) for field, default in files.items()}
        for field, value in files.items():
            if not (isinstance(value, str) and value):
                raise InputError(f"{where}: field {field}: expected a relative path, got {value!r:.80}")
    intrinsic, extrinsic = files.values()
    return side_root / intrinsic, side_root / extrinsic
