"""Unified dataset -> KITTI 3D object files, for tools that only read KITTI (OpenPCDet, mmdetection3d).

Writes ``training/`` (annotated frames) and ``testing/`` (the others), each with ``calib/``,
``velodyne/``, ``image_2/`` and (training) ``label_2/``, plus ``ImageSets/{train,val,trainval,test}.txt``
and ``avdata_export.json`` (which scene and frame each sample came from), one task per scene on an
executor (:mod:`avdata.exporters.driver`: resume, stale files, ``errors.jsonl``). Works on any unified dataset:

- ``velodyne/NNNNNN.bin``: the chosen lidar's points in its own frame as float32 x, y, z, intensity
  (the stored bytes unchanged when they already are exactly that; intensity 0 when the source has none).
- ``image_2/NNNNNN.png``: the chosen camera's PNG bytes unchanged (JPEG is re-encoded as PNG).
- ``calib``: for a scene converted from KITTI with the default sensors, KITTI's own matrices (kept in the
  scene metadata as ``kitti_calibration``), exactly. Otherwise the reference ("rectified camera 0")
  frame is ``<agent>/cam0`` when the dataset has it with a calibration, else the chosen camera. ``P_i = K_i · [R | t]`` of
  ``cam_i_T_ref`` (the KITTI baseline form when cameras are parallel); ``R0_rect`` = ``ref_T_unrect``
  and ``Tr_velo_to_cam`` = ``unrect_T_lidar`` when ``<ref>_unrectified`` exists, else identity and
  ``ref_T_lidar``; ``Tr_imu_to_velo`` = ``lidar_T_imu`` (``<agent>/imu``, else the body frame).
  Cameras the dataset lacks get P2's matrix.
- ``label_2``: boxes moved into the reference frame through the scene's graph, written with KITTI's
  bottom centre, h w l and ``rotation_y``; truncation, occlusion, alpha and 2D box from the camera's
  visibility labels, or computed from the projected box when absent (occlusion then 3 = unknown);
  ignore regions become DontCare lines. Class: the source class when the source is KITTI, else the
  unified class capitalised (``car`` -> ``Car``, ``traffic_cone`` -> ``Traffic_cone``). A box tilted
  in the reference frame (KITTI boxes only turn about camera y) keeps its centre and the heading of
  its x axis; the number of such boxes is reported.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from avdata.errors import AvdataError, DiskFullError, InputError
from avdata.executors.folder import OutputFolder
from avdata.executors.pipeline import SceneRunResult, outcome_fields
from avdata.executors.scenes import FAILED, WRITTEN, Problem, SceneOutcome
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
from avdata.frames import Boxes3D, FrameGraph, Transform
from avdata.schema import DatasetReader, SceneReader, VisibilityLabels, scene_path, topics
from avdata.schema.dataset import dataset_root, open_scene
from avdata.sources.kitti import CALIB_KEYS, KITTI_CLASS_OF_UNIFIED, KITTI_CLASSES, VELODYNE_DTYPE, format_calib
from avdata.storage import Location

_UPRIGHT_TOLERANCE = 1e-6
_SPLITS = ("training", "testing")


@dataclass(frozen=True, slots=True, kw_only=True)
class ExportResult(SceneRunResult):
    """What an export run did: samples in the export per KITTI split, scenes by outcome, problems.

    ``training``, ``testing``, ``tilted_boxes`` and ``skipped_frames`` count the whole export (scenes
    complete from an earlier run included); ``problems`` are those of the scenes this run wrote or failed.
    """

    training: int
    testing: int
    tilted_boxes: int
    skipped_frames: int


@dataclass(frozen=True, slots=True, kw_only=True)
class _Sensors:
    agent: str
    lidar: str
    camera: str
    reference: str


@dataclass(frozen=True, slots=True, kw_only=True)
class _Sample:
    """One planned KITTI sample: the frame it comes from and where it goes."""

    frame_index: int
    split: str
    sample: str
    image_set: str
    timestamp_ns: int
    lidar_time_ns: int
    camera_time_ns: int

    def files(self) -> list[str]:
        """Its files relative to DST."""
        folders = {"calib": ".txt", "velodyne": ".bin", "image_2": ".png"}
        if self.split == "training":
            folders["label_2"] = ".txt"
        return [f"{self.split}/{folder}/{self.sample}{suffix}" for folder, suffix in folders.items()]


@dataclass(frozen=True, slots=True, kw_only=True)
class _SceneTask:
    job: SceneJob
    sensors: _Sensors
    kitti_source: bool
    n_frames: int
    samples: tuple[_Sample, ...]


def export_kitti_object(
    dataset_root: str | Path | Location,
    dst: str | Path | Location,
    *,
    lidar: str | None = None,
    camera: str | None = None,
    scenes: Sequence[str] | None = None,
    config: ExportConfig | None = None,
) -> ExportResult:
    """Writes a unified dataset as KITTI object files, one task per scene.

    A planning pass over the index (no sensor data) numbers the samples across scenes and picks each
    one's split; each scene task then writes its samples; the finishing step writes ``ImageSets/`` and
    ``avdata_export.json``. The files are the same whatever the executor or number of workers.

    Args:
        dataset_root: the unified dataset folder (a path, or ``s3://...``, ``gs://...``).
        dst: the KITTI folder to write (``training/``, ``testing/``, ``ImageSets/``; a path, or a store URI).
        lidar: the lidar sensor frame, e.g. "ego/velodyne"; default ``<agent>/velodyne`` or the
            agent's first lidar.
        camera: the camera for ``image_2`` and P2; default ``<agent>/cam2`` or the agent's first camera.
        scenes: only these scenes (all when None).
        config: executor, workers, ``force``, progress (its ``dataset``, ``dst`` and ``scenes`` are
            replaced by the arguments above); default: the calling process, quiet.

    Raises:
        InputError: the dataset is missing or unreadable, a scene is unknown, DST cannot be written or
            another process holds its lock. Problems of single scenes and frames are in the result instead.
    """
    config = export_config(config, dataset_root, dst, scenes)
    return run_export(KittiObjectExporter(config, lidar=lidar, camera=camera))


class KittiObjectExporter(Exporter[ExportResult]):
    """Unified -> KITTI object files (see the module docstring and :func:`export_kitti_object`)."""

    format = "kitti-object"

    def __init__(self, config: ExportConfig, *, lidar: str | None = None, camera: str | None = None):
        super().__init__(config)
        self.lidar = lidar
        self.camera = camera
        self._skipped_frames = 0

    def plan(self, dataset: DatasetReader, scenes: list[str]) -> tuple[list[Any], list[SceneOutcome]]:
        """Numbers the samples across scenes (see :func:`_plan`) and removes files no planned sample writes."""
        tasks, failures, self._skipped_frames = _plan(dataset, self.config, scenes, self.lidar, self.camera)
        prune(self.out, _SPLITS, {name for task in tasks for s in task.samples for name in s.files()})
        return list(tasks), failures

    def export_scene(self, task: Any) -> SceneOutcome:
        """Writes one scene's samples (see :func:`_export_scene`)."""
        return _export_scene(task)

    def finish(self, dataset: DatasetReader, outcomes: list[SceneOutcome]) -> ExportResult:
        """Writes ``ImageSets/`` and ``avdata_export.json``; the counts of the whole export."""
        written = [(o.scene, _Sample(**s)) for o in outcomes if o.data for s in o.data["samples"]]
        samples = [s for _, s in written]
        _write_image_sets(self.out, samples)
        provenance = [{"split": s.split, "sample": s.sample, "scene": scene, "frame_index": s.frame_index,
                       "timestamp_ns": s.timestamp_ns} for scene, s in written]
        self.out.write("avdata_export.json",
                         json.dumps({"source": str(dataset.root), "samples": provenance}, indent=1).encode())
        return ExportResult(
            training=sum(s.split == "training" for s in samples), testing=sum(s.split == "testing" for s in samples),
            tilted_boxes=sum(o.data["tilted"] for o in outcomes if o.data), skipped_frames=self._skipped_frames,
            **outcome_fields(outcomes))


def _plan(dataset: DatasetReader, config: ExportConfig, names: list[str], lidar: str | None,
          camera: str | None) -> tuple[list[_SceneTask], list[SceneOutcome], int]:
    """(one task per plannable scene, outcomes of scenes that cannot be planned, frames skipped).

    Samples are numbered across scenes in scene and frame order, separately per split, from the index's
    frames table and each scene's sensor list (no sensor data is read).
    """
    kitti_source = str((dataset.manifest.get("source") or {}).get("name", "")).startswith("kitti")
    frames = dataset.frames().select(["scene", "frame_index", "timestamp_ns", "annotated", "sensor_timestamps_ns"])
    rows: dict[str, list[dict[str, Any]]] = {}
    for row in frames.to_pylist():
        rows.setdefault(row["scene"], []).append(row)
    counters = dict.fromkeys(_SPLITS, 0)
    tasks: list[_SceneTask] = []
    failures: list[SceneOutcome] = []
    n_skipped = 0
    for name in names:
        path = scene_path(dataset.root, name)
        try:
            reader = open_scene(dataset.root, name)
            try:
                sensors = _choose_sensors(reader, lidar, camera)
                scene_split = str(reader.metadata.get("split", ""))
            finally:
                reader.close()
        except AvdataError as error:
            failures.append(SceneOutcome(scene=name, status=FAILED, problems=[problem(name, path, error)]))
            continue
        image_set = "val" if scene_split in ("val", "validation") else "train"
        samples = []
        skipped: dict[str, list[int]] = {}
        scene_rows = sorted(rows.get(name, []), key=lambda r: r["frame_index"])
        for row in scene_rows:
            times = dict(row["sensor_timestamps_ns"] or [])
            missing = [s for s in (sensors.lidar, sensors.camera) if s not in times]
            if missing:
                skipped.setdefault(", ".join(missing), []).append(int(row["frame_index"]))
                continue
            split = "training" if row["annotated"] else "testing"
            samples.append(_Sample(frame_index=int(row["frame_index"]), split=split, sample=f"{counters[split]:06d}",
                                   image_set=image_set if row["annotated"] else "test",
                                   timestamp_ns=int(row["timestamp_ns"]), lidar_time_ns=int(times[sensors.lidar]),
                                   camera_time_ns=int(times[sensors.camera])))
            counters[split] += 1
        n_skipped += sum(len(f) for f in skipped.values())
        warnings = tuple(Problem(severity="warning", scene=name, file=str(path),
                                 message=f"{'frame' if len(f) == 1 else 'frames'} {_ranges(f)} skipped: no message of {m}")
                         for m, f in skipped.items())
        options = {"sensors": asdict(sensors), "kitti_source": kitti_source, "n_frames": len(scene_rows),
                   "samples": [asdict(s) for s in samples]}
        job = SceneJob(dataset=str(dataset.root), dst=str(config.dst), scene=name, force=config.force,
                       fingerprint=scene_fingerprint(dataset, name, "kitti-object", options), problems=warnings)
        tasks.append(_SceneTask(job=job, sensors=sensors, kitti_source=kitti_source, n_frames=len(scene_rows),
                                samples=tuple(samples)))
    return tasks, failures, n_skipped


def _export_scene(task: _SceneTask) -> SceneOutcome:
    """One scene task: skip it if complete, else write its samples; input errors are returned, never raised.

    A frame whose data cannot be read costs its sample (its files are removed); a scene that cannot be
    read at all costs its samples.
    """
    job = task.job
    done = completed(job)
    if done is not None:
        return done
    dst = OutputFolder.of(job.dst)
    path: Path | Location = scene_path(dataset_root(job.dataset), job.scene)
    problems = list(job.problems)
    written: list[_Sample] = []
    tilted = 0
    try:
        reader, path = open_dataset_scene(job)
    except AvdataError as error:
        return _scene_failed(task, problems, problem(job.scene, path, error))
    try:
        n_frames = len(reader.times(topics.OBJECTS))
        if n_frames != task.n_frames:
            return _scene_failed(task, problems, problem(job.scene, path, AvdataError(
                f"expected {task.n_frames} frames as index/frames.parquet lists, got {n_frames} "
                f"(rebuild the index: avdata index {job.dataset})")))
        visibility = {index: vis for sensor, index, _, vis in reader.iter_visibility() if sensor == task.sensors.camera}
        lost: dict[str, list[_Sample]] = {}  # error message -> the samples it cost
        for sample in task.samples:
            try:
                tilted += _write_sample(reader, task, sample, visibility.get(sample.frame_index), dst)
            except DiskFullError:  # the run stops: no sample of this unfinished scene stays
                dst.remove([name for s in [*written, sample] for name in s.files()])
                raise
            except AvdataError as error:
                dst.remove(sample.files())
                lost.setdefault(problem(job.scene, path, error).message, []).append(sample)
                continue
            written.append(sample)
        # One line per cause (a damaged chunk can hold many frames), not one per frame.
        for message, samples in lost.items():
            what = (f"frame {samples[0].frame_index} (sample {samples[0].split}/{samples[0].sample})" if len(samples) == 1
                    else f"frames {_ranges([s.frame_index for s in samples])} ({len(samples)} samples)")
            problems.append(problem(job.scene, path, AvdataError(message), f"{what} not written: "))
    except DiskFullError:
        raise
    except AvdataError as error:
        return _scene_failed(task, problems, problem(job.scene, path, error))
    finally:
        reader.close()
    outcome = SceneOutcome(scene=job.scene, status=WRITTEN, problems=problems,
                           data={"samples": [asdict(s) for s in written], "tilted": tilted})
    return record(job, outcome, [name for s in written for name in s.files()])


def _scene_failed(task: _SceneTask, problems: list[Problem], error: Problem) -> SceneOutcome:
    # An earlier export's files under this scene's sample names must not pass for this run's.
    OutputFolder.of(task.job.dst).remove([name for sample in task.samples for name in sample.files()])
    return SceneOutcome(scene=task.job.scene, status=FAILED, problems=[*problems, error])


def _write_sample(reader: SceneReader, task: _SceneTask, sample: _Sample, vis: VisibilityLabels | None,
                  dst: OutputFolder) -> int:
    """Writes one sample's files; returns its number of tilted boxes."""
    sensors = task.sensors
    info, labels = reader.labels(sample.frame_index)
    times = info.sensor_timestamps_ns
    planned = (sample.timestamp_ns, sample.split == "training", sample.lidar_time_ns, sample.camera_time_ns)
    found = (info.timestamp_ns, info.annotated, times.get(sensors.lidar), times.get(sensors.camera))
    if found != planned:
        raise AvdataError(f"expected the frame (time, annotated, lidar and camera times) index/frames.parquet lists, "
                          f"{planned}, got {found} (rebuild the index: avdata index {task.job.dataset})")
    root = sample.split
    calibration = reader.camera_calibration(sensors.camera, times[sensors.camera])
    K = np.array(calibration.K).reshape(3, 3)
    size = (int(calibration.width), int(calibration.height))
    calib = _calib(reader, sensors, info.timestamp_ns, K) | _source_calib(reader, sensors, sample.frame_index)
    points = reader.points(sensors.lidar, times[sensors.lidar])
    data, fmt = reader.image(sensors.camera, times[sensors.camera])
    n_tilted = 0
    label = None
    if info.annotated:
        boxes_ref = labels.boxes.to(sensors.reference, reader.graph, info.timestamp_ns)
        lines, n_tilted = _label_lines(boxes_ref, labels.source_classes if task.kitti_source else None, vis,
                                       calib["P2"], size)
        label = "".join(line + "\n" for line in lines)
    dst.write(f"{root}/calib/{sample.sample}.txt", format_calib(calib).encode())
    _write_velodyne(dst, f"{root}/velodyne/{sample.sample}.bin", points)
    _write_png(dst, f"{root}/image_2/{sample.sample}.png", data, fmt)
    if label is not None:
        dst.write(f"{root}/label_2/{sample.sample}.txt", label.encode())
    return n_tilted


def _write_image_sets(dst: OutputFolder, samples: list[_Sample]) -> None:
    """``ImageSets/{train,val,test,trainval}.txt`` of the samples written, in sample order."""
    lists: dict[str, list[str]] = {"train": [], "val": [], "test": []}
    for sample in samples:
        lists[sample.image_set].append(sample.sample)
    for list_name, names in (*lists.items(), ("trainval", sorted(lists["train"] + lists["val"]))):
        dst.write(f"ImageSets/{list_name}.txt", "".join(s + "\n" for s in names).encode())


def _choose_sensors(reader: SceneReader, lidar: str | None, camera: str | None) -> _Sensors:
    agent = reader.ego_frame() or "ego"
    sensors = reader.sensors()

    def pick(given: str | None, kind: str, preferred: str, suffix: str) -> str:
        if given is not None:
            if given not in sensors or sensors[given].get("kind") != kind:
                of_kind = sorted(s for s, spec in sensors.items() if spec.get("kind") == kind)
                raise InputError(f"scene {reader.name!r}: expected a {kind} among {of_kind}, got {given!r}")
            return given
        topics = set(reader.topics)
        candidates = sorted(s for s, spec in sensors.items() if spec.get("kind") == kind and s.startswith(agent + "/")
                            and f"/{s}/{suffix}" in topics)
        if preferred in candidates:
            return preferred
        if not candidates:
            raise InputError(f"scene {reader.name!r}: no {kind} of agent {agent!r} with data; sensors: {sorted(sensors)}")
        return candidates[0]

    lidar_frame = pick(lidar, "lidar", f"{agent}/velodyne", "points")
    camera_frame = pick(camera, "camera", f"{agent}/cam2", "image")
    cam0 = f"{agent}/cam0"
    reference = cam0 if cam0 in reader.graph.frames and f"/{cam0}/calibration" in reader.topics else camera_frame
    return _Sensors(agent=agent, lidar=lidar_frame, camera=camera_frame, reference=reference)


def _calib(reader: SceneReader, sensors: _Sensors, time_ns: int, K_camera: np.ndarray) -> dict[str, np.ndarray]:
    """KITTI's seven matrices for one frame (see the module docstring)."""
    graph: FrameGraph = reader.graph
    out: dict[str, np.ndarray] = {}
    for i in range(4):
        frame = f"{sensors.agent}/cam{i}"
        if i == 2 or frame not in graph.frames or f"/{frame}/calibration" not in reader.topics:
            frame, K = sensors.camera, K_camera
        else:
            K = np.array(reader.camera_calibration(frame, time_ns).K).reshape(3, 3)
        cam_T_ref = graph.lookup(frame, sensors.reference, time_ns)
        rotation = np.eye(3) if np.allclose(cam_T_ref.rotation, np.eye(3), atol=1e-12, rtol=0) else cam_T_ref.rotation
        out[f"P{i}"] = K @ np.hstack([rotation, cam_T_ref.translation[:, None]])
    unrectified = f"{sensors.reference}_unrectified"
    if unrectified in graph.frames:
        out["R0_rect"] = graph.lookup(sensors.reference, unrectified, time_ns).rotation
        cam_T_lidar = graph.lookup(unrectified, sensors.lidar, time_ns)
    else:
        out["R0_rect"] = np.eye(3)
        cam_T_lidar = graph.lookup(sensors.reference, sensors.lidar, time_ns)
    imu = f"{sensors.agent}/imu" if f"{sensors.agent}/imu" in graph.frames else sensors.agent
    lidar_T_imu = graph.lookup(sensors.lidar, imu, time_ns)
    out["Tr_velo_to_cam"] = _matrix_3x4(cam_T_lidar)
    out["Tr_imu_to_velo"] = _matrix_3x4(lidar_T_imu)
    return out


def _source_calib(reader: SceneReader, sensors: _Sensors, frame_index: int) -> dict[str, np.ndarray]:
    """KITTI's own matrices of the frame, so the export repeats them exactly.

    They are used when the scene was converted from KITTI with them in its metadata (``kitti_calibration``)
    and the default sensors are exported.
    """
    stored = reader.metadata.get("kitti_calibration")
    agent = sensors.agent
    if not isinstance(stored, dict) or (sensors.lidar, sensors.camera, sensors.reference) != (
            f"{agent}/velodyne", f"{agent}/cam2", f"{agent}/cam0"):
        return {}
    if "P0" not in stored:  # KITTI object: one calibration per sample
        sample_ids = reader.metadata.get("kitti_sample_ids") or []
        stored = stored.get(f"{sample_ids[frame_index]:06d}", {}) if frame_index < len(sample_ids) else {}
    shapes = {"R0_rect": (3, 3)}
    return {key: np.asarray(stored[key], dtype=np.float64).reshape(shapes.get(key, (3, 4)))
            for key in CALIB_KEYS if key in stored}


def _matrix_3x4(transform: Transform) -> np.ndarray:
    return np.hstack([transform.rotation, transform.translation[:, None]])


def _label_lines(boxes_ref: Boxes3D, source_classes: np.ndarray | None, vis: VisibilityLabels | None,
                 P2: np.ndarray, image_size: tuple[int, int]) -> tuple[list[str], int]:
    """KITTI label lines of one frame's boxes (in the reference camera frame) and the tilted-box count."""
    n = len(boxes_ref)
    rotation = boxes_ref.rotation_matrix()
    up = rotation[:, :, 2] if n else np.zeros((0, 3))
    tilted = np.any(np.abs(up - [0.0, -1.0, 0.0]) > _UPRIGHT_TOLERANCE, axis=1)
    hwl, bottom, rotation_y = _upright(boxes_ref, tilted).to_kitti_camera()
    projected, projected_truncation, in_image = _project(boxes_ref, P2, image_size)
    geometric_alpha = rotation_y - np.arctan2(bottom[:, 0], bottom[:, 2])
    if vis is None:
        keep, occlusion = in_image, np.full(n, 3)
        box2d, truncation, alpha = projected, projected_truncation, geometric_alpha
        ignore = np.zeros((0, 4))
    else:
        by_id = {object_id: k for k, object_id in enumerate(vis.object_ids.tolist())}
        k = np.array([by_id.get(str(object_id), -1) for object_id in np.asarray(boxes_ref.ids).tolist()], dtype=np.int64)
        found = k >= 0
        k = np.where(found, k, 0)

        def take(values: np.ndarray | None, fallback: np.ndarray) -> np.ndarray:
            taken = np.asarray(values)[k] if len(vis) else fallback
            finite = np.isfinite(taken) if taken.ndim == 1 else np.all(np.isfinite(taken), axis=1)
            return np.where((found & finite).reshape((-1,) + (1,) * (taken.ndim - 1)), taken, fallback)

        keep = found & (np.asarray(vis.in_fov)[k] if len(vis) else found)
        occlusion = np.where(found, np.asarray(vis.occlusion)[k], 3) if len(vis) else np.full(n, 3)
        box2d = take(vis.box2d_xyxy, projected)
        truncation = take(vis.truncation, projected_truncation)
        alpha = take(vis.alpha_rad, geometric_alpha)
        ignore = np.asarray(vis.ignore_regions_xyxy)
    lines = []
    for i in np.flatnonzero(keep):
        cls = _kitti_class(str(np.asarray(boxes_ref.classes)[i]), None if source_classes is None else str(source_classes[i]))
        values = [alpha[i], *box2d[i], *hwl[i], *bottom[i], rotation_y[i]]
        lines.append(f"{cls} {_number(truncation[i])} {int(occlusion[i]):d} " + " ".join(_number(v) for v in values))
    for x0, y0, x1, y1 in ignore.tolist():
        lines.append(f"DontCare -1 -1 -10 {x0:.2f} {y0:.2f} {x1:.2f} {y1:.2f} -1 -1 -1 -1000 -1000 -1000 -10")
    return lines, int(np.sum(tilted))


def _upright(boxes_ref: Boxes3D, tilted: np.ndarray) -> Boxes3D:
    """The boxes with each ``tilted`` (N,) one turned upright about its centre, keeping the heading of its x axis."""
    if not np.any(tilted):
        return boxes_ref
    axis_x = boxes_ref.rotation_matrix()[:, :, 0]
    heading = np.arctan2(-axis_x[:, 2], axis_x[:, 0])
    hwl = boxes_ref.size_lwh[:, [2, 1, 0]]
    bottom = boxes_ref.center + hwl[:, :1] / 2.0 * np.array([0.0, 1.0, 0.0])
    upright = Boxes3D.from_kitti_camera(hwl, bottom, heading, boxes_ref.frame)
    return replace(boxes_ref, quat_wxyz=np.where(tilted[:, None], upright.quat_wxyz, boxes_ref.quat_wxyz))


def _project(boxes_ref: Boxes3D, P2: np.ndarray, image_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N, 4) clipped 2D boxes (-1 where none), (N,) truncation (fraction of the unclipped box outside), (N,) in image."""
    clipped, truncation, in_image = boxes_ref.image_boxes(P2, image_size)
    return np.nan_to_num(clipped, nan=-1.0), truncation, in_image


def _ranges(frames: list[int]) -> str:
    """Sorted frame indices as ranges: [2, 3, 4, 9] -> "2-4, 9"."""
    values = np.asarray(sorted(frames), dtype=np.int64)
    runs = np.split(values, np.flatnonzero(np.diff(values) != 1) + 1)
    return ", ".join(f"{run[0]}" if len(run) == 1 else f"{run[0]}-{run[-1]}" for run in runs)


def _number(value: float) -> str:
    """KITTI object's two decimals, or six when two would lose more than 1e-4 (e.g. tracking labels)."""
    text = f"{value:.2f}"
    return text if abs(float(text) - value) < 1e-4 else f"{value:.6f}"


def _kitti_class(unified: str, source: str | None) -> str:
    if source is not None and source in KITTI_CLASSES:
        return source
    return KITTI_CLASS_OF_UNIFIED.get(unified, unified[:1].upper() + unified[1:])


def _write_velodyne(dst: OutputFolder, name: str, points: np.ndarray) -> None:
    if points.dtype == VELODYNE_DTYPE:
        data = points.tobytes()
    else:
        packed = np.zeros(len(points), dtype=VELODYNE_DTYPE)
        for field in ("x", "y", "z", "intensity"):
            if field in (points.dtype.names or ()):
                packed[field] = points[field]
        data = packed.tobytes()
    dst.write(name, data)


def _write_png(dst: OutputFolder, name: str, data: bytes, fmt: str) -> None:
    if fmt != "png":
        image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise AvdataError(f"{dst}/{name}: the stored {fmt} image does not decode; cannot write it as PNG")
        _, encoded = cv2.imencode(".png", image)
        data = encoded.tobytes()
    dst.write(name, data)
