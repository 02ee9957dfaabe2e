"""DAIR-V2X-C (vehicle + infrastructure cooperative pairs) -> multi-agent unified scenes.

Scenes are sequences, as in V2X-Seq: the pairs of ``cooperative/data_info.json`` (``selected_data_info.json``
when that is the file present) whose vehicle frame has the same ``batch_id`` in ``vehicle-side/data_info.json``
form scene ``coop_batch_<batch_id>``, one frame per pair, ordered by the vehicle ``pointcloud_timestamp``
(the devkit's grouping: ``v2x/dataset/dair_v2x_for_detection.py`` ``VICDataset.veh_frames``; DAIR-V2X's
``data/README.md``: "Infrastructure and vehicle frame with the same batch_id share the same segments").
In a sequence, a pair that cannot be placed (a bad field or pose calibration, no usable timestamp, a vehicle
frame paired twice, a second sweep at the same time) costs that frame with one error. A pair without
``batch_id`` (no side data_info.json, no row for its frame, or a row without the field) is a scene of its
own, ``coop_<vehicle frame id>``; a ``batch_id`` that cannot name a file is warned
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
rotations           orthonormalized (SVD); residual max |RᵀR - I| of each stored calibration recorded
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
                    (which map lidar points into the camera), rotation orthonormalized as above.
                    CameraCalibration: K = ``cam_K``, D = ``cam_D`` (plumb_bob), P = [K | 0], so P
                    projects as the devkit does (``cam_K @ (R @ p + t)``; it never applies ``cam_D``).
                    Calibration files as the side's data_info row names them (``calib_camera_intrinsic_path``,
                    ``calib_[virtual]lidar_to_camera_path``), by the image's frame id without a row
==================  ==================================================================================

A missing image costs that camera with a warning (its calibration is not read); a damaged image or
camera calibration costs that camera with an error.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from avdata.converters.base import Converter, Report
from avdata.converters.dair_v2x.cameras import Camera, declared_cameras, read_camera
from avdata.converters.dair_v2x.pairs import (
    SIDES,
    Pair,
    frame_id,
    lenient_time_us,
    max_difference,
    read_pair,
    row_batch_id,
    usable_rows,
)
from avdata.errors import InputError
from avdata.frames import Boxes3D, Transform
from avdata.inputs import Source, is_present
from avdata.schema import DatasetWriter, ObjectLabels, SceneWriter, VisibilityLabels
from avdata.sources.dair_v2x import DISTORTION_MODEL, Labels3D, read_json, read_labels, unified_class
from avdata.sources.pcd import read_pcd

HINT_MARGIN_M = 0.5


#: A mount calibration (lidar_to_novatel, [virtual]lidar_to_camera) may drift this much within a sequence.
STATIC_TOLERANCE = 1e-3


class DairV2xConverter(Converter):
    """DAIR-V2X-C cooperative pairs (cooperative/data_info.json, vehicle-side/, infrastructure-side/)."""

    name = "dair-v2x"
    source = "DAIR-V2X-C"
    licence = "research use only (DAIR-V2X terms)"
    reads_stores = True

    def __init__(self, config: Any):
        super().__init__(config)
        self._scenes: dict[str, list[dict[str, Any]]] | None = None

    def __getstate__(self) -> dict[str, Any]:
        # Without the pairs: a worker reads them once (``_info``). Pickled with every task, every pair of the
        # dataset would go to the workers once per pair.
        return {**self.__dict__, "_scenes": None}

    def _info(self) -> dict[str, list[dict[str, Any]]]:
        """Scene name -> its pair entries, each with ``_file``, ``_index``, ``_batch``, ``_batch_problem``, ``_time_us``."""
        if self._scenes is None:
            root = self.config.src
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
            vehicle_rows = usable_rows(root / "vehicle-side" / "data_info.json")
            scenes: dict[str, list[dict[str, Any]]] = {}
            for index, entry in enumerate(entries):
                try:
                    vehicle_id = frame_id(entry["vehicle_pointcloud_path"])
                except (KeyError, TypeError):
                    raise InputError(f"{path}: entry [{index}]: expected vehicle_pointcloud_path, got {entry!r:.80}") from None
                row = vehicle_rows.get(vehicle_id)
                batch, problem = row_batch_id(row)
                name = f"coop_batch_{batch}" if batch is not None else f"coop_{vehicle_id}"
                scenes.setdefault(name, []).append({**entry, "_file": str(path), "_index": index, "_batch": batch,
                                                    "_batch_problem": problem, "_time_us": lenient_time_us(row)})
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
        root = self.config.src
        entries = self._info()[scene]
        batch = entries[0]["_batch"]
        pairs = self._read_pairs(root, scene, entries, batch, report)
        first = pairs[0]
        novatel_T_lidar = first.calibrations["vehicle lidar_to_novatel"].transform
        vehicle = root / "vehicle-side"
        for pair in pairs[1:]:
            drift = max_difference(pair.calibrations["vehicle lidar_to_novatel"].transform, novatel_T_lidar)
            if drift > STATIC_TOLERANCE:
                report.warn(vehicle / "calib" / "lidar_to_novatel" / f"{pair.vehicle_id}.json",
                            f"differs from the sequence's first frame {first.vehicle_id} by {drift:.3g}; "
                            "the first frame's mount is used")
        # A fixed infrastructure is on /tf_static; one whose calibration or system_error_offset changes
        # within the sequence is stamped per frame, so each frame is placed by its own pair's pose.
        infra_static = all(pair.world_T_infra.allclose(first.world_T_infra) for pair in pairs)
        cameras = declared_cameras(root, pairs)
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

    def _read_pairs(self, root: Source, scene: str, entries: list[dict[str, Any]], batch: str | None,
                    report: Report) -> list[Pair]:
        """The scene's pairs in time order; a lone pair's problem fails the scene, a sequence's costs that pair."""
        pairs: list[Pair] = []
        seen: dict[str, int] = {}
        for entry in entries:
            if entry["_batch_problem"] is not None:
                report.warn(root / "vehicle-side" / "data_info.json", entry["_batch_problem"])
            try:
                pair = read_pair(root, scene, entry, report)
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

    def _warn_interleaved(self, root: Source, batch: str, pairs: list[Pair], report: Report) -> None:
        """One warning when another batch's vehicle sweeps fall inside this batch's time span.

        The devkit groups by ``batch_id`` alone (``VICDataset.veh_frames``), and so does this converter: the
        batch stays one sequence. But one vehicle cannot drive two segments at once, so interleaved batches
        mean a mislabelled ``batch_id`` or a second vehicle, and a loader's windows of consecutive frames
        then span a jump the user should know about.
        """
        start_us, end_us = pairs[0].time_ns // 1000, pairs[-1].time_ns // 1000
        inside = sorted((str(entry["_batch"]), frame_id(entry["vehicle_pointcloud_path"]))
                        for entries in self._info().values() for entry in entries
                        if entry["_batch"] not in (None, batch) and entry["_time_us"] is not None
                        and start_us <= entry["_time_us"] <= end_us)
        if inside:
            others = sorted({other for other, _ in inside})
            report.warn(root / "vehicle-side" / "data_info.json",
                        f"batch {batch}: vehicle frames of batch(es) {', '.join(others)} lie inside its time span "
                        f"{start_us} .. {end_us} µs ({len(inside)} frames, first {inside[0][1]}); kept as separate "
                        "sequences by batch_id, as the devkit groups them")

    def _write_pair(self, out: SceneWriter, root: Source, index: int, pair: Pair, novatel_T_lidar: Transform,
                    cameras: dict[str, Camera], report: Report) -> None:
        """One pair as frame ``index``: both sweeps, both images, the cooperative labels and hints."""
        images = []
        for side in SIDES:
            camera = read_camera(root, side, pair, report)  # reports why a camera is not converted
            if camera is None or camera.frame not in cameras:  # (not declared: the file changed since)
                continue
            frame = camera.frame
            drift = max_difference(camera.lidar_T_camera, cameras[frame].lidar_T_camera)
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

    def _objects(self, path: Source, vehicle_id: str, report: Report) -> ObjectLabels:
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

    def _hints(self, path: Source, world_T_lidar: Transform, objects: ObjectLabels, points_world: np.ndarray,
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


def _stamped_poses(pairs: list[Pair], infra_static: bool,
                   cameras: dict[str, Camera]) -> list[tuple[int, str, Transform]]:
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
