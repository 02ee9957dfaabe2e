"""The Parquet index, derived from the scene MCAP files (which stay the source of truth).

``index/frames.parquet``      one row per (scene, frame): time, annotated, sensor times, ego pose in world
``index/objects.parquet``     one row per (scene, frame, object): classes, box in world and in ego, velocity
``index/visibility.parquet``  one row per (scene, frame, sensor, object): what that sensor could see

Column names carry frames and units (``x_world_m``, ``yaw_ego_rad``, ``timestamp_ns``). Boxes are
moved between frames only through each scene's FrameGraph.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from avdata.errors import AvdataError
from avdata.frames import Boxes3D, Transform
from avdata.schema.scene_reader import SceneReader

INDEX_TABLES = ("frames", "objects", "visibility")

FRAMES_SCHEMA = pa.schema(
    [
        ("scene", pa.string()),
        ("frame_index", pa.int32()),
        ("timestamp_ns", pa.int64()),
        ("annotated", pa.bool_()),
        ("split", pa.string()),
        ("sensor_timestamps_ns", pa.map_(pa.string(), pa.int64())),
        ("ego_frame", pa.string()),
        ("world_T_ego_x_m", pa.float64()),
        ("world_T_ego_y_m", pa.float64()),
        ("world_T_ego_z_m", pa.float64()),
        ("world_T_ego_qw", pa.float64()),
        ("world_T_ego_qx", pa.float64()),
        ("world_T_ego_qy", pa.float64()),
        ("world_T_ego_qz", pa.float64()),
        ("n_objects", pa.int32()),
    ]
)

_BOX_COLUMNS = [
    f"{axis}_{frame}_m" for frame in ("world", "ego") for axis in ("x", "y", "z")
] + [f"q{c}_{frame}" for frame in ("world", "ego") for c in "wxyz"]

OBJECTS_SCHEMA = pa.schema(
    [
        ("scene", pa.string()),
        ("frame_index", pa.int32()),
        ("timestamp_ns", pa.int64()),
        ("object_id", pa.string()),
        ("class", pa.string()),
        ("source_class", pa.string()),
        ("length_m", pa.float64()),
        ("width_m", pa.float64()),
        ("height_m", pa.float64()),
    ]
    + [(name, pa.float64()) for name in _BOX_COLUMNS]
    + [
        ("yaw_world_rad", pa.float64()),
        ("yaw_ego_rad", pa.float64()),
        ("vx_world_mps", pa.float64()),
        ("vy_world_mps", pa.float64()),
        ("vz_world_mps", pa.float64()),
        ("vx_ego_mps", pa.float64()),
        ("vy_ego_mps", pa.float64()),
        ("vz_ego_mps", pa.float64()),
        ("attributes_json", pa.string()),
        ("extras_json", pa.string()),
    ]
)

VISIBILITY_SCHEMA = pa.schema(
    [
        ("scene", pa.string()),
        ("frame_index", pa.int32()),
        ("timestamp_ns", pa.int64()),
        ("sensor", pa.string()),
        ("object_id", pa.string()),
        ("in_fov", pa.bool_()),
        ("n_points", pa.int32()),
        ("visible_fraction", pa.float32()),
        ("occlusion", pa.int8()),
        ("truncation", pa.float32()),
        ("box2d_x0_px", pa.float32()),
        ("box2d_y0_px", pa.float32()),
        ("box2d_x1_px", pa.float32()),
        ("box2d_y1_px", pa.float32()),
        ("visible_pixel_fraction", pa.float32()),
        ("alpha_rad", pa.float32()),
    ]
)

SCHEMAS = {"frames": FRAMES_SCHEMA, "objects": OBJECTS_SCHEMA, "visibility": VISIBILITY_SCHEMA}


def scene_index(scene: SceneReader, split: str = "") -> dict[str, pa.Table]:
    """The three index tables of one scene, computed from its MCAP file."""
    graph = scene.graph
    ego = scene.ego_frame()
    frames: dict[str, list] = {field.name: [] for field in FRAMES_SCHEMA}
    objects: dict[str, list] = {field.name: [] for field in OBJECTS_SCHEMA}
    for info, labels in (scene.labels(i) for i in range(len(scene.times("/labels/objects")))):
        t = info.timestamp_ns
        world_T_ego = _lookup(graph, "world", ego, t)
        frames["scene"].append(scene.name)
        frames["frame_index"].append(info.frame_index)
        frames["timestamp_ns"].append(t)
        frames["annotated"].append(info.annotated)
        frames["split"].append(split)
        frames["sensor_timestamps_ns"].append(list(info.sensor_timestamps_ns.items()))
        frames["ego_frame"].append(ego)
        pose = (
            [np.nan] * 7
            if world_T_ego is None
            else world_T_ego.translation.tolist() + world_T_ego.quat_wxyz().tolist()
        )
        for name, value in zip(list(FRAMES_SCHEMA.names)[7:14], pose):
            frames[name].append(value)
        frames["n_objects"].append(len(labels))
        if not len(labels):
            continue
        boxes = labels.boxes
        n = len(boxes)
        world_T_labels = _lookup(graph, "world", boxes.frame, t)
        ego_T_labels = _lookup(graph, ego, boxes.frame, t)
        in_world = _moved(boxes, world_T_labels, "world")
        in_ego = _moved(boxes, ego_T_labels, ego or "ego")
        objects["scene"].extend([scene.name] * n)
        objects["frame_index"].extend([info.frame_index] * n)
        objects["timestamp_ns"].extend([t] * n)
        objects["object_id"].extend(boxes.ids.tolist())
        objects["class"].extend(boxes.classes.tolist())
        objects["source_class"].extend(labels.source_classes.tolist())
        for i, name in enumerate(("length_m", "width_m", "height_m")):
            objects[name].extend(boxes.size_lwh[:, i].tolist())
        for frame_name, moved in (("world", in_world), ("ego", in_ego)):
            for i, axis in enumerate("xyz"):
                objects[f"{axis}_{frame_name}_m"].extend(moved["center"][:, i].tolist())
            for i, c in enumerate("wxyz"):
                objects[f"q{c}_{frame_name}"].extend(moved["quat"][:, i].tolist())
            objects[f"yaw_{frame_name}_rad"].extend(moved["yaw"].tolist())
            for i, axis in enumerate("xyz"):
                objects[f"v{axis}_{frame_name}_mps"].extend(moved["velocity"][:, i].tolist())
        objects["attributes_json"].extend(
            [json.dumps(a, sort_keys=True) for a in labels.attributes] if labels.attributes else ["{}"] * n
        )
        objects["extras_json"].extend(
            [json.dumps(e, sort_keys=True) for e in labels.extras] if labels.extras else ["{}"] * n
        )
    visibility: dict[str, list] = {field.name: [] for field in VISIBILITY_SCHEMA}
    frame_times = dict(zip(frames["frame_index"], frames["timestamp_ns"]))
    for sensor, frame_index, _, vis in scene.iter_visibility():
        n = len(vis)
        visibility["scene"].extend([scene.name] * n)
        visibility["frame_index"].extend([frame_index] * n)
        visibility["timestamp_ns"].extend([frame_times.get(frame_index, -1)] * n)
        visibility["sensor"].extend([sensor] * n)
        visibility["object_id"].extend(vis.object_ids.tolist())
        visibility["in_fov"].extend(vis.in_fov.tolist())
        visibility["n_points"].extend(vis.n_points.tolist())
        visibility["visible_fraction"].extend(vis.visible_fraction.tolist())
        visibility["occlusion"].extend(vis.occlusion.tolist())
        visibility["truncation"].extend(vis.truncation.tolist())
        for i, name in enumerate(("box2d_x0_px", "box2d_y0_px", "box2d_x1_px", "box2d_y1_px")):
            visibility[name].extend(vis.box2d_xyxy[:, i].tolist())
        visibility["visible_pixel_fraction"].extend(vis.visible_pixel_fraction.tolist())
        visibility["alpha_rad"].extend(vis.alpha_rad.tolist())
    return {
        "frames": pa.table(frames, schema=FRAMES_SCHEMA),
        "objects": pa.table(objects, schema=OBJECTS_SCHEMA),
        "visibility": pa.table(visibility, schema=VISIBILITY_SCHEMA),
    }


def write_index(index_dir: Path, tables: dict[str, list[pa.Table]]) -> None:
    """Writes each table (concatenated over scenes) atomically: temp name, then rename."""
    index_dir.mkdir(parents=True, exist_ok=True)
    for name in INDEX_TABLES:
        parts = tables.get(name) or []
        table = pa.concat_tables(parts) if parts else SCHEMAS[name].empty_table()
        final = index_dir / f"{name}.parquet"
        tmp = index_dir / f"{name}.parquet.tmp"
        pq.write_table(table, tmp)
        os.replace(tmp, final)


def _lookup(graph, target: str | None, source: str, time_ns: int) -> Transform | None:
    if target is None or target not in graph.frames or source not in graph.frames:
        return None
    try:
        return graph.lookup(target, source, time_ns)
    except AvdataError:
        return None


def _moved(boxes: Boxes3D, target_T_labels: Transform | None, target: str) -> dict[str, np.ndarray]:
    n = len(boxes)
    if target_T_labels is None:
        nan3 = np.full((n, 3), np.nan)
        return {"center": nan3, "quat": np.full((n, 4), np.nan), "yaw": np.full(n, np.nan), "velocity": nan3}
    moved = boxes.transform(target_T_labels, target)
    velocity = moved.velocity if moved.velocity is not None else np.full((n, 3), np.nan)
    return {"center": moved.center, "quat": moved.quat_wxyz, "yaw": moved.yaw(), "velocity": velocity}
