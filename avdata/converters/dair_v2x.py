"""DAIR-V2X-C (vehicle + infrastructure cooperative pairs) -> multi-agent unified scenes.

Scenes are sequences, as in V2X-Seq: the pairs of ``cooperative/data_info.json`` (``selected_data_info.json``
when that is the file present) whose vehicle frame has the same ``batch_id`` in ``vehicle-side/data_info.json``
form scene ``coop_batch_<batch_id>``, one frame per pair, ordered by the vehicle ``pointcloud_timestamp``
(the devkit's grouping: ``v2x/dataset/dair_v2x_for_detection.py`` ``VICDataset.veh_frames``; DAIR-V2X's
``data/README.md``: "Infrastructure and vehicle frame with the same batch_id share the same segments").
In a sequence, a pair that cannot be placed (a bad field or pose calibration, no usable timestamp, a vehicle
frame paired twice, a second sweep at the same time) costs that frame with one error. A pair without
``batch_id`` (no side data_info.json, no row for its frame, or a row without the field) is a scene of its
own, ``coop_<vehicle frame id>``, as before sequences; a ``batch_id`` that cannot name a file is warned
about and treated the same. A batch whose time span holds another batch's vehicle sweeps stays one
sequence (the devkit's grouping), with one warning naming the batches; an infrastructure frame whose
``batch_id`` differs from its vehicle frame's is warned about and follows the vehicle. The source's rows of docs/conventions.md:

==================  ==================================================================================
DAIR-V2X-C          how it is converted
==================  ==================================================================================
world               DAIR's world (map) frame, right-handed, z up; not re-centred
ego (vehicle)       agent ``ego``, body = the NovAtel (INS) frame: ``world -> ego`` =
                    ``novatel_to_world``; ``ego/lidar`` = ``lidar_to_novatel`` on /tf_static, so the
                    lidar's world pose is ``novatel_to_world @ lidar_to_novatel`` (devkit). Each frame's
                    pose is stamped at its sweep's time, and at its vehicle image's when that lies outside
                    the scene's sweeps (the devkit uses one pose for both; inside, the image takes the pose
                    interpolated between sweeps, so the trajectory stays continuous). Mounts
                    (``lidar_to_novatel``, the camera extrinsics) are the sequence's first frame's; a
                    later frame's differing by more than STATIC_TOLERANCE is warned about
infrastructure      agent ``infra``: ``world -> infra`` = ``virtuallidar_to_world`` with
                    ``system_error_offset`` added to its x, y translation (devkit), on /tf_static when
                    every frame of the scene gives the same pose, else stamped at each frame's times;
                    ``infra/lidar`` = identity
rotations           orthonormalised (SVD); residual max |RᵀR - I| of each stored calibration recorded
                    in the metadata (a pose's: the largest of the scene's frames),
                    warned above 1e-6, refused above 1e-2
points              PCDs (binary_compressed, mixed types: vehicle ``intensity`` u8, ``timestamp`` f8)
                    stored untouched in each lidar's frame, every field kept
objects             ``cooperative/label_world`` boxes (centre, l w h, yaw about z) in ``world``;
                    ids ``<vehicle frame id>_<k>``, k = 0 .. N-1 in file order: DAIR-V2X-C has no track
                    ids, so no id is shared by two frames of a sequence
per-side labels     ``label/lidar`` (vehicle) and ``label/virtuallidar`` (infra): visibility hints of
                    each lidar: a cooperative object is ``in_fov`` when a side box's centre, moved to
                    world, lies inside it (grown by 0.5 m)
time                ``pointcloud_timestamp`` (µs) of the vehicle side's data_info when present, else 0
                    (a lone pair only, flagged scene-relative); the infrastructure sweep at its own
                    ``pointcloud_timestamp``
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
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from avdata.converters.base import Converter, Report
from avdata.errors import InputError
from avdata.frames import Boxes3D, Transform
from avdata.frames.rotations import SILENT_TOLERANCE
from avdata.inputs import is_present, read_regular_file
from avdata.schema import DatasetWriter, ObjectLabels, SceneWriter, VisibilityLabels
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
#: A mount calibration (lidar_to_novatel, [virtual]lidar_to_camera) may drift this much within a sequence.
STATIC_TOLERANCE = 1e-3


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
    calibration_path: Path
    residual: float
    intrinsic: CameraIntrinsic
    image: bytes
    width: int
    height: int
    time_ns: int


@dataclass(frozen=True, slots=True, kw_only=True)
class _Pair:
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

    def image_time_ns(self, side: _Side) -> int:
        """The side's ``image_timestamp`` when the scene time is absolute, else its sweep's time."""
        own_us = self.source_times.get(f"{side.name}_image") if "vehicle" in self.source_times else None
        return self.cloud_times[f"{side.agent}/lidar"] if own_us is None else own_us * 1000

    @property
    def world_T_infra(self) -> Transform:
        return self.calibrations["infrastructure virtuallidar_to_world"].transform


class DairV2xConverter(Converter):
    """DAIR-V2X-C cooperative pairs (cooperative/data_info.json, vehicle-side/, infrastructure-side/)."""

    name = "dair-v2x"
    source = "DAIR-V2X-C"
    licence = "research use only (DAIR-V2X terms)"

    def __init__(self, config: Any):
        super().__init__(config)
        self._scenes: dict[str, list[dict[str, Any]]] | None = None

    def __getstate__(self) -> dict[str, Any]:
        # Without the pairs: a worker reads them once (``_info``). Pickled with every task, all ~6,600 of
        # DAIR-V2X-C's pairs went to the workers once per pair.
        return {**self.__dict__, "_scenes": None}

    def _info(self) -> dict[str, list[dict[str, Any]]]:
        """Scene name -> its pair entries, each with ``_file``, ``_index``, ``_batch``, ``_batch_problem``, ``_time_us``."""
        if self._scenes is None:
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
            # An unusable vehicle data_info.json leaves every pair on its own; each pair's conversion names why.
            vehicle_rows = _usable_rows(root / "vehicle-side" / "data_info.json")
            scenes: dict[str, list[dict[str, Any]]] = {}
            for index, entry in enumerate(entries):
                try:
                    vehicle_id = _frame_id(entry["vehicle_pointcloud_path"])
                except (KeyError, TypeError):
                    raise InputError(f"{path}: entry [{index}]: expected vehicle_pointcloud_path, got {entry!r:.80}") from None
                row = vehicle_rows.get(vehicle_id)
                batch, problem = _batch_id(row)
                name = f"coop_batch_{batch}" if batch is not None else f"coop_{vehicle_id}"
                scenes.setdefault(name, []).append({**entry, "_file": str(path), "_index": index, "_batch": batch,
                                                    "_batch_problem": problem, "_time_us": _lenient_time_us(row)})
            self._scenes = scenes
        return self._scenes

    def release(self) -> None:
        """Drops the cached source tables before the index is built."""
        self._scenes = None

    def list_scenes(self) -> list[str]:
        """Every scene of the source, in a stable order."""
        return sorted(self._info())

    def convert_scene(self, scene: str, writer: DatasetWriter, report: Report) -> None:
        """Converts one scene into writer; problems of single records go to report."""
        root = Path(self.config.src)
        entries = self._info()[scene]
        batch = entries[0]["_batch"]
        pairs = self._read_pairs(root, scene, entries, batch, report)
        first = pairs[0]
        novatel_T_lidar = first.calibrations["vehicle lidar_to_novatel"].transform
        vehicle = root / "vehicle-side"
        for pair in pairs[1:]:
            drift = _max_difference(pair.calibrations["vehicle lidar_to_novatel"].transform, novatel_T_lidar)
            if drift > STATIC_TOLERANCE:
                report.warn(vehicle / "calib" / "lidar_to_novatel" / f"{pair.vehicle_id}.json",
                            f"differs from the sequence's first frame {first.vehicle_id} by {drift:.3g}; "
                            "the first frame's mount is used")
        # A fixed infrastructure is on /tf_static; one whose calibration or system_error_offset changes
        # within the sequence is stamped per frame, so each frame is placed by its own pair's pose.
        infra_static = all(pair.world_T_infra.allclose(first.world_T_infra) for pair in pairs)
        cameras = _declared_cameras(root, pairs)
        # The residual of each stored calibration: the mounts are the first frame's, the poses every frame's.
        residuals = {name: max(pair.calibrations[name].residual for pair in pairs) for name in first.calibrations}
        residuals["vehicle lidar_to_novatel"] = first.calibrations["vehicle lidar_to_novatel"].residual
        residuals.update({camera.calibration: camera.residual for camera in cameras.values()})
        metadata = {
            "batch_id": batch,
            "pairs": [{"vehicle_frame": pair.vehicle_id, "infrastructure_frame": pair.infra_id,
                       "system_error_offset_m": list(pair.offset_xy), "source_timestamps_us": pair.source_times}
                      for pair in pairs],
            "calibration_residuals": residuals,
            "world_origin": "DAIR-V2X world (map) frame, z up",
            "time": "vehicle pointcloud_timestamp (UTC)" if first.source_times.get("vehicle") else "scene-relative: 0",
            "ego_pose": "each frame's novatel_to_world, stamped at its vehicle sweep's time and at its vehicle "
                        "image's when that lies outside the scene's sweeps (the devkit uses one pose for both: "
                        "v2x/dataset/dataset_utils/frame.py VICFrame.transform); between sweeps, interpolated",
            "infrastructure_pose": ("one pose for the scene (/tf_static)" if infra_static else
                                    "stamped per frame: virtuallidar_to_world or system_error_offset changes "
                                    "within the sequence"),
        }
        with writer.scene(scene, metadata) as out:
            out.add_agent("ego", kind="vehicle", origin="the NovAtel INS (novatel_to_world)", source_id=first.vehicle_id)
            out.add_agent("infra", kind="infrastructure", origin="the infrastructure (virtual) LiDAR",
                          source_id=first.infra_id)
            out.add_sensor("ego/lidar", kind="lidar", source="vehicle-side/velodyne")
            out.add_sensor("infra/lidar", kind="lidar", source="infrastructure-side/velodyne")
            out.add_static_transform("ego", "ego/lidar", novatel_T_lidar)
            if infra_static:
                out.add_static_transform("world", "infra", first.world_T_infra)
            out.add_static_transform("infra", "infra/lidar", Transform.identity())
            for camera in cameras.values():
                out.add_sensor(camera.frame, kind="camera", width=camera.width, height=camera.height,
                               source=camera.source)
                out.add_static_transform(camera.lidar, camera.frame, camera.lidar_T_camera)
            # /tf goes in time order: every frame's poses first (a frame's infrastructure sweep and images
            # are older than its vehicle sweep, and may be older than the frame before's).
            for time_ns, child, parent_T_child in _stamped_poses(pairs, infra_static, cameras):
                out.add_transform("world", child, time_ns, parent_T_child)
            for index, pair in enumerate(pairs):
                self._write_pair(out, root, index, pair, novatel_T_lidar, cameras, report)

    def _read_pairs(self, root: Path, scene: str, entries: list[dict[str, Any]], batch: str | None,
                    report: Report) -> list[_Pair]:
        """The scene's pairs in time order; a lone pair's problem fails the scene, a sequence's costs that pair."""
        pairs: list[_Pair] = []
        seen: dict[str, int] = {}
        for entry in entries:
            if entry["_batch_problem"] is not None:
                report.warn(root / "vehicle-side" / "data_info.json", entry["_batch_problem"])
            try:
                pair = _read_pair(root, scene, entry, report)
            except InputError as error:
                if batch is None:
                    raise
                report.error(entry["_file"], f"entry [{entry['_index']}]: {error}; pair left out of batch {batch}")
                continue
            if pair.vehicle_id in seen:
                report.error(entry["_file"], f"entry [{entry['_index']}]: expected one pair per vehicle frame, got "
                                             f"vehicle frame {pair.vehicle_id} again (first in entry "
                                             f"[{seen[pair.vehicle_id]}]); left out")
                continue
            if batch is not None and "vehicle" not in pair.source_times:
                report.error(root / "vehicle-side" / "data_info.json",
                             f"frame {pair.vehicle_id}: no usable pointcloud_timestamp, which orders batch {batch}; "
                             "pair left out")
                continue
            seen[pair.vehicle_id] = entry["_index"]
            pairs.append(pair)
        if not pairs:
            raise InputError(f"{entries[0]['_file']}: batch {batch}: expected at least one usable pair, got none")
        pairs.sort(key=lambda pair: (pair.time_ns, pair.vehicle_id))
        kept = pairs[:1]
        for pair in pairs[1:]:
            if pair.time_ns == kept[-1].time_ns:  # two ego poses at one time: the frame graph keeps one
                report.error(root / "vehicle-side" / "data_info.json",
                             f"frame {pair.vehicle_id}: field pointcloud_timestamp: expected one vehicle sweep per "
                             f"time in batch {batch}, got {pair.time_ns // 1000} µs as frame {kept[-1].vehicle_id}; "
                             "pair left out")
                continue
            kept.append(pair)
        pairs = kept
        if batch is not None:
            self._warn_interleaved(root, batch, pairs, report)
        return pairs

    def _warn_interleaved(self, root: Path, batch: str, pairs: list[_Pair], report: Report) -> None:
        """One warning when another batch's vehicle sweeps fall inside this batch's time span.

        The devkit groups by ``batch_id`` alone (``VICDataset.veh_frames``), and so does this converter: the
        batch stays one sequence. But one vehicle cannot drive two segments at once, so interleaved batches
        mean a mislabelled ``batch_id`` or a second vehicle, and a loader's windows of consecutive frames
        then span a jump the user should know about.
        """
        start_us, end_us = pairs[0].time_ns // 1000, pairs[-1].time_ns // 1000
        inside = sorted((str(entry["_batch"]), _frame_id(entry["vehicle_pointcloud_path"]))
                        for entries in self._info().values() for entry in entries
                        if entry["_batch"] not in (None, batch) and entry["_time_us"] is not None
                        and start_us <= entry["_time_us"] <= end_us)
        if inside:
            others = sorted({other for other, _ in inside})
            report.warn(root / "vehicle-side" / "data_info.json",
                        f"batch {batch}: vehicle frames of batch(es) {', '.join(others)} lie inside its time span "
                        f"{start_us} .. {end_us} µs ({len(inside)} frames, first {inside[0][1]}); kept as separate "
                        "sequences by batch_id, as the devkit groups them")

    def _write_pair(self, out: SceneWriter, root: Path, index: int, pair: _Pair, novatel_T_lidar: Transform,
                    cameras: dict[str, _Camera], report: Report) -> None:
        """One pair as frame ``index``: both sweeps, both images, the cooperative labels and hints."""
        images = []
        for side in SIDES:
            camera = _read_camera(root, side, pair, report)  # reports why a camera is not converted
            if camera is None or camera.frame not in cameras:  # (not declared: the file changed since)
                continue
            frame = camera.frame
            drift = _max_difference(camera.lidar_T_camera, cameras[frame].lidar_T_camera)
            if drift > STATIC_TOLERANCE:
                report.warn(camera.calibration_path, f"differs from the sequence's first {side.extrinsic} by "
                                                     f"{drift:.3g}; the first is used")
            images.append(camera)
        world_T_novatel = pair.calibrations["vehicle novatel_to_world"].transform
        vehicle, infra = root / "vehicle-side", root / "infrastructure-side"
        sensor_times = {}
        clouds = {}
        sides = (("ego/lidar", pair.entry["vehicle_pointcloud_path"],
                  vehicle / "label" / "lidar" / f"{pair.vehicle_id}.json", world_T_novatel @ novatel_T_lidar),
                 ("infra/lidar", pair.entry["infrastructure_pointcloud_path"],
                  infra / "label" / "virtuallidar" / f"{pair.infra_id}.json", pair.world_T_infra))
        for sensor, cloud_path, _, world_T_lidar in sides:
            try:
                points = read_pcd(root / cloud_path)
                out.add_point_cloud(sensor, pair.cloud_times[sensor], points)
                sensor_times[sensor] = pair.cloud_times[sensor]
                xyz = np.stack([points["x"], points["y"], points["z"]], axis=1).astype(np.float64)
                clouds[sensor] = world_T_lidar.apply(xyz)
            except InputError as error:
                report.error(root / cloud_path, str(error))
        for camera in images:
            try:  # (an image older than the sequence's previous one on its topic is refused)
                out.add_camera_calibration(camera.frame, camera.time_ns, K=camera.intrinsic.K, width=camera.width,
                                           height=camera.height, D=camera.intrinsic.D,
                                           distortion_model=DISTORTION_MODEL)
                out.add_image(camera.frame, camera.time_ns, camera.image, "jpeg")
            except InputError as error:
                report.error(root / camera.source, f"{error}; camera {camera.frame} not converted")
                continue
            sensor_times[camera.frame] = camera.time_ns
        objects = self._objects(root / pair.entry["cooperative_label_path"], pair.vehicle_id, report)
        out.add_frame(index, pair.time_ns, objects, sensor_timestamps_ns=sensor_times)
        for sensor, _, label_path, world_T_lidar in sides:
            if sensor in clouds:
                out.add_visibility(sensor, index, pair.time_ns,
                                   self._hints(label_path, world_T_lidar, objects, clouds[sensor], report))

    def _objects(self, path: Path, vehicle_id: str, report: Report) -> ObjectLabels:
        try:
            labels, errors = read_labels(path)
        except InputError as error:
            report.error(path, str(error))
            return ObjectLabels.empty("world")
        for line in errors:
            report.error(path, line.removeprefix(f"{path}: "))
        # DAIR-V2X-C has no track ids: an id names one box of one frame, never the same object in two frames.
        ids = np.char.add(f"{vehicle_id}_", np.arange(len(labels.yaw_rad)).astype(str)).astype(str)
        classes = np.array([unified_class(c) for c in labels.source_classes], dtype=str).reshape(len(ids))
        boxes = Boxes3D.from_yaw(labels.center, labels.size_lwh, labels.yaw_rad, "world", ids=ids, classes=classes)
        return ObjectLabels(boxes=boxes, source_classes=labels.source_classes)

    def _hints(self, path: Path, world_T_lidar: Transform, objects: ObjectLabels, points_world: np.ndarray,
               report: Report) -> VisibilityLabels:
        """``in_fov``: a side label's centre lies in the object's box (grown by HINT_MARGIN_M); ``n_points``: returns in it."""
        ids = objects.boxes.ids if objects.boxes.ids is not None else np.zeros(0, dtype=str)
        n_points = objects.boxes.count_points(points_world)
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


def _read_pair(root: Path, scene: str, entry: dict[str, Any], report: Report) -> _Pair:
    """A pair's fields, calibrations and source times, checked.

    Raises:
        InputError: a pair field or a pose calibration (lidar_to_novatel, novatel_to_world,
            virtuallidar_to_world) is unusable: the pair cannot be placed in ``world``.
    """
    info_file = entry["_file"]
    try:
        offset = entry.get("system_error_offset") or {"delta_x": 0.0, "delta_y": 0.0}
        offset_xy = (float(offset["delta_x"]), float(offset["delta_y"]))
        paths = {key: entry[key] for key in PAIR_PATHS}
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
    return _Pair(entry=entry, vehicle_id=vehicle_id, infra_id=infra_id, offset_xy=offset_xy, calibrations=calibrations,
                 rows=rows, source_times=source_times, time_ns=time_ns, cloud_times=cloud_times)


def _declared_cameras(root: Path, pairs: list[_Pair]) -> dict[str, _Camera]:
    """Per camera frame, the first pair's camera that reads: its size and mount are the scene's declaration.

    Its problems are reported when each pair's camera is read again for writing (``_write_pair``).
    """
    cameras: dict[str, _Camera] = {}
    quiet = Report("", strict=False)
    for side in SIDES:
        for pair in pairs:
            camera = _read_camera(root, side, pair, quiet)
            if camera is not None:
                cameras[camera.frame] = camera
                break
    return cameras


def _stamped_poses(pairs: list[_Pair], infra_static: bool,
                   cameras: dict[str, _Camera]) -> list[tuple[int, str, Transform]]:
    """(time, child of ``world``, pose) of every frame, in time order.

    Each frame's ``novatel_to_world`` at its vehicle sweep's time; a vehicle image between two sweeps
    takes the pose interpolated between them, one outside the sequence's sweeps (always, for a lone pair)
    its frame's pose stamped at its time too, as the devkit uses the frame's one pose for both. A stamped
    infrastructure's pose at every time of its frame, so any of the frame's data is placed by its own pair.
    """
    poses = []
    first_ns, last_ns = pairs[0].time_ns, pairs[-1].time_ns
    for pair in pairs:
        images = {f"{side.agent}/camera": pair.image_time_ns(side) for side in SIDES}
        outside = "ego/camera" in cameras and not first_ns <= images["ego/camera"] <= last_ns
        ego_times = {pair.time_ns} | ({images["ego/camera"]} if outside else set())
        poses += [(t, "ego", pair.calibrations["vehicle novatel_to_world"].transform) for t in ego_times]
        if not infra_static:
            infra_times = {pair.time_ns, *pair.cloud_times.values(), *(images[frame] for frame in cameras)}
            poses += [(t, "infra", pair.world_T_infra) for t in infra_times]
    return sorted(poses, key=lambda pose: pose[:2])


def _usable_rows(path: Path) -> dict[str, dict[str, Any]]:
    """A side's data_info.json rows by frame id, or none when the file is absent or unusable (reported per pair)."""
    if not is_present(path):
        return {}
    try:
        status = path.stat()
    except OSError:
        return {}
    rows = _data_info_rows(path, status.st_mtime_ns, status.st_size)
    return {} if isinstance(rows, str) else rows


#: A ``batch_id`` becomes part of a scene (file) name: these characters only.
BATCH_ID = re.compile(r"^[0-9A-Za-z_-]{1,64}$")


def _batch_id(row: dict[str, Any] | None) -> tuple[str | None, str | None]:
    """(the row's ``batch_id`` as a name, or None; a warning line when it is present but unusable)."""
    if row is None or row.get("batch_id") is None:
        return None, None
    value = row["batch_id"]
    name = str(value) if isinstance(value, str | int) and not isinstance(value, bool) else ""
    if not BATCH_ID.match(name):
        return None, (f"frame {_frame_id(str(row.get('pointcloud_path')))}: field batch_id: expected a batch name "
                      f"(1 to 64 letters, digits, _ or -), got {value!r:.40}; the pair is its own scene")
    return name, None


def _lenient_time_us(row: dict[str, Any] | None) -> int | None:
    """A row's ``pointcloud_timestamp`` when it reads as an integer (for spans only; ``_timestamps`` checks it)."""
    try:
        return int(row["pointcloud_timestamp"]) if row is not None else None
    except (KeyError, TypeError, ValueError, OverflowError):
        return None


def _max_difference(a: Transform, b: Transform) -> float:
    return float(max(np.abs(a.rotation - b.rotation).max(), np.abs(a.translation - b.translation).max()))


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
                times[key] = int(value)  # type: ignore[arg-type]  # a value of another type is reported below
            except (TypeError, ValueError):
                report.error(path, f"frame {frame}: field {field}: expected integer µs, got {value!r:.80}")
                continue
            if not 0 <= times[key] <= MAX_TIMESTAMP_US or (isinstance(value, float) and not value.is_integer()):
                del times[key]
                report.error(path, f"frame {frame}: field {field}: expected integer µs since 1970 "
                                   f"(0 .. {MAX_TIMESTAMP_US}), got {value!r:.80}")
    return times


def _read_camera(root: Path, side: _Side, pair: _Pair, report: Report) -> _Camera | None:
    """One side's image and calibration, checked; None (reported) when the camera cannot be converted."""
    frame = f"{side.agent}/camera"
    image_rel = pair.entry.get(side.image_field)
    row = pair.rows[side.name]
    if not (isinstance(image_rel, str) and image_rel):
        report.warn(pair.entry["_file"], f"field {side.image_field}: expected a relative path, got {image_rel!r:.80}; "
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
                   calibration_path=extrinsic_path, residual=camera_T_lidar.residual, intrinsic=intrinsic, image=image,
                   width=width, height=height, time_ns=pair.image_time_ns(side))


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
