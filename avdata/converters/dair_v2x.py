"""DAIR-V2X-C (vehicle + infrastructure cooperative pairs) -> multi-agent unified scenes.

One scene per pair of ``cooperative/data_info.json`` (``selected_data_info.json`` when that is the
file present), named ``coop_<vehicle frame id>``. The source's rows of DESIGN.md §2:

==================  ==================================================================================
DAIR-V2X-C          how it is converted
==================  ==================================================================================
world               DAIR's world (map) frame, right-handed, z up; not re-centred
ego (vehicle)       agent ``ego``, body = the NovAtel (INS) frame: ``world -> ego`` =
                    ``novatel_to_world``; ``ego/lidar`` = ``lidar_to_novatel`` on /tf_static, so the
                    lidar's world pose is ``novatel_to_world @ lidar_to_novatel`` (devkit)
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
cameras             not converted
==================  ==================================================================================
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from avdata.converters.base import Converter, Report
from avdata.converters.opv2v import count_points_in_boxes
from avdata.errors import InputError
from avdata.frames import Boxes3D, Transform
from avdata.schema import DatasetWriter, ObjectLabels, VisibilityLabels
from avdata.sources.dair_v2x import (
    SILENT_RESIDUAL,
    Labels3D,
    read_calibration,
    read_json,
    read_labels,
    unified_class,
)
from avdata.sources.pcd import read_pcd

HINT_MARGIN_M = 0.5
#: Point-cloud timestamps beyond this (µs, year 2262) would overflow int64 ns.
MAX_TIMESTAMP_US = 9_223_372_036_854_775
#: The fields of a cooperative pair that name files, relative to the source root.
PAIR_PATHS = ("vehicle_pointcloud_path", "infrastructure_pointcloud_path", "cooperative_label_path")


def _frame_id(path: str) -> str:
    return Path(path).stem


class DairV2xConverter(Converter):
    """DAIR-V2X-C cooperative pairs (cooperative/data_info.json, vehicle-side/, infrastructure-side/)."""

    name = "dair-v2x"
    source = "DAIR-V2X-C"
    licence = "research use only (DAIR-V2X terms)"

    def __init__(self, config: Any):
        super().__init__(config)
        self._pairs: dict[str, dict] | None = None

    def _info(self) -> dict[str, dict]:
        if self._pairs is None:
            root = Path(self.config.src)
            path = root / "cooperative" / "data_info.json"
            selected = root / "cooperative" / "selected_data_info.json"
            # exists() rather than is_file(): a folder or FIFO there is reported as itself, not as a missing file.
            if not (path.exists() or path.is_symlink()) and (selected.exists() or selected.is_symlink()):
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
        calibrations = {
            "vehicle lidar_to_novatel": read_calibration(vehicle / "calib" / "lidar_to_novatel" / f"{vehicle_id}.json"),
            "vehicle novatel_to_world": read_calibration(vehicle / "calib" / "novatel_to_world" / f"{vehicle_id}.json"),
            "infrastructure virtuallidar_to_world": read_calibration(
                infra / "calib" / "virtuallidar_to_world" / f"{infra_id}.json", offset_xy),
        }
        for name, calibration in calibrations.items():
            if calibration.residual > SILENT_RESIDUAL:
                side, file = name.split(" ")
                frame = vehicle_id if side == "vehicle" else infra_id
                path = (vehicle if side == "vehicle" else infra) / "calib" / file / f"{frame}.json"
                report.warn(path, f"field rotation: not orthonormal (max |RᵀR - I| = {calibration.residual:.3g} > "
                                  f"{SILENT_RESIDUAL}); replaced by the nearest rotation")
        time_ns, source_times = _timestamps(root, vehicle_id, infra_id, report)
        novatel_T_lidar = calibrations["vehicle lidar_to_novatel"].transform
        world_T_novatel = calibrations["vehicle novatel_to_world"].transform
        world_T_infra = calibrations["infrastructure virtuallidar_to_world"].transform
        metadata = {
            "vehicle_frame": vehicle_id,
            "infrastructure_frame": infra_id,
            "system_error_offset_m": list(offset_xy),
            "calibration_residuals": {name: c.residual for name, c in calibrations.items()},
            "source_timestamps_us": source_times,
            "world_origin": "DAIR-V2X world (map) frame, z up",
            "time": "vehicle pointcloud_timestamp (UTC)" if source_times.get("vehicle") else "scene-relative: 0",
        }
        with writer.scene(scene, metadata) as out:
            out.add_agent("ego", kind="vehicle", origin="the NovAtel INS (novatel_to_world)", source_id=vehicle_id)
            out.add_agent("infra", kind="infrastructure", origin="the infrastructure (virtual) LiDAR", source_id=infra_id)
            out.add_sensor("ego/lidar", kind="lidar", source="vehicle-side/velodyne")
            out.add_sensor("infra/lidar", kind="lidar", source="infrastructure-side/velodyne")
            out.add_static_transform("ego", "ego/lidar", novatel_T_lidar)
            out.add_static_transform("world", "infra", world_T_infra)
            out.add_static_transform("infra", "infra/lidar", Transform.identity())
            out.add_transform("world", "ego", time_ns, world_T_novatel)
            sensor_times = {}
            clouds = {}
            sides = (("ego/lidar", pair["vehicle_pointcloud_path"], vehicle / "label" / "lidar" / f"{vehicle_id}.json",
                      world_T_novatel @ novatel_T_lidar),
                     ("infra/lidar", pair["infrastructure_pointcloud_path"],
                      infra / "label" / "virtuallidar" / f"{infra_id}.json", world_T_infra))
            # The infrastructure sweep keeps its own capture time (pairs are matched within ~100 ms); it is fixed,
            # so its pose does not depend on it.
            cloud_times = {"ego/lidar": time_ns, "infra/lidar": time_ns}
            if "vehicle" in source_times and "infrastructure" in source_times:
                cloud_times["infra/lidar"] = source_times["infrastructure"] * 1000
            for sensor, cloud_path, _, world_T_lidar in sides:
                try:
                    points = read_pcd(root / cloud_path)
                    out.add_point_cloud(sensor, cloud_times[sensor], points)
                    sensor_times[sensor] = cloud_times[sensor]
                    xyz = np.stack([points["x"], points["y"], points["z"]], axis=1).astype(np.float64)
                    clouds[sensor] = world_T_lidar.apply(xyz)
                except InputError as error:
                    report.error(root / cloud_path, str(error))
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
        if not path.exists():  # (a folder or FIFO there is no missing file: read_labels names it as an error)
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


def _timestamps(root: Path, vehicle_id: str, infra_id: str, report: Report) -> tuple[int, dict[str, int]]:
    """(frame time in ns, source point-cloud timestamps in µs by side) from the sides' data_info.json."""
    times = {}
    for side, folder, frame in (("vehicle", "vehicle-side", vehicle_id), ("infrastructure", "infrastructure-side", infra_id)):
        path = root / folder / "data_info.json"
        if not (path.exists() or path.is_symlink()):
            continue
        try:
            entries = read_json(path)
        except InputError as error:
            report.error(path, f"{error} (frame {frame}: no timestamp)".removeprefix(f"{path}: "))
            continue
        if not isinstance(entries, list):
            report.error(path, f"expected a JSON list of frames, got {type(entries).__name__} (frame {frame}: no timestamp)")
            continue
        matches = [entry for entry in entries
                   if isinstance(entry, dict) and _frame_id(str(entry.get("pointcloud_path", ""))) == frame]
        if not matches:
            report.warn(path, f"no entry with pointcloud_path of frame {frame}: no timestamp")
            continue
        value = matches[0].get("pointcloud_timestamp")
        try:
            times[side] = int(value)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            report.error(path, f"frame {frame}: field pointcloud_timestamp: expected integer µs, got {value!r:.80}")
            continue
        if not 0 <= times[side] <= MAX_TIMESTAMP_US or (isinstance(value, float) and not value.is_integer()):
            del times[side]
            report.error(path, f"frame {frame}: field pointcloud_timestamp: expected integer µs since 1970 "
                               f"(0 .. {MAX_TIMESTAMP_US}), got {value!r:.80}")
    return times.get("vehicle", 0) * 1000, times
