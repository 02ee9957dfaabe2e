"""Unified dataset -> nuScenes tables and files, for nuScenes-based tools (devkit, mmdetection3d, OpenPCDet).

Writes ``OUT/<version>/`` with the 13 tables, ``OUT/samples/<CHANNEL>/`` (key frames), ``OUT/sweeps/<CHANNEL>/``
(sensor messages between frames) and ``OUT/maps/`` (one empty raster mask: the devkit refuses tables whose map
files are missing; there is no map to export). Mapping (unified -> nuScenes):

* channel: the ego's sensors with a nuScenes equivalent get its name (``ego/velodyne`` -> ``LIDAR_TOP``, ``ego/cam2``
  -> ``CAM_FRONT``: :mod:`avdata.sources.nuscenes.channels`, which also says why), every other sensor its own name
  (``ego/cam3`` -> ``CAM3``, ``infra_03/lidar`` -> ``INFRA_03_LIDAR``); ``channels`` overrides any of them. The
  mapping used is written to ``OUT/avdata_channels.json`` (sensor frame -> channel);
* each frame is a ``sample`` (timestamp in microseconds), except, in a scene that has a ``LIDAR_TOP`` sensor, a frame
  without a message of it (nuScenes tools read every sample's ``LIDAR_TOP`` key frame: mmdetection3d's converter
  fails on a sample without one, nuScenes detection eval refuses it); such frames are counted in
  ``skipped_frames``. Each lidar / camera message a sample's frame names is a key-frame ``sample_data`` of that
  sample, other messages of the sensor are sweeps linked to the next sample (the last ones to the last sample);
  ``prev``/``next`` chain every sensor's messages;
* every sample_data's ``ego_pose`` is the pose of the agent carrying the sensor, ``calibrated_sensor`` the
  sensor's pose in that agent (one record per distinct calibration and sensor), with ``camera_intrinsic`` = the
  calibration's K;
* ``global`` = the dataset's ``world`` of the scene; annotations are the frame's boxes in it, size as
  nuScenes writes it (width, length, height), rotation (w, x, y, z); ``instance`` = object id per scene;
  ``num_lidar_pts`` = the sum of the lidars' point counts from the visibility labels (-1 when no lidar
  counted, e.g. KITTI's camera labels), ``visibility`` from the visible fraction (or occlusion level);
* category: the source's nuScenes category when the source is nuScenes-schema, else the unified class's
  nuScenes equivalent (:data:`CATEGORY_OF_CLASS`);
* lidar files: ``.pcd.bin``, float32 x, y, z, intensity, ring (0 where the source has none), as the devkit reads;
  images: the stored bytes, unchanged. Radars are not exported.

Times in nanoseconds that are not whole microseconds are rounded, and the count is reported.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from avdata.errors import AvdataError, DiskFullError
from avdata.executors.folder import OutputFolder
from avdata.executors.pipeline import SceneRunResult, outcome_fields
from avdata.executors.scenes import FAILED, WRITTEN, SceneOutcome
from avdata.exporters.driver import (
    ExportConfig,
    Exporter,
    SceneJob,
    completed,
    export_config,
    open_dataset_scene,
    problem,
    prune,
    record,
    run_export,
    scene_fingerprint,
)
from avdata.outputs import checked_name
from avdata.schema import DatasetReader, SceneReader, scene_path, topics
from avdata.schema.dataset import dataset_root
from avdata.sources.nuscenes.categories import ATTRIBUTES, CATEGORY_OF_CLASS
from avdata.sources.nuscenes.channels import channel_map, check_overrides
from avdata.storage import Location

__all__ = ["CATEGORY_OF_CLASS", "CHANNELS_FILE", "TABLES", "NuScenesExportResult", "annotation_token", "export_nuscenes",
           "sample_token"]

#: The tables written, in the order of the files.
TABLES = ("attribute", "calibrated_sensor", "category", "ego_pose", "instance", "log", "map", "sample",
          "sample_annotation", "sample_data", "scene", "sensor", "visibility")
#: Tables whose rows each scene task returns (the others are built from all scenes).
_SCENE_TABLES = ("calibrated_sensor", "ego_pose", "instance", "log", "sample", "sample_annotation", "sample_data", "scene")
_VISIBILITY = {"1": "v0-40", "2": "v40-60", "3": "v60-80", "4": "v80-100"}
_FOLDERS = ("samples", "sweeps", "maps")
#: The channel mapping of an export (sensor frame -> channel), in the dataroot (no nuScenes tool reads it).
CHANNELS_FILE = "avdata_channels.json"

#: The map placeholder (an 8 x 8 black 8-bit grey PNG: the devkit refuses tables without a map file), as fixed bytes:
#: an encoder's output changes with its version (OpenCV 5 encodes it differently from 4), an export must not.
_BLANK_MAP_PNG = bytes.fromhex(
    "89504e470d0a1a0a0000000d4948445200000008000000080800000000e164e1570000000c4944415478da6360a00e0000004800011045efd2"
    "0000000049454e44ae426082")


@dataclass(frozen=True, slots=True, kw_only=True)
class NuScenesExportResult(SceneRunResult):
    """What an export run did: table sizes of the whole export, scenes by outcome, problems.

    ``problems`` are those of the scenes this run wrote or failed.
    """

    scenes: int
    samples: int
    sample_data: int
    annotations: int
    rounded_timestamps: int
    skipped_frames: int


@dataclass(frozen=True, slots=True, kw_only=True)
class _SceneTask:
    job: SceneJob
    nuscenes_source: bool
    description: str
    channels: tuple[tuple[str, str], ...]


def _token(*parts: object) -> str:
    return hashlib.md5("\x1f".join(str(p) for p in parts).encode()).hexdigest()


def sample_token(scene: str, frame_index: int) -> str:
    """The ``sample`` token of a frame (deterministic: reruns give the same tables)."""
    return _token("sample", scene, frame_index)


def annotation_token(scene: str, frame_index: int, object_id: str) -> str:
    """The ``sample_annotation`` token of an object at a frame (deterministic: reruns give the same tables)."""
    return _token("sample_annotation", scene, frame_index, object_id)


def _us(time_ns: int) -> int:
    return int(round(time_ns / 1000))


def _visibility_level(fraction: float, occlusion: int) -> str:
    if np.isfinite(fraction):
        return "4" if fraction >= 0.8 else "3" if fraction >= 0.6 else "2" if fraction >= 0.4 else "1"
    return {0: "4", 1: "3", 2: "2"}.get(int(occlusion), "1")


def export_nuscenes(dataset_root: str | Path | Location, dst: str | Path | Location, *, version: str = "v1.0-avdata",
                    scenes: Sequence[str] | None = None, channels: Mapping[str, str] | None = None,
                    config: ExportConfig | None = None) -> NuScenesExportResult:
    """Writes a unified dataset as nuScenes tables and files under ``dst``, one task per scene.

    Each scene task writes its ``samples/`` and ``sweeps/`` files and returns its table rows (tokens
    are deterministic per scene and frame); the finishing step merges the rows in scene order and
    writes the tables. The files are the same whatever the executor or number of workers.

    Args:
        dataset_root: the unified dataset (a path, or ``s3://...``, ``gs://...``).
        dst: the nuScenes dataroot to write (``dst/<version>/*.json``, ``samples/``, ``sweeps/``, ``maps/``; a path,
            or a store URI).
        version: the table folder name (what ``NuScenes(version=...)`` is given).
        scenes: only these scenes (all when None).
        channels: sensor frame -> nuScenes channel, replacing the default mapping
            (:mod:`avdata.sources.nuscenes.channels`) for these sensors, e.g. ``{"ego/cam3": "CAM_FRONT_RIGHT"}``.
        config: executor, workers, ``force``, progress (its ``dataset``, ``dst`` and ``scenes`` are
            replaced by the arguments above); default: the calling process, quiet.

    Raises:
        AvdataError: a sensor frame or channel of ``channels`` is malformed, or names a sensor the dataset lacks.
        InputError: the dataset is missing or unreadable, a scene is unknown, DST cannot be written or
            another process holds its lock. Problems of single scenes (two sensors mapped to one channel) are in
            the result instead.
    """
    overrides = tuple(sorted(check_overrides(channels or {}).items()))
    config = export_config(config, dataset_root, dst, scenes)
    if overrides:  # a mistyped sensor would be ignored: the export written with the default channel instead
        known = sorted(DatasetReader(config.dataset).manifest.get("sensors", {}))
        unknown = [sensor for sensor, _ in overrides if sensor not in known]
        if unknown:
            raise AvdataError(f"{config.dataset}: channel mapping: expected sensors of the dataset {known}, got {unknown}")
    return run_export(NuScenesExporter(config, tables=version, channels=overrides))


class NuScenesExporter(Exporter[NuScenesExportResult]):
    """Unified -> nuScenes tables and files (see the module docstring and :func:`export_nuscenes`)."""

    format = "nuscenes"
    table_files = tuple(f"{table}.json" for table in TABLES)

    def __init__(self, config: ExportConfig, *, tables: str, channels: tuple[tuple[str, str], ...] = ()):
        super().__init__(config, tables)
        self.channels = channels

    def plan(self, dataset: DatasetReader, scenes: list[str]) -> tuple[list[Any], list[SceneOutcome]]:
        """One task per scene; every scene can be planned."""
        source = str((dataset.manifest.get("source") or {}).get("name", ""))
        nuscenes_source = source.startswith("nuscenes") or source.startswith("lyft")
        description = f"exported by avdata from {dataset.root}"
        options = {"nuscenes_source": nuscenes_source, "description": description, "channels": self.channels}
        config = self.config
        return [_SceneTask(job=SceneJob(dataset=str(dataset.root), dst=str(config.dst), scene=name, force=config.force,
                                        fingerprint=scene_fingerprint(dataset, name, "nuscenes", options)),
                           nuscenes_source=nuscenes_source, description=description, channels=self.channels)
                for name in scenes], []

    def export_scene(self, task: Any) -> SceneOutcome:
        """Writes one scene's files and returns its rows (see :func:`_export_scene`)."""
        return _export_scene(task)

    def finish(self, dataset: DatasetReader, outcomes: list[SceneOutcome]) -> NuScenesExportResult:
        """Merges the scenes' rows in scene order, removes files no row names, writes the tables."""
        dst, version = self.out, str(self.tables)
        parts = [o.data for o in outcomes if o.data]
        tables, rounded = _merge(dataset, parts)
        channel_of = {sensor: channel for part in parts for sensor, channel in part["channels"].items()}
        map_file = tables["map"][0]["filename"]
        prune(dst, _FOLDERS, {r["filename"] for r in tables["sample_data"]} | {map_file})
        dst.write(map_file, _BLANK_MAP_PNG)
        for table, rows in tables.items():
            dst.write(f"{version}/{table}.json", json.dumps(rows, indent=0).encode())
        dst.write(CHANNELS_FILE, json.dumps(dict(sorted(channel_of.items())), indent=0).encode())
        return NuScenesExportResult(
            scenes=len(tables["scene"]), samples=len(tables["sample"]), sample_data=len(tables["sample_data"]),
            annotations=len(tables["sample_annotation"]), rounded_timestamps=rounded,
            skipped_frames=sum(part["skipped_frames"] for part in parts), **outcome_fields(outcomes))


def _merge(dataset: DatasetReader, parts: list[dict[str, Any]]) -> tuple[dict[str, list[dict[str, Any]]], int]:
    """(the 13 tables, times rounded) from the scenes' rows in scene order.

    A calibrated_sensor, sensor or category record shared by scenes is kept once, as the first scene has it.
    """
    tables: dict[str, list[dict[str, Any]]] = {name: [] for name in TABLES}
    tables["attribute"] = [{"token": _token("attribute", a), "name": a, "description": a} for a in ATTRIBUTES]
    tables["visibility"] = [{"token": k, "level": v, "description": f"visibility of whole object is {v[1:]}%"}
                            for k, v in _VISIBILITY.items()]
    calibrations: set[str] = set()
    sensors: dict[str, tuple[str, str]] = {}
    categories: dict[str, str] = {}
    for part in parts:
        for table in _SCENE_TABLES:
            rows = part["tables"][table]
            if table == "calibrated_sensor":
                rows = [r for r in rows if r["token"] not in calibrations]
                calibrations.update(r["token"] for r in rows)
            tables[table].extend(rows)
        for channel, token, kind in part["sensors"]:
            sensors.setdefault(channel, (token, kind))
        for category in part["categories"]:
            categories.setdefault(category, _token("category", category))
    tables["sensor"] = [{"token": token, "channel": channel, "modality": kind} for channel, (token, kind) in sensors.items()]
    tables["category"] = [{"token": token, "name": cat, "description": cat} for cat, token in categories.items()]
    map_token = _token("map", str(dataset.root))
    tables["map"] = [{"token": map_token, "log_tokens": [r["token"] for r in tables["log"]], "category": "semantic_prior",
                      "filename": f"maps/{map_token}.png"}]
    return tables, sum(part["rounded"] for part in parts)


def _export_scene(task: _SceneTask) -> SceneOutcome:
    """One scene task: skip it if complete, else write its files and return its rows; input errors are returned."""
    job = task.job
    done = completed(job)
    if done is not None:
        return done
    path: Path | Location = scene_path(dataset_root(job.dataset), job.scene)
    dst = OutputFolder.of(job.dst)
    files: list[str] = []
    try:
        reader, path = open_dataset_scene(job)
        try:
            data = _scene_rows(reader, task, dst, files)
        finally:
            reader.close()
    except AvdataError as error:
        dst.remove(files)
        if isinstance(error, DiskFullError):  # the run stops (one line), leaving no file of this scene
            raise
        return SceneOutcome(scene=job.scene, status=FAILED, problems=[problem(job.scene, path, error)])
    return record(job, SceneOutcome(scene=job.scene, status=WRITTEN, problems=[], data=data), files)


def _scene_rows(reader: SceneReader, task: _SceneTask, dst: OutputFolder, files: list[str]) -> dict[str, Any] | None:
    """Writes the scene's sensor files (their names appended to ``files``) and returns its rows; None without frames."""
    name = task.job.scene
    graph = reader.graph
    ego = reader.ego_frame() or "ego"
    specs = {s: spec for s, spec in reader.sensors().items()
             if spec.get("kind") in ("lidar", "camera")}
    channel_of = channel_map(specs, ego, dict(task.channels))
    all_infos = reader.frame_infos()
    lidar_top = [s for s, channel in channel_of.items() if channel == "LIDAR_TOP"]
    infos = [info for info in all_infos if not lidar_top or lidar_top[0] in info.sensor_timestamps_ns]
    if not infos:
        return None
    tables: dict[str, list[dict[str, Any]]] = {table: [] for table in _SCENE_TABLES}
    sensors_seen: dict[str, tuple[str, str]] = {}
    calibrations: dict[tuple[Any, ...], str] = {}
    rounded = 0
    log_token = _token("log", name)
    tables["log"].append({"token": log_token, "logfile": name, "vehicle": ego, "date_captured": "",
                          "location": str(reader.metadata.get("location", name))})
    sample_tokens = [sample_token(name, info.frame_index) for info in infos]
    frame_times_ns = np.array([info.timestamp_ns for info in infos], np.int64)
    for i, info in enumerate(infos):
        rounded += int(info.timestamp_ns % 1000 != 0)
        tables["sample"].append({"token": sample_tokens[i], "timestamp": _us(info.timestamp_ns),
                                 "scene_token": _token("scene", name),
                                 "prev": sample_tokens[i - 1] if i else "",
                                 "next": sample_tokens[i + 1] if i + 1 < len(infos) else ""})
    tables["scene"].append({"token": _token("scene", name), "log_token": log_token, "nbr_samples": len(infos),
                            "first_sample_token": sample_tokens[0], "last_sample_token": sample_tokens[-1],
                            "name": name, "description": task.description})
    for sensor, spec in sorted(specs.items()):
        kind = spec["kind"]
        topic = topics.sensor_topic(sensor, topics.POINTS_SUFFIX if kind == "lidar" else topics.IMAGE_SUFFIX)
        if topic not in reader.topics:
            continue
        channel = checked_name(channel_of[sensor], f"nuScenes channel of {sensor}")
        sensor_token = sensors_seen.setdefault(channel, (_token("sensor", channel), kind))[0]
        agent = sensor.split("/")[0]
        key_times = {info.sensor_timestamps_ns[sensor]: i for i, info in enumerate(infos)
                     if sensor in info.sensor_timestamps_ns}
        times = reader.times(topic)
        sd_tokens = [_token("sample_data", name, sensor, int(t)) for t in times]
        for j, t in enumerate(times.tolist()):
            rounded += int(t % 1000 != 0)
            is_key = t in key_times
            owner = key_times[t] if is_key else min(int(np.searchsorted(frame_times_ns, t)), len(infos) - 1)
            agent_T_sensor = graph.lookup(agent, sensor, t)
            calib_key = (channel, *np.round(agent_T_sensor.as_matrix().ravel(), 12).tolist())
            intrinsic: list[list[float]] = []
            width = height = 0
            if kind == "camera":
                calibration = reader.camera_calibration(sensor, t)
                intrinsic = np.asarray(calibration.K, float).reshape(3, 3).tolist()
                width, height = int(calibration.width), int(calibration.height)
                calib_key = (*calib_key, *np.ravel(intrinsic).tolist())
            if calib_key not in calibrations:
                calibrations[calib_key] = _token("calibrated_sensor", *calib_key)
                tables["calibrated_sensor"].append({
                    "token": calibrations[calib_key], "sensor_token": sensor_token,
                    "translation": agent_T_sensor.translation.tolist(), "rotation": agent_T_sensor.quat_wxyz().tolist(),
                    "camera_intrinsic": intrinsic})
            pose = graph.lookup("world", agent, t)
            pose_token = _token("ego_pose", name, agent, t)
            tables["ego_pose"].append({"token": pose_token, "timestamp": _us(t), "rotation": pose.quat_wxyz().tolist(),
                                       "translation": pose.translation.tolist()})
            filename, fileformat = _write_sensor_file(reader, sensor, kind, f"{'samples' if is_key else 'sweeps'}/{channel}",
                                                      f"{name}__{channel}__{t}", t, dst, files)
            tables["sample_data"].append({
                "token": sd_tokens[j], "sample_token": sample_tokens[owner], "ego_pose_token": pose_token,
                "calibrated_sensor_token": calibrations[calib_key], "timestamp": _us(t), "fileformat": fileformat,
                "is_key_frame": bool(is_key), "height": height, "width": width, "filename": filename,
                "prev": sd_tokens[j - 1] if j else "", "next": sd_tokens[j + 1] if j + 1 < len(times) else ""})
    categories: dict[str, str] = {}
    _annotations(reader, name, infos, sample_tokens, tables, categories, task.nuscenes_source, specs)
    return {"tables": tables, "rounded": rounded, "categories": list(categories),
            "sensors": [[channel, token, kind] for channel, (token, kind) in sensors_seen.items()],
            "channels": {sensor: channel_of[sensor] for sensor in specs}, "skipped_frames": len(all_infos) - len(infos)}


def _write_sensor_file(reader: SceneReader, sensor: str, kind: str, folder: str, stem: str, time_ns: int, dst: OutputFolder,
                       files: list[str]) -> tuple[str, str]:
    """Writes one lidar or camera message as ``folder/stem.<format>``, its name appended to ``files`` first.

    Returns:
        (its name relative to DST, its nuScenes ``fileformat``).
    """
    if kind == "lidar":
        filename = f"{folder}/{stem}.pcd.bin"
        files.append(filename)
        dst.write(filename, _pcd_bin(reader.points(sensor, time_ns)))
        return filename, "pcd"
    data, fmt = reader.image(sensor, time_ns)
    # The stored format and the channel come from the scene file: a crafted one must not name a path.
    fileformat = checked_name("jpg" if fmt.lower() in ("jpeg", "jpg") else fmt.lower(), f"{sensor} image format")
    filename = f"{folder}/{stem}.{fileformat}"
    files.append(filename)
    dst.write(filename, data)
    return filename, fileformat


def _pcd_bin(points: np.ndarray) -> bytes:
    names = points.dtype.names or ()
    out = np.zeros((len(points), 5), np.float32)
    for column, field_name in enumerate(("x", "y", "z", "intensity", "ring")):
        if field_name in names:
            out[:, column] = points[field_name]
    return out.tobytes()


def _annotations(reader: Any, name: str, infos: list[Any], sample_tokens: list[str], tables: dict[str, list[dict[str, Any]]],
                 categories: dict[str, str], nuscenes_source: bool, specs: dict[str, dict[str, Any]]) -> None:
    own = {str(a.get("object_id")) for a in reader.metadata.get("agents", {}).values() if isinstance(a, dict)}
    lidars = [s for s, spec in specs.items() if spec["kind"] == "lidar"]
    visibility: dict[tuple[int, str], list[Any]] = {}
    for sensor, frame_index, _, vis in reader.iter_visibility():
        visibility.setdefault((frame_index, sensor), []).append(vis)
    chains: dict[str, list[str]] = {}
    rows_by_token: dict[str, dict[str, Any]] = {}
    for i, info in enumerate(infos):
        if not info.annotated:
            continue
        _, labels = reader.labels(info.frame_index)
        boxes = labels.boxes.to("world", reader.graph, info.timestamp_ns)
        points = np.zeros(len(boxes), np.int64)
        counted = np.zeros(len(boxes), bool)
        fraction = np.full(len(boxes), np.nan)
        occlusion = np.full(len(boxes), 3)
        for (frame_index, sensor), entries in visibility.items():
            if frame_index != info.frame_index:
                continue
            for vis in entries:
                ids = np.asarray(vis.object_ids).astype(str)
                order = np.argsort(ids)
                pos = np.clip(np.searchsorted(ids[order], boxes.ids), 0, max(len(ids) - 1, 0))
                has = (ids[order][pos] == boxes.ids) if len(ids) else np.zeros(len(boxes), bool)
                row = order[pos][has]
                if sensor in lidars and vis.n_points is not None:
                    n = np.asarray(vis.n_points)[row]
                    points[has] += np.maximum(n, 0)
                    counted[has] |= n >= 0
                if vis.visible_fraction is not None:
                    fraction[has] = np.fmax(fraction[has], np.asarray(vis.visible_fraction, float)[row])
                if vis.occlusion is not None:
                    occlusion[has] = np.minimum(occlusion[has], np.asarray(vis.occlusion)[row])
        for k in range(len(boxes)):
            oid = str(boxes.ids[k])
            if oid in own:
                continue
            category = str(labels.source_classes[k]) if nuscenes_source else CATEGORY_OF_CLASS.get(str(boxes.classes[k]),
                                                                                              "movable_object.debris")
            categories.setdefault(category, _token("category", category))
            instance = _token("instance", name, oid)
            token = annotation_token(name, info.frame_index, oid)
            length, width, height = boxes.size_lwh[k].tolist()
            row = {"token": token, "sample_token": sample_tokens[i], "instance_token": instance,
                   "visibility_token": _visibility_level(float(fraction[k]), int(occlusion[k])), "attribute_tokens": [],
                   "translation": boxes.center[k].tolist(), "size": [width, length, height],
                   "rotation": boxes.quat_wxyz[k].tolist(), "prev": "", "next": "",
                   "num_lidar_pts": int(points[k]) if counted[k] else -1, "num_radar_pts": 0,
                   "category_name": category}
            rows_by_token[token] = row
            chains.setdefault(instance, []).append(token)
    for instance, tokens in chains.items():
        for a, b in zip(tokens, tokens[1:], strict=False):
            rows_by_token[a]["next"], rows_by_token[b]["prev"] = b, a
        category = rows_by_token[tokens[0]].pop("category_name")
        for t in tokens[1:]:
            rows_by_token[t].pop("category_name")
        tables["instance"].append({"token": instance, "category_token": categories[category], "nbr_annotations": len(tokens),
                                   "first_annotation_token": tokens[0], "last_annotation_token": tokens[-1]})
        tables["sample_annotation"].extend(rows_by_token[t] for t in tokens)
