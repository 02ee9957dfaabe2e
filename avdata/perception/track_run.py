"""``avdata track``'s scene task and output writers: one tracker per scene of a unified dataset.

A scene's detections (already keyed by the dataset's frames, :func:`~avdata.perception.detection_files.
match_to_dataset`) are tracked frame by frame over every frame of the scene, in ``world`` (each frame's
detections moved through the scene's frame tree at that frame's time and made upright about +z) or, where
the scene has no poses, in the sensor frame (KITTI: ``ego/cam0_flu``). The tracks are written as

* ``kitti``: ``OUT/<seq>.txt`` in KITTI's tracking result layout, boxes in camera 0 of each frame, with the 2D
  box, alpha and raw score of the detection that last updated the track (as AB3DMOT writes them);
* ``nuscenes``: ``OUT/tracking_results.json``, a nuScenes tracking submission (boxes in ``world``, the
  dataset's global frame; sample tokens as ``avdata export nuscenes`` names the frames);
* ``unified``: ``OUT/tracks.parquet``, the tracks table of ``avdata eval tracking --protocol avdata``.

The table formats keep one part per scene in ``OUT/.avdata-track/<scene>.json`` (what makes them resumable)
and are assembled from the parts of the run's scenes at its end.

OUT may be a local folder or a prefix in an object store (``s3://``, ``gs://``); every file goes through its
:class:`~avdata.executors.folder.OutputFolder`, so a sequence file or part appears whole (a temporary key, a
server-side copy) and the table is written after every part.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from avdata.errors import InputError
from avdata.executors.folder import OutputFolder
from avdata.executors.scenes import WRITTEN, SceneOutcome
from avdata.frames import Boxes3D
from avdata.perception.detection_files import (
    CAMERA_FRAME,
    FLU_T_CAM0,
    NON_KITTI_FORMATS,
    UPRIGHT_FRAME,
    camera_boxes,
    upright,
)
from avdata.perception.detections import Detections
from avdata.perception.tracker import TrackerConfig, Tracks, checked_tracks, load_tracker
from avdata.sources.kitti.detections import KittiDetectionRows, format_kitti_tracking_lines

__all__ = ["NUSCENES_FILE", "NUSCENES_TRACKING_NAMES", "OUTPUT_FORMATS", "PARTS_DIR", "UNIFIED_FILE", "TrackTask",
           "default_output_format", "scene_output", "track_scene", "write_table"]

OUTPUT_FORMATS = ("kitti", "nuscenes", "unified")
#: Folder of the per-scene parts of the table formats, inside OUT.
PARTS_DIR = ".avdata-track"
NUSCENES_FILE = "tracking_results.json"
UNIFIED_FILE = "tracks.parquet"
#: unified class -> nuScenes tracking name (the devkit's 7 tracking classes; tracks of other classes are not written).
NUSCENES_TRACKING_NAMES = {"car": "car", "truck": "truck", "bus": "bus", "trailer": "trailer", "motorcycle": "motorcycle",
                           "bicycle": "bicycle", "cyclist": "bicycle", "pedestrian": "pedestrian"}
#: KITTI extras a KITTI result line needs from the detection that updated a track.
_KITTI_EXTRAS = ("box2d_px", "alpha_rad", "score_raw", "kitti_class")


def default_output_format(source: str, detection_format: str) -> str:
    """The native tracking format of a dataset converted from ``source`` (KITTI's needs KITTI-style detections)."""
    if source.startswith("kitti"):
        return "kitti" if detection_format not in NON_KITTI_FORMATS else "unified"
    return "nuscenes" if source in ("nuscenes", "lyft") else "unified"


def scene_output(scene: str, kitti_sequence: str, output_format: str) -> str:
    """The file (relative to OUT) that holds one scene's tracks (its existence marks the scene complete)."""
    if output_format == "kitti":
        return f"{kitti_sequence}.txt"
    return f"{PARTS_DIR}/{scene}.json"


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackTask:
    """One scene to track.

    Attributes:
        dataset: the unified dataset root.
        scene: the dataset scene.
        frames: dataset frame index -> that frame's detections (any frame of the dataset's tree).
        tracker: ``kalman`` or ``MODULE:CALLABLE``.
        config: the Kalman tracker's settings.
        world: track in ``world`` (False: in the detections' sensor frame, made upright).
        output_format: one of :data:`OUTPUT_FORMATS`.
        out: OUT, a path or a store URI.
        name: the scene's output file relative to OUT (:func:`scene_output`).
    """

    dataset: str
    scene: str
    frames: dict[int, Detections]
    tracker: str
    config: TrackerConfig
    world: bool
    output_format: str
    out: str
    name: str


def track_scene(task: TrackTask) -> SceneOutcome:
    """Tracks one scene over all its frames and writes its output file atomically."""
    from avdata.schema.dataset import DatasetReader

    reader = DatasetReader(task.dataset, verify=True)
    frames = reader.frames().select(["scene", "frame_index", "timestamp_ns"]).to_pydict()
    times = sorted((int(f), int(t)) for s, f, t in zip(frames["scene"], frames["frame_index"], frames["timestamp_ns"],
                                                       strict=True) if s == task.scene)
    graph = reader.scene(task.scene).graph
    tracker = load_tracker(task.tracker, "--tracker", task.config)
    first = next(iter(task.frames.values()), None)
    # A frame without detections is the files' empty selection: the same frame and extras as every other frame.
    none = first.select(np.zeros(0, np.int64)) if first is not None else Detections.empty("world", 0)
    records: list[Any] = []
    for frame_index, time_ns in times:
        detections = replace(task.frames.get(frame_index, none), timestamp_ns=time_ns)
        if task.world:
            world = detections.to("world", graph.lookup("world", detections.boxes.frame, time_ns))
            tracked = replace(world, boxes=_upright(world.boxes))
        elif detections.boxes.frame == CAMERA_FRAME:
            tracked = upright(detections)
        else:
            tracked = detections
        tracks = checked_tracks(tracker(tracked), f"--tracker {task.tracker}")
        if len(tracks.boxes) and tracks.boxes.frame != tracked.boxes.frame:
            raise InputError(f"--tracker {task.tracker}: expected tracks in {tracked.boxes.frame!r}, "
                             f"got {tracks.boxes.frame!r}")
        records += _records(task, tracks, frame_index, time_ns, graph)
    text = ("".join(line + "\n" for line in records) if task.output_format == "kitti"
            else json.dumps(records, separators=(",", ":")) + "\n")
    OutputFolder.of(task.out).write(task.name, text.encode())
    n_boxes = sum(len(r["tracks"]) for r in records) if task.output_format == "nuscenes" else len(records)
    return SceneOutcome(scene=task.scene, status=WRITTEN, problems=[], data=n_boxes)


def _upright(boxes: Boxes3D) -> Boxes3D:
    """``boxes`` turned upright about +z of their frame (heading kept; a pose's pitch and roll tilt them)."""
    return Boxes3D.from_yaw(boxes.center, boxes.size_lwh, boxes.yaw(), boxes.frame, ids=boxes.ids,
                            classes=boxes.classes, velocity=boxes.velocity)


def _in(boxes: Boxes3D, frame: str, graph: Any, time_ns: int) -> Boxes3D:
    """``boxes`` (in ``world``, ``ego/cam0_flu`` or a frame of the tree) expressed in ``frame`` at ``time_ns``."""
    if boxes.frame == frame:
        return boxes
    if boxes.frame == UPRIGHT_FRAME:
        boxes = boxes.transform(FLU_T_CAM0.inverse(), CAMERA_FRAME)
    return boxes.transform(graph.lookup(frame, boxes.frame, time_ns), frame)


def _records(task: TrackTask, tracks: Tracks, frame_index: int, time_ns: int, graph: Any) -> list[Any]:
    n = len(tracks.boxes)
    if not n:
        return [{"frame_index": frame_index, "tracks": []}] if task.output_format == "nuscenes" else []
    ids = np.asarray(tracks.boxes.ids).astype(str)
    if task.output_format == "kitti":
        if missing := [key for key in _KITTI_EXTRAS if key not in tracks.extras]:
            raise InputError(f"--output-format kitti: expected detections with KITTI extras {list(_KITTI_EXTRAS)}, "
                             f"got none of {missing} (read a KITTI-style detection format)")
        flu = tracks.boxes
        if flu.frame != UPRIGHT_FRAME:  # tracked in world: camera 0 of this frame, upright in it
            flu = _upright(_in(flu, CAMERA_FRAME, graph, time_ns).transform(FLU_T_CAM0, UPRIGHT_FRAME))
        hwl, bottom, rotation_y = camera_boxes(flu)
        raw = np.asarray(tracks.extras["score_raw"], dtype=np.float64)
        rows = KittiDetectionRows(
            scene=np.full(n, task.scene), frame=np.full(n, frame_index), kitti_class=tracks.extras["kitti_class"],
            track_id=ids.astype(np.int64), box2d_px=tracks.extras["box2d_px"], hwl_m=hwl, bottom_cam0_m=bottom,
            rotation_y_rad=rotation_y, alpha_rad=tracks.extras["alpha_rad"],
            score_raw=np.where(np.isnan(raw), tracks.scores, raw))
        return format_kitti_tracking_lines(rows)
    world = _upright(_in(tracks.boxes, "world", graph, time_ns))
    classes = np.asarray(world.classes).astype(str)
    velocity = world.velocity if world.velocity is not None else np.zeros((n, 3))
    if task.output_format == "unified":
        yaw = world.yaw()
        return [{"frame_index": frame_index, "object_id": ids[i], "class": classes[i],
                 "x_world_m": float(world.center[i, 0]), "y_world_m": float(world.center[i, 1]),
                 "z_world_m": float(world.center[i, 2]), "length_m": float(world.size_lwh[i, 0]),
                 "width_m": float(world.size_lwh[i, 1]), "height_m": float(world.size_lwh[i, 2]),
                 "yaw_world_rad": float(yaw[i]), "score": float(tracks.scores[i])} for i in range(n)]
    center, wlh, quat = world.to_nuscenes()
    boxes = [{"translation": center[i].tolist(), "size": wlh[i].tolist(), "rotation": quat[i].tolist(),
              "velocity": velocity[i, :2].tolist(), "tracking_id": ids[i],
              "tracking_name": NUSCENES_TRACKING_NAMES[classes[i]], "tracking_score": float(tracks.scores[i])}
             for i in range(n) if classes[i] in NUSCENES_TRACKING_NAMES]
    return [{"frame_index": frame_index, "tracks": boxes}]


def write_table(out: OutputFolder, output_format: str, scenes: list[str]) -> str:
    """Assembles the parts of ``scenes`` into ``OUT/tracks.parquet`` or ``OUT/tracking_results.json``; its path."""
    parts = {scene: json.loads(_part(out, scene)) for scene in scenes}
    if output_format == "unified":
        import pyarrow as pa
        import pyarrow.parquet as pq

        from avdata.eval.unified import DETECTION_COLUMNS

        rows = [{"scene": scene} | row for scene, records in parts.items() for row in records]
        names = (*DETECTION_COLUMNS, "score")
        schema = pa.schema([(name, pa.string() if name in ("scene", "object_id", "class") else
                             pa.int64() if name == "frame_index" else pa.float64()) for name in names])
        sink = pa.BufferOutputStream()
        pq.write_table(pa.table({name: [row[name] for row in rows] for name in names}, schema=schema), sink)
        out.write(UNIFIED_FILE, sink.getvalue().to_pybytes())
        return f"{out}/{UNIFIED_FILE}"
    from avdata.exporters.nuscenes import sample_token

    results = {sample_token(scene, record["frame_index"]): [{"sample_token": sample_token(scene, record["frame_index"]),
                                                              **box} for box in record["tracks"]]
               for scene, records in parts.items() for record in records}
    # The devkit requires these keys; what the detector used is not known here.
    meta = {"use_camera": False, "use_lidar": False, "use_radar": False, "use_map": False, "use_external": False}
    out.write(NUSCENES_FILE, (json.dumps({"meta": meta, "results": results}, sort_keys=True) + "\n").encode())
    return f"{out}/{NUSCENES_FILE}"


def _part(out: OutputFolder, scene: str) -> bytes:
    found = out.read_bytes(f"{PARTS_DIR}/{scene}.json")
    if found is None:
        raise InputError(f"{out}/{PARTS_DIR}/{scene}.json: expected the tracks of scene {scene}, got no file (rerun)")
    return found
