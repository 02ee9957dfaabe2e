"""A scene in Rerun (``avdata view --rerun``): the frame tree, point clouds, boxes, images and visibility over time.

Needs the optional extra ``rerun`` (``pip install 'avdata[rerun]'``). Entity paths follow the frame tree: frame
``f`` with parent ``p`` is ``<path of p>/<f without the "p/" prefix>`` under ``world`` (so ``ego/lidar_top``
is ``world/ego/lidar_top``); each carries its ``Transform3D`` (parent from child), static or on the timeline.
Under a sensor's entity:

* ``points``: the lidar's cloud in the sensor frame, coloured by intensity (turbo colour map over the
  cloud's 1st-99th percentile), at the sensor's own message time;
* ``image``: the encoded image (PNG/JPEG as stored) with its ``Pinhole`` (K, resolution; RDF camera axes);
* ``visibility``: the sensor's visibility labels of each frame (object ids, in field of view, lidar points,
  occlusion) as values at the frame's time.

Under the label frame's entity, ``labels``: the frame's boxes (centres, half sizes, rotations) labelled
``"<class> <id>"`` in their class colour. Timelines: ``scene_time`` (the scene's own nanosecond clock as
timestamps) and ``frame`` (the frame index, on labels and visibility).
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import cv2
import numpy as np
import numpy.typing as npt

from avdata.errors import InputError
from avdata.frames import FrameGraph
from avdata.outputs import temporary_path
from avdata.schema import DatasetReader, topics
from avdata.schema.records import CLASS_COLORS, OTHER_CLASS_COLOR, required_ids_and_classes
from avdata.schema.scene_reader import SceneReader

if TYPE_CHECKING:  # rerun is an optional extra, imported only when a scene is logged
    import rerun

__all__ = ["RerunCounts", "entity_path", "import_rerun", "log_scene"]

TIMELINE = "scene_time"
FRAME_TIMELINE = "frame"


@dataclass(frozen=True, slots=True, kw_only=True)
class RerunCounts:
    """What :func:`log_scene` logged: messages per kind (for the command's summary and the tests)."""

    transforms: int
    point_clouds: int
    points: int
    images: int
    box_sets: int
    boxes: int
    visibility: int


def import_rerun() -> ModuleType:
    """The ``rerun`` module, or one line saying how to install it."""
    try:
        import rerun
    except ImportError:
        raise InputError("view --rerun: expected the Rerun SDK, got none; install it with "
                         "pip install 'avdata[rerun]' (or pip install rerun-sdk)") from None
    return rerun


def entity_path(graph: FrameGraph, frame: str) -> str:
    """The Rerun entity path of ``frame``: its chain of frames from the root, each part relative to its parent."""
    import rerun as rr

    parts = []
    current: str | None = frame
    while current is not None:
        parent = graph.parent(current)
        part = current.removeprefix(f"{parent}/") if parent is not None else current
        parts.append(rr.escape_entity_path_part(part))
        current = parent
    return "/".join(reversed(parts))


def _intensity_colors(intensity: npt.NDArray[np.float64]) -> npt.NDArray[np.uint8]:
    """(N, 3) uint8 RGB of the turbo colour map over the intensities' 1st-99th percentile."""
    if not len(intensity):
        return np.zeros((0, 3), np.uint8)
    low, high = np.percentile(intensity, [1, 99])
    level = np.clip((intensity - low) / max(high - low, 1e-9) * 255.0, 0, 255).astype(np.uint8)
    # OpenCV's stubs allow any integer or float dtype here; a colour map writes (N, 1, 3) uint8 BGR.
    bgr: npt.NDArray[np.uint8] = cv2.applyColorMap(level.reshape(-1, 1), cv2.COLORMAP_TURBO)
    return np.ascontiguousarray(bgr.reshape(-1, 3)[:, ::-1])


def log_scene(ds: DatasetReader, scene: str, recording: rerun.RecordingStream) -> RerunCounts:
    """Logs every message of ``scene`` into the Rerun ``recording``."""
    import rerun as rr

    if scene not in ds.scenes:
        raise InputError(f"{ds.root}: expected a scene of {ds.scenes}, got {scene!r}")
    reader = ds.scene(scene)
    recording.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    n_transforms = _log_transforms(reader.graph, recording)
    n_clouds, n_points, n_images = _log_sensor_data(reader, recording)
    n_box_sets, n_boxes, n_visibility = _log_labels(reader, recording)
    return RerunCounts(transforms=n_transforms, point_clouds=n_clouds, points=n_points, images=n_images,
                       box_sets=n_box_sets, boxes=n_boxes, visibility=n_visibility)


def _at(recording: rerun.RecordingStream, time_ns: int, frame_index: int | None = None) -> None:
    """Sets the recording's time (and frame index) for the messages logged next."""
    recording.set_time(TIMELINE, timestamp=np.datetime64(int(time_ns), "ns"))
    if frame_index is not None:
        recording.set_time(FRAME_TIMELINE, sequence=frame_index)


def _log_transforms(graph: FrameGraph, recording: rerun.RecordingStream) -> int:
    """Logs every edge of the frame tree (static ones once, stamped ones at their times); returns the count."""
    import rerun as rr

    n_transforms = 0
    for frame in sorted(graph.frames):
        parent = graph.parent(frame)
        if parent is None:
            continue
        path = entity_path(graph, frame)
        if graph.is_static(frame):
            transform = graph.lookup(parent, frame, 0)
            recording.log(path, rr.Transform3D(translation=transform.translation, mat3x3=transform.rotation), static=True)
            n_transforms += 1
            continue
        edge = graph.stamped_edge(frame)
        for time_ns, rotation, translation in zip(edge.timestamps_ns.tolist(), edge.parent_T_child.rotation,
                                                  edge.parent_T_child.translation, strict=True):
            _at(recording, time_ns)
            recording.log(path, rr.Transform3D(translation=translation, mat3x3=rotation))
            n_transforms += 1
    return n_transforms


def _log_sensor_data(reader: SceneReader, recording: rerun.RecordingStream) -> tuple[int, int, int]:
    """Logs every point cloud and image of the scene's sensors; returns (clouds, points, images)."""
    import rerun as rr

    graph = reader.graph
    n_clouds = n_points = n_images = 0
    for sensor in sorted(reader.sensors()):
        if sensor not in graph.frames:
            continue
        path = entity_path(graph, sensor)
        points_topic = topics.sensor_topic(sensor, topics.POINTS_SUFFIX)
        if points_topic in reader.topics:
            for time_ns in reader.times(points_topic).tolist():
                cloud = reader.points(sensor, time_ns)
                xyz = np.stack([cloud["x"], cloud["y"], cloud["z"]], axis=1).astype(np.float32)
                colors = _intensity_colors(cloud["intensity"].astype(np.float64)) if "intensity" in (cloud.dtype.names or ()) \
                    else None
                _at(recording, time_ns)
                recording.log(f"{path}/points", rr.Points3D(xyz, colors=colors))
                n_clouds += 1
                n_points += len(xyz)
        image_topic = topics.sensor_topic(sensor, topics.IMAGE_SUFFIX)
        if image_topic in reader.topics:
            for time_ns in reader.times(image_topic).tolist():
                data, fmt = reader.image(sensor, time_ns)
                calibration = reader.camera_calibration(sensor, time_ns)
                _at(recording, time_ns)
                recording.log(f"{path}/image", rr.Pinhole(image_from_camera=np.asarray(calibration.K).reshape(3, 3),
                                                          resolution=[calibration.width, calibration.height],
                                                          camera_xyz=rr.ViewCoordinates.RDF))
                recording.log(f"{path}/image", rr.EncodedImage(contents=bytes(data), media_type=f"image/{_media(fmt)}"))
                n_images += 1
    return n_clouds, n_points, n_images


def _log_labels(reader: SceneReader, recording: rerun.RecordingStream) -> tuple[int, int, int]:
    """Logs each frame's boxes and its sensors' visibility labels; returns (box sets, boxes, visibility sets)."""
    import rerun as rr

    graph = reader.graph
    n_box_sets = n_boxes = n_visibility = 0
    for info in reader.frame_infos():
        _, labels = reader.labels(info.frame_index)
        boxes = labels.boxes
        _at(recording, info.timestamp_ns, info.frame_index)
        if boxes.frame in graph.frames:
            ids, classes = required_ids_and_classes(boxes) if len(boxes) else (np.zeros(0, str), np.zeros(0, str))
            class_rgb = [tuple(int(255 * c) for c in CLASS_COLORS.get(str(k), OTHER_CLASS_COLOR)) for k in classes]
            recording.log(f"{entity_path(graph, boxes.frame)}/labels", rr.Boxes3D(
                centers=boxes.center, half_sizes=boxes.size_lwh / 2,
                quaternions=[rr.Quaternion(xyzw=q) for q in boxes.quat_wxyz[:, [1, 2, 3, 0]]],
                labels=[f"{k} {i}" for k, i in zip(classes.tolist(), ids.tolist(), strict=True)], colors=class_rgb))
            n_box_sets += 1
            n_boxes += len(boxes)
        for sensor in sorted(reader.sensors()):
            visibility = reader.visibility(sensor, info.frame_index)
            if visibility is None or sensor not in graph.frames:
                continue
            recording.log(f"{entity_path(graph, sensor)}/visibility", rr.AnyValues(
                object_id=[str(i) for i in visibility.object_ids], in_fov=np.asarray(visibility.in_fov, bool),
                n_points=np.asarray(visibility.n_points, np.int64), occlusion=np.asarray(visibility.occlusion, np.int64)))
            n_visibility += 1
    return n_box_sets, n_boxes, n_visibility


def _media(fmt: str) -> str:
    return "jpeg" if fmt.lower() in ("jpg", "jpeg") else fmt.lower()


def write_rerun(root: str | Path, scene: str | None, save: Path | None) -> tuple[str, RerunCounts]:
    """Logs a scene (default: the first) to ``save`` (an .rrd file, whole or not at all) or a spawned viewer.

    Returns:
        The scene's name and what was logged.
    """
    from avdata.errors import OutputError

    rr = import_rerun()
    ds = DatasetReader(root, verify=True)
    scene = (ds.scenes[0] if ds.scenes else "") if scene is None else scene  # not `scene or`: --scene '' is refused
    recording = rr.RecordingStream("avdata", recording_id=f"{Path(root).name}/{scene}")
    if save is None:
        if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            # The spawned viewer would die at once and every message be dropped after seconds of retries.
            raise InputError("view --rerun: expected a display for the Rerun viewer (DISPLAY and WAYLAND_DISPLAY are "
                             "unset); write a recording with --save OUT.rrd and open it with 'rerun OUT.rrd' elsewhere")
        recording.spawn()
        return scene, log_scene(ds, scene, recording)
    save = Path(save)
    if save.suffix != ".rrd":
        raise InputError(f"{save}: expected an .rrd file, got suffix {save.suffix!r}")
    if save.is_dir():
        raise OutputError(f"{save}: cannot write this file (a folder is in its place)")
    tmp = temporary_path(save)
    try:
        save.parent.mkdir(parents=True, exist_ok=True)
        recording.save(tmp)
        counts = log_scene(ds, scene, recording)
        recording.flush()
        recording.disconnect()
        tmp.replace(save)
    except OSError as error:
        raise OutputError(f"{save}: cannot write this file ({error.strerror or error})") from None
    finally:
        tmp.unlink(missing_ok=True)
    return scene, counts
