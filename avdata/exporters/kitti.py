"""Unified dataset -> KITTI 3D object files, for tools that only read KITTI (OpenPCDet, mmdetection3d).

Writes ``training/`` (annotated frames) and ``testing/`` (the others), each with ``calib/``,
``velodyne/``, ``image_2/`` and (training) ``label_2/``, plus ``ImageSets/{train,val,trainval,test}.txt``
and ``avdata_export.json`` (which scene and frame each sample came from). Works on any unified dataset:

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
import os
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from avdata.errors import AvdataError, InputError
from avdata.frames import Boxes3D, FrameGraph, Transform
from avdata.schema import DatasetReader, SceneReader, VisibilityLabels
from avdata.sources.kitti import CALIB_KEYS, VELODYNE_DTYPE, format_calib

#: KITTI object classes written verbatim from a KITTI source.
KITTI_CLASSES = frozenset({"Car", "Van", "Truck", "Pedestrian", "Person_sitting", "Cyclist", "Tram", "Misc"})
_UPRIGHT_TOLERANCE = 1e-6


@dataclass(frozen=True, slots=True, kw_only=True)
class ExportResult:
    """What an export wrote: sample counts per KITTI split, and why frames were left out."""

    training: int
    testing: int
    tilted_boxes: int
    skipped: list[str] = field(default_factory=list)
    skipped_frames: int = 0


@dataclass(frozen=True, slots=True, kw_only=True)
class _Sensors:
    agent: str
    lidar: str
    camera: str
    reference: str


def export_kitti_object(
    dataset_root: str | Path,
    dst: str | Path,
    *,
    lidar: str | None = None,
    camera: str | None = None,
    scenes: Sequence[str] | None = None,
) -> ExportResult:
    """Writes a unified dataset as KITTI object files.

    Args:
        dataset_root: the unified dataset folder.
        dst: the KITTI folder to write (``training/``, ``testing/``, ``ImageSets/``).
        lidar: the lidar sensor frame, e.g. "ego/velodyne"; default ``<agent>/velodyne`` or the
            agent's first lidar.
        camera: the camera for ``image_2`` and P2; default ``<agent>/cam2`` or the agent's first camera.
        scenes: only these scenes (all when None).

    Raises:
        InputError: the dataset has no lidar or camera to export, or a named one is unknown.
    """
    dataset = DatasetReader(dataset_root)
    dst = Path(dst)
    kitti_source = str((dataset.manifest.get("source") or {}).get("name", "")).startswith("kitti")
    names = list(scenes) if scenes else dataset.scenes
    counters = {"training": 0, "testing": 0}
    lists: dict[str, list[str]] = {"train": [], "val": [], "test": []}
    provenance = []
    skipped: list[str] = []
    n_skipped = 0
    tilted = 0
    for name in names:
        reader = dataset.scene(name)
        sensors = _choose_sensors(reader, lidar, camera)
        visibility = {index: vis for sensor, index, _, vis in reader.iter_visibility() if sensor == sensors.camera}
        skipped_frames: dict[tuple[str, str], list[int]] = {}
        split = str(reader.metadata.get("split", ""))
        for frame_index in range(len(reader.times("/labels/objects"))):
            info, labels = reader.labels(frame_index)
            times = info.sensor_timestamps_ns
            missing = [s for s in (sensors.lidar, sensors.camera) if s not in times]
            if missing:
                skipped_frames.setdefault((name, ", ".join(missing)), []).append(frame_index)
                continue
            kitti_split = "training" if info.annotated else "testing"
            sample = f"{counters[kitti_split]:06d}"
            counters[kitti_split] += 1
            root = dst / kitti_split
            calibration = reader.camera_calibration(sensors.camera, times[sensors.camera])
            K = np.array(calibration.K).reshape(3, 3)
            size = (int(calibration.width), int(calibration.height))
            calib = _calib(reader, sensors, info.timestamp_ns, K) | _source_calib(reader, sensors, frame_index)
            _write(root / "calib" / f"{sample}.txt", format_calib(calib))
            _write_velodyne(root / "velodyne" / f"{sample}.bin", reader.points(sensors.lidar, times[sensors.lidar]))
            data, fmt = reader.image(sensors.camera, times[sensors.camera])
            _write_png(root / "image_2" / f"{sample}.png", data, fmt)
            if info.annotated:
                boxes_ref = labels.boxes.to(sensors.reference, reader.graph, info.timestamp_ns)
                lines, n_tilted = _label_lines(boxes_ref, labels.source_classes if kitti_source else None,
                                               visibility.get(frame_index), calib["P2"], size)
                tilted += n_tilted
                _write(root / "label_2" / f"{sample}.txt", "".join(line + "\n" for line in lines))
                lists["val" if split in ("val", "validation") else "train"].append(sample)
            else:
                lists["test"].append(sample)
            provenance.append({"split": kitti_split, "sample": sample, "scene": name, "frame_index": frame_index,
                               "timestamp_ns": info.timestamp_ns})
        n_skipped += sum(len(frames) for frames in skipped_frames.values())
        for (scene_name, missing_sensors), frames in skipped_frames.items():
            skipped.append(f"{scene_name} {'frame' if len(frames) == 1 else 'frames'} {_ranges(frames)}: "
                           f"no message of {missing_sensors}")
    image_sets = dst / "ImageSets"
    image_sets.mkdir(parents=True, exist_ok=True)
    for list_name, samples in (*lists.items(), ("trainval", sorted(lists["train"] + lists["val"]))):
        _write(image_sets / f"{list_name}.txt", "".join(s + "\n" for s in samples))
    _write(dst / "avdata_export.json", json.dumps({"source": str(dataset.root), "samples": provenance}, indent=1))
    return ExportResult(training=counters["training"], testing=counters["testing"], tilted_boxes=tilted,
                        skipped=skipped, skipped_frames=n_skipped)


def _choose_sensors(reader: SceneReader, lidar: str | None, camera: str | None) -> _Sensors:
    agent = reader.ego_frame() or "ego"
    sensors = reader.sensors()

    def pick(given: str | None, kind: str, preferred: str, suffix: str) -> str:
        if given is not None:
            if given not in sensors or sensors[given].get("kind") != kind:
                raise InputError(f"scene {reader.name!r}: expected a {kind} among {sorted(sensors)}, got {given!r}")
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
    """(N, 4) clipped 2D boxes, (N,) truncation (fraction of the unclipped box outside), (N,) in image."""
    n = len(boxes_ref)
    if not n:
        return np.zeros((0, 4)), np.zeros(0), np.zeros(0, dtype=bool)
    corners = boxes_ref.corners().reshape(-1, 3)
    homogeneous = np.c_[corners, np.ones(len(corners))] @ P2.T
    depth = homogeneous[:, 2].reshape(n, 8)
    with np.errstate(divide="ignore", invalid="ignore"):
        pixels = (homogeneous[:, :2] / homogeneous[:, 2:]).reshape(n, 8, 2)
    front = depth > 0.1
    # Corners behind the camera are left out; a box with none in front has no 2D box (NaN), computed
    # without nanmin's "All-NaN slice" warning.
    lowest = np.min(np.where(front[:, :, None], pixels, np.inf), axis=1)
    highest = np.max(np.where(front[:, :, None], pixels, -np.inf), axis=1)
    box = np.where(np.any(front, axis=1)[:, None], np.concatenate([lowest, highest], axis=1), np.nan)
    width, height = image_size
    if width and height:
        clipped = np.clip(box, 0.0, [width - 1, height - 1, width - 1, height - 1])
    else:
        clipped = box
    area = (box[:, 2] - box[:, 0]) * (box[:, 3] - box[:, 1])
    clipped_area = (clipped[:, 2] - clipped[:, 0]) * (clipped[:, 3] - clipped[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        truncation = np.where(area > 0, 1.0 - clipped_area / area, 1.0)
    in_image = np.any(front, axis=1) & (clipped_area > 0)
    return np.nan_to_num(clipped, nan=-1.0), np.nan_to_num(truncation, nan=1.0), in_image


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
    return {"car": "Car", "truck": "Truck", "pedestrian": "Pedestrian", "cyclist": "Cyclist"}.get(
        unified, unified[:1].upper() + unified[1:])


def _write(path: Path, text: str) -> None:
    _write_bytes(path, text.encode())


def _write_bytes(path: Path, data: bytes) -> None:
    """Writes under a temporary name and renames, so an interrupted export leaves no truncated file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def _write_velodyne(path: Path, points: np.ndarray) -> None:
    if points.dtype == VELODYNE_DTYPE:
        data = points.tobytes()
    else:
        packed = np.zeros(len(points), dtype=VELODYNE_DTYPE)
        for name in ("x", "y", "z", "intensity"):
            if name in (points.dtype.names or ()):
                packed[name] = points[name]
        data = packed.tobytes()
    _write_bytes(path, data)


def _write_png(path: Path, data: bytes, fmt: str) -> None:
    if fmt != "png":
        image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise AvdataError(f"{path}: the stored {fmt} image does not decode; cannot write it as PNG")
        _, encoded = cv2.imencode(".png", image)
        data = encoded.tobytes()
    _write_bytes(path, data)
