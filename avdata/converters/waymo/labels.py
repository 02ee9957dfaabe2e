"""Waymo labels: 3D lidar boxes -> object labels, projected lidar boxes -> each camera's 2D boxes."""

from __future__ import annotations

from typing import Any

import numpy as np

from avdata.converters.waymo.segment import (
    CAMERA_KEY,
    OBJECT_KEY,
    Segment,
    as_int,
    camera_frame,
    column_numbers,
    file_rows,
    float_column,
)
from avdata.frames import Boxes3D
from avdata.schema import ObjectLabels, VisibilityLabels
from avdata.schema.limits import MAX_ANGLE_RAD, MAX_BOX_SIZE_M, MAX_CAMERA_VALUE_PX, MAX_COORDINATE_M, MAX_SPEED_MPS
from avdata.sources.waymo import BOX_TYPES, CAMERA_NAMES, CLASS_MAP
from avdata.sources.waymo.components import TIME_KEY

#: An object accelerating faster than this (100 g) is damage, not data.
MAX_ACCELERATION_MPS2 = 1_000.0


def object_labels(seg: Segment, frame_of_time: dict[int, int]) -> list[ObjectLabels] | None:
    """Each frame's object labels (frame order), or None when lidar_box is missing or unreadable (reported).

    A box that is out of the scene writer's limits, of an unknown type, without an id or given twice in one frame
    is reported and left out; the frame keeps its other boxes.
    """
    fields = ["box.center.x", "box.center.y", "box.center.z", "box.size.x", "box.size.y", "box.size.z",
              "box.heading", "type", "num_lidar_points_in_box", "num_top_lidar_points_in_box"]
    optional = (*(f"{group}.{axis}" for group in ("speed", "acceleration") for axis in "xyz"),
                "difficulty_level.detection", "difficulty_level.tracking")
    table = seg.read("lidar_box", fields, (TIME_KEY, OBJECT_KEY), optional)
    if table is None:
        return None
    file = seg.files["lidar_box"]
    n = table.num_rows
    col = file.column
    times = column_numbers(table.column(TIME_KEY))
    known = np.asarray([int(t) in frame_of_time for t in times.tolist()], dtype=bool)
    unknown = ~known & ~np.isin(times, list(seg.skipped_us))  # a skipped frame's boxes go with it
    for t in sorted(set(times[unknown].tolist()))[:1]:
        seg.report.error(file.path, f"{TIME_KEY}: expected times of vehicle_pose, got {t} "
                                     f"({int(unknown.sum())} boxes skipped)")
    center = np.stack([float_column(table, col(f"box.center.{a}"), n) for a in "xyz"], axis=1)
    size = np.stack([float_column(table, col(f"box.size.{a}"), n) for a in "xyz"], axis=1)
    heading = float_column(table, col("box.heading"), n)
    speed = np.stack([float_column(table, col(f"speed.{a}"), n) for a in "xyz"], axis=1)
    accel = np.stack([float_column(table, col(f"acceleration.{a}"), n) for a in "xyz"], axis=1)
    types = column_numbers(table.column(col("type")))
    id_column = table.column(OBJECT_KEY)
    null_id = np.asarray(id_column.is_null(), dtype=bool)
    ids = np.asarray(id_column.fill_null("").to_pylist(), dtype=str)
    for k in np.flatnonzero(null_id & known).tolist():
        seg.report.error(file.path, f"row {file_rows(table)[k]} at {int(times[k])}: {OBJECT_KEY}: expected an object "
                                     "id, got null; "
                                     "that box is skipped")
    # The scene writer's limits: a centre of 1e30 m refused there cost the segment.
    # A heading of 1e308 rad (any turn) and a speed or acceleration of 1e308 are damage: the speed was refused by
    # the scene writer with the whole frame, the others written. Unknown (NaN) motion is kept.
    with np.errstate(invalid="ignore"):
        motion_ok = np.all(np.isnan(speed) | (np.abs(speed) <= MAX_SPEED_MPS), axis=1) \
            & np.all(np.isnan(accel) | (np.abs(accel) <= MAX_ACCELERATION_MPS2), axis=1)
    bad = ~(np.all(np.abs(center) <= MAX_COORDINATE_M, axis=1) & np.all((size >= 0) & (size <= MAX_BOX_SIZE_M), axis=1)
            & (np.abs(heading) <= MAX_ANGLE_RAD) & motion_ok)
    bad |= ~np.isin(types, list(BOX_TYPES))
    for k in np.flatnonzero(bad & known & ~null_id)[:5]:
        seg.report.error(file.path, f"object {ids[k]} at {times[k]}: expected a box within {MAX_COORDINATE_M:g} m of "
                                     f"size 0 .. {MAX_BOX_SIZE_M:g} m, heading within +-{MAX_ANGLE_RAD:.4g} rad, speed within "
                                     f"{MAX_SPEED_MPS:g} m/s, acceleration within {MAX_ACCELERATION_MPS2:g} m/s2 and a "
                                     f"known type, got centre {center[k].tolist()} size {size[k].tolist()} heading "
                                     f"{heading[k]} speed {speed[k].tolist()} acceleration {accel[k].tolist()} type "
                                     f"{types[k]}; that box is skipped")
    bad |= null_id
    # An object given twice in one frame: which row is right is unknown, so neither is kept.
    pairs = np.asarray([f"{int(t)}/{i}" for t, i in zip(times.tolist(), ids.tolist(), strict=True)])
    unique_pairs, counts = np.unique(pairs[~null_id], return_counts=True)
    repeated = np.isin(pairs, unique_pairs[counts > 1]) & ~null_id
    for pair in unique_pairs[counts > 1].tolist():
        time_text, object_id = pair.split("/", 1)
        seg.report.error(file.path, f"object {object_id} at {time_text}: expected one box per frame, got "
                                     f"{int(np.sum(pairs == pair))}; those boxes are skipped")
    keep = known & ~bad & ~repeated
    source = np.asarray([BOX_TYPES[int(t)] if t in BOX_TYPES else "" for t in types.tolist()])  # a null type: NaN
    box_extras = {name: float_column(table, col(name), n) for name in ("num_lidar_points_in_box", "num_top_lidar_points_in_box")}
    # An unset difficulty is UNKNOWN (0), the proto default that Waymo's metrics count at both levels.
    box_extras["detection_difficulty_level"] = np.nan_to_num(float_column(table, col("difficulty_level.detection"), n), nan=0.0)
    box_extras["tracking_difficulty_level"] = np.nan_to_num(float_column(table, col("difficulty_level.tracking"), n), nan=0.0)
    frames = np.asarray([frame_of_time.get(int(t), -1) for t in times.tolist()])
    labels = []
    for i in range(len(frame_of_time)):
        rows = np.flatnonzero(keep & (frames == i))
        if not len(rows):
            labels.append(ObjectLabels.empty("ego"))
            continue
        boxes = Boxes3D.from_waymo(center[rows], size[rows], heading[rows], "ego", ids=ids[rows],
                                   classes=np.asarray([CLASS_MAP[s] for s in source[rows]]), velocity=speed[rows])
        extras = [{name: float(values[k]) for name, values in box_extras.items()} for k in rows.tolist()]
        labels.append(ObjectLabels(boxes=boxes, source_classes=source[rows], acceleration=accel[rows], extras=extras))
    return labels


def projected_boxes(seg: Segment, scene: Any, frame_of_time: dict[int, int], boxed_ids: dict[int, set[str]] | None,
                     cameras_written: set[int]) -> None:
    """Each written camera's 2D boxes of the objects that have a 3D box in that frame.

    A camera whose calibration was refused takes its visibility labels with it (reported with the calibration),
    and a 2D box of an object without a 3D box is left out with a warning. ``boxed_ids`` (frame time in µs ->
    ids of its 3D boxes) is None when lidar_box is missing or unreadable (reported): no 2D box is written.
    """
    fields = ["box.center.x", "box.center.y", "box.size.x", "box.size.y", "type"]
    table = seg.read("projected_lidar_box", fields, (TIME_KEY, CAMERA_KEY, OBJECT_KEY))
    if table is None or boxed_ids is None:
        return
    file = seg.files["projected_lidar_box"]
    n = table.num_rows
    times = column_numbers(table.column(TIME_KEY))
    cameras = as_int(table.column(CAMERA_KEY))
    ids = np.asarray(table.column(OBJECT_KEY).to_pylist(), dtype=str)
    cx, cy, sx, sy = (float_column(table, file.column(f), n) for f in fields[:4])
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow (inf) or NaN fails the same test
        xyxy = np.stack([cx - sx / 2, cy - sy / 2, cx + sx / 2, cy + sy / 2], axis=1)
        bad = ~(np.all(np.abs(xyxy) <= MAX_CAMERA_VALUE_PX, axis=1) & (sx >= 0) & (sy >= 0))
    if bad.any():  # one line for all of them; each costs only its own 2D box
        first = int(np.flatnonzero(bad)[0])
        seg.report.error(file.path, f"box.center / box.size: expected corners within {MAX_CAMERA_VALUE_PX:g} px and "
                                     f"sizes >= 0, got {int(bad.sum())} row(s), first row {file_rows(table)[first]} "
                                     f"(object {ids[first]}): center ({cx[first]}, {cy[first]}), "
                                     f"size ({sx[first]}, {sy[first]}); those 2D boxes are left out")
        times, cameras, ids, xyxy = times[~bad], cameras[~bad], ids[~bad], xyxy[~bad]
    for time_us in sorted(set(times.tolist())):
        if int(time_us) not in frame_of_time:
            if int(time_us) not in seg.skipped_us:
                seg.report.error(file.path, f"{TIME_KEY}: expected a time of vehicle_pose, got {time_us}")
            continue
        in_frame = times == time_us
        orphans = in_frame & ~np.isin(ids, list(boxed_ids[int(time_us)]))
        if orphans.any():
            seg.report.warn(file.path, f"frame {int(time_us)}: {OBJECT_KEY}: expected objects with a 3D box, got "
                                        f"{sorted(set(ids[orphans].tolist()))[:5]} ({int(orphans.sum())} 2D boxes); "
                                        "those 2D boxes are left out")
        for camera in sorted(set(cameras[in_frame].tolist())):
            if camera not in CAMERA_NAMES:
                seg.report.error(file.path, f"{CAMERA_KEY}: expected one of {sorted(CAMERA_NAMES)}, got {camera}")
                continue
            if camera not in cameras_written:  # its calibration was refused (reported there)
                continue
            rows = np.flatnonzero(in_frame & (cameras == camera) & ~orphans)
            visibility = VisibilityLabels(object_ids=ids[rows], in_fov=np.ones(len(rows), dtype=bool), box2d_xyxy=xyxy[rows])
            scene.add_visibility(camera_frame(camera), frame_of_time[int(time_us)], int(time_us) * 1000, visibility)
