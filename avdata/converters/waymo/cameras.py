"""Waymo cameras: calibrations, JPEG images, and the timing and poses stored with each image."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from avdata.converters.waymo.segment import CAMERA_KEY, Segment, as_int, camera_frame, is_time_s, reported_duplicates
from avdata.errors import InputError
from avdata.frames import XFWD_T_OPTICAL
from avdata.sources.jpeg import jpeg_problem
from avdata.sources.waymo import CAMERA_NAMES
from avdata.sources.waymo.components import TIME_KEY, iter_component

#: Camera calibration fields that must be positive (focal lengths in pixels, image size).
_POSITIVE_CALIBRATION = ("intrinsic.f_u", "intrinsic.f_v", "width", "height")



def camera_calibrations(seg: Segment, scene: Any, first_time_ns: int) -> dict[int, dict[str, Any]]:
    """Camera name -> its calibration row, each camera's sensor, ``/tf_static`` entry and intrinsics written to ``scene``.

    A row that is not usable (a missing or non-finite value, a non-positive focal length or size, an extrinsic that
    is not a rigid transform) costs that camera, reported once (:attr:`Segment.reported_cameras`).
    """
    intrinsic = [f"intrinsic.{n}" for n in ("f_u", "f_v", "c_u", "c_v", "k1", "k2", "p1", "p2", "k3")]
    fields = [*intrinsic, "extrinsic.transform", "width", "height", "rolling_shutter_direction"]
    table = seg.read("camera_calibration", fields, (CAMERA_KEY,))
    if table is None:
        return {}
    file = seg.files["camera_calibration"]
    rows = table.to_pylist()
    result = {}
    names = as_int(table.column(CAMERA_KEY))
    twice = reported_duplicates(seg.report, file.path, names, CAMERA_KEY, "that camera is not converted")
    seg.reported_cameras |= twice
    for row, camera in zip(rows, names.tolist(), strict=True):
        if camera in twice:
            continue
        if camera not in CAMERA_NAMES:
            seg.report.error(file.path, f"{CAMERA_KEY}: expected one of {sorted(CAMERA_NAMES)}, got {camera}")
            continue
        value = {name: row[file.column(name)] for name in fields}
        empty = [name for name, v in value.items() if v is None or (isinstance(v, list) and (len(v) != 16 or None in v))
                 or (name in intrinsic and not math.isfinite(v)) or (name in _POSITIVE_CALIBRATION and v <= 0)]
        if empty:
            seg.report.error(file.path, f"camera {camera}: expected finite numbers (positive focal length and size) "
                                         f"in {empty}, got {[value[n] for n in empty]}")
            seg.reported_cameras.add(camera)
            continue
        frame = camera_frame(camera)
        try:
            vehicle_T_camera = seg.transform(np.asarray(value["extrinsic.transform"], dtype=np.float64).reshape(4, 4),
                                               file.path, f"extrinsic of camera {camera}")
        except InputError as error:
            seg.report.error(file.path, str(error).removeprefix(f"{file.path}: "))
            seg.reported_cameras.add(camera)
            continue
        fu, fv, cu, cv, k1, k2, p1, p2, k3 = (float(value[n]) for n in intrinsic)
        scene.add_sensor(frame, "camera", camera_name=CAMERA_NAMES[camera],
                         rolling_shutter_direction=int(value["rolling_shutter_direction"]),
                         width=int(value["width"]), height=int(value["height"]))
        scene.add_static_transform("ego", frame, vehicle_T_camera @ XFWD_T_OPTICAL)
        scene.add_camera_calibration(frame, first_time_ns, np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]]),
                                     int(value["width"]), int(value["height"]), D=np.array([k1, k2, p1, p2, k3]))
        result[camera] = value
    return result


def camera_images(seg: Segment, scene: Any, cameras: dict[int, dict[str, Any]], frame_of_time: dict[int, int],
                   sensor_times: list[dict[str, int]]) -> None:
    """Writes each frame's JPEG images of the calibrated cameras, stamped with the image's pose time."""
    file = seg.files.get("camera_image")
    # Reported once already (by _camera_poses, _camera_calibrations): not again for every image.
    if file is None or {"camera_image", "camera_calibration"} & seg.unreadable:
        return
    fields = ["image", "pose_timestamp"]
    seen: set[tuple[int, int]] = set()
    try:
        for batch in iter_component(file, [TIME_KEY, CAMERA_KEY, *(file.column(f) for f in fields)]):
            for row in batch.to_pylist():
                if row[TIME_KEY] is None or row[CAMERA_KEY] is None:  # reported by camera_poses
                    continue
                time_us, camera = int(row[TIME_KEY]), int(row[CAMERA_KEY])
                where = f"frame {time_us} camera {camera}"
                if (time_us, camera) in seen:  # the first row was written; which one is right is unknown
                    seg.report.error(file.path, f"{where}: expected one image per frame and camera, got another; "
                                                 "the later row is skipped")
                    continue
                seen.add((time_us, camera))
                if time_us not in frame_of_time:
                    if time_us not in seg.skipped_us:
                        seg.report.error(file.path, f"{where}: {TIME_KEY}: expected a time of vehicle_pose, got {time_us}")
                    continue
                if camera in seg.reported_cameras:  # its calibration error was reported
                    continue
                if camera not in cameras:
                    seg.report.error(file.path, f"{where}: {CAMERA_KEY}: expected a calibrated camera "
                                                 f"{sorted(cameras)}, got {camera}")
                    continue
                pose_s = row[file.column("pose_timestamp")]
                if not is_time_s(pose_s):
                    seg.report.error(file.path, f"{where}: pose_timestamp: expected seconds in 0 .. 9.2e9 "
                                                 f"(int64 nanoseconds), got {pose_s}")
                    continue
                time_ns = round(pose_s * 1e9)
                if time_ns in seg.unposed_ns:  # its pose was refused (reported): no pose to place it by
                    continue
                image = row[file.column("image")]
                problem, _ = jpeg_problem(image) if image is not None else ("expected JPEG bytes, got null", None)
                if problem is not None:
                    seg.report.error(file.path, f"{where}: image: {problem}")
                    continue
                frame = camera_frame(camera)
                scene.add_image(frame, time_ns, image, "jpeg")
                sensor_times[frame_of_time[time_us]][frame] = time_ns
    except InputError as error:
        seg.report.error(file.path, str(error).removeprefix(f"{file.path}: "))


def camera_poses(seg: Segment) -> tuple[dict[str, list[dict[str, float]]], dict[int, np.ndarray]]:
    """Camera timing and poses, images left unread.

    Returns (camera frame -> per image its frame time, pose time and rolling-shutter parameters;
    image time in ns -> the SDC pose ``world_T_vehicle`` stored with the image).
    """
    fields = ["pose_timestamp", "rolling_shutter_params.shutter", "rolling_shutter_params.camera_trigger_time",
              "rolling_shutter_params.camera_readout_done_time"]
    table = seg.read("camera_image", [*fields, "pose.transform"], (TIME_KEY, CAMERA_KEY))
    if table is None:
        return {}, {}
    file = seg.files["camera_image"]
    shutter: dict[str, list[dict[str, float]]] = {}
    poses: dict[int, np.ndarray] = {}
    for row, camera in zip(table.to_pylist(), as_int(table.column(CAMERA_KEY)).tolist(), strict=True):
        pose_s = row[file.column("pose_timestamp")]
        if camera not in CAMERA_NAMES or not is_time_s(pose_s):
            continue  # reported with the image
        entry = {"frame_timestamp_us": row[TIME_KEY]}
        entry.update({name.rpartition(".")[2] + "_s": row[file.column(name)] for name in fields})
        shutter.setdefault(camera_frame(camera), []).append(entry)
        pose = row[file.column("pose.transform")]
        if pose is None or len(pose) != 16 or any(v is None for v in pose):
            seg.report.error(file.path, f"frame {row[TIME_KEY]} camera {camera}: pose.transform: expected 16 numbers, "
                                         f"got {pose}; that image is skipped")
            seg.unposed_ns.add(round(pose_s * 1e9))
            continue
        poses[round(pose_s * 1e9)] = np.asarray(pose, dtype=np.float64).reshape(4, 4)
    return shutter, poses
