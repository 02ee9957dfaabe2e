"""Builds a v2 component fixture from the real v1 frame with Waymo's own code, plus Waymo's points.

Run with ``.oracle-envs/waymo/bin/python waymo_v2_fixture.py TFRECORD OUT``. The real frame has no range
images, so range images (both returns) are made here for each of its 5 real laser calibrations, with a
per-pixel pose for the top lidar (a rolling sweep around the real vehicle pose), injected into the v1
Frame as Waymo stores them (zlib-compressed MatrixFloat) and extracted with ``v2.perception.compat_v1``
like every other component (compat_v1's lidar extractors fail on this protobuf version; the same
inflate + parse is done here into the same v2 dataclasses). Writes ``OUT/<component>/<context>.parquet`` and, per laser,
``OUT/points_<laser>.npz`` with Waymo's points: ``v2 = lidar_utils.convert_range_image_to_point_cloud``
(float32, as Waymo's own path runs) and ``f64 = range_image_utils.extract_point_cloud_from_range_image``
in float64, both returns, in ``tf.where`` (row-major) order. Prints JSON {context, lasers}.
"""

import json
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import tensorflow as tf
from waymo_open_dataset import dataset_pb2
from waymo_open_dataset.utils import range_image_utils, transform_utils
from waymo_open_dataset.v2.perception import base as v2_base
from waymo_open_dataset.v2.perception import context as v2_context
from waymo_open_dataset.v2.perception import lidar as v2_lidar
from waymo_open_dataset.v2.perception import pose as v2_pose
from waymo_open_dataset.v2.perception.compat_v1 import box, camera_image, context, interfaces, pose
from waymo_open_dataset.v2.perception.utils import lidar_utils

SHAPES = {1: (64, 2650), 2: (200, 600), 3: (200, 600), 4: (200, 600), 5: (200, 600)}


def roll_pitch_yaw(rotation: np.ndarray) -> np.ndarray:
    return np.array([np.arctan2(rotation[2, 1], rotation[2, 2]), -np.arcsin(rotation[2, 0]),
                     np.arctan2(rotation[1, 0], rotation[0, 0])])


def range_images(frame: dataset_pb2.Frame, rng: np.random.Generator) -> dict[int, list[np.ndarray | None]]:
    """laser name -> [return 1 (H, W, 4), return 2 (H, W, 4), top lidar pixel pose (H, W, 6) or None]."""
    world_T_vehicle = np.asarray(frame.pose.transform, dtype=np.float64).reshape(4, 4)
    rpy = roll_pitch_yaw(world_T_vehicle[:3, :3])
    result: dict[int, list[np.ndarray | None]] = {}
    for calibration in frame.context.laser_calibrations:
        height, width = SHAPES[calibration.name]
        result[calibration.name] = []
        for empty in (0.1, 0.7):
            image = np.zeros((height, width, 4), dtype=np.float32)
            image[..., 0] = rng.uniform(1.0, 75.0, (height, width)) * (rng.random((height, width)) > empty)
            image[..., 1] = rng.uniform(0.0, 1.5, (height, width))
            image[..., 2] = rng.uniform(0.0, 0.5, (height, width))
            image[..., 3] = rng.random((height, width)) < 0.02
            result[calibration.name].append(image)
        result[calibration.name].append(None)
        if calibration.name == 1:
            # The sweep takes 0.1 s; the car drives at ~10 m/s and turns a little while it does.
            dt = np.linspace(-0.05, 0.05, width)[None, :].repeat(height, 0)
            pixel = np.zeros((height, width, 6), dtype=np.float32)
            pixel[..., 0] = rpy[0] + 0.001 * dt
            pixel[..., 1] = rpy[1] - 0.002 * dt
            pixel[..., 2] = rpy[2] + 0.1 * dt
            pixel[..., 3:] = world_T_vehicle[:3, 3] + dt[..., None] * (world_T_vehicle[:3, :3] @ [10.0, 0.3, 0.0])
            result[calibration.name][2] = pixel
    return result


def write(out: Path, name: str, context_name: str, components: list) -> None:
    if not components:
        return
    table = pa.Table.from_pylist([c.to_flatten_dict() for c in components], schema=type(components[0]).schema())
    (out / name).mkdir(parents=True, exist_ok=True)
    pq.write_table(table, out / name / f"{context_name}.parquet")


def main() -> None:
    tfrecord, out = sys.argv[1], Path(sys.argv[2])
    data = next(iter(tf.data.TFRecordDataset(tfrecord))).numpy()
    frame = dataset_pb2.Frame.FromString(data)
    images = range_images(frame, np.random.default_rng(0))
    src = interfaces.FrameComponentSrc(frame=frame)
    name = frame.context.name
    write(out, "vehicle_pose", name, list(pose.VehiclePoseFrameExtractor()(src)))
    write(out, "stats", name, list(context.StatsComponentExtractor()(src)))
    write(out, "lidar_calibration", name, [c for cal in frame.context.laser_calibrations for c in
                                           context.LiDARCalibrationComponentExtractor()(
                                               interfaces.LiDARCalibrationComponentSrc(frame=frame, lidar_calibration=cal))])
    write(out, "camera_calibration", name, [c for cal in frame.context.camera_calibrations for c in
                                            context.CameraCalibrationComponentExtractor()(
                                                interfaces.CameraCalibrationComponentSrc(frame=frame, camera_calibration=cal))])
    write(out, "camera_image", name, [c for image in frame.images for c in camera_image.CameraImageComponentExtractor()(
        interfaces.CameraImageComponentSrc(frame=frame, camera_image=image))])
    # compat_v1's lidar extractors fail on this protobuf version (MatrixFloat.FromString(bytearray)): the
    # range images go straight into the same v2 dataclasses they would build (flattened values + shape).
    def key(laser: int) -> v2_base.LaserKey:
        return v2_base.LaserKey(segment_context_name=name, frame_timestamp_micros=frame.timestamp_micros, laser_name=laser)

    def as_v2(array: np.ndarray, cls: type) -> object:
        return cls(values=array.ravel().tolist(), shape=list(array.shape))

    write(out, "lidar", name, [v2_lidar.LiDARComponent(
        key=key(laser), range_image_return1=as_v2(ri1, v2_lidar.RangeImage), range_image_return2=as_v2(ri2, v2_lidar.RangeImage))
        for laser, (ri1, ri2, _) in images.items()])
    write(out, "lidar_pose", name, [
        v2_lidar.LiDARPoseComponent(key=key(laser), range_image_return1=as_v2(pixel, v2_lidar.PoseRangeImage))
        for laser, (_, _, pixel) in images.items() if pixel is not None])
    write(out, "lidar_box", name, [c for label in frame.laser_labels for c in box.LiDARBoxComponentExtractor()(
        interfaces.LiDARLabelComponentSrc(frame=frame, lidar_label=label))])
    write(out, "projected_lidar_box", name, [
        c for labels in frame.projected_lidar_labels for label in labels.labels
        for c in box.ProjectedLiDARBoxComponentExtractor()(
            interfaces.CameraLabelComponentSrc(frame=frame, camera_labels=labels, label=label))])
    write(out, "camera_box", name, [c for labels in frame.camera_labels for label in labels.labels
                                    for c in box.CameraBoxComponentExtractor()(
                                        interfaces.CameraLabelComponentSrc(frame=frame, camera_labels=labels, label=label))])

    # Waymo's points, from the v2 components just written (read back as v2 dataclasses).
    def rows(component: str) -> list[dict]:
        return pq.read_table(out / component / f"{name}.parquet").to_pylist()

    calibrations = {r["key.laser_name"]: v2_context.LiDARCalibrationComponent.from_dict(r) for r in rows("lidar_calibration")}
    pixel_poses = {r["key.laser_name"]: v2_lidar.LiDARPoseComponent.from_dict(r) for r in rows("lidar_pose")}
    frame_pose = v2_pose.VehiclePoseComponent.from_dict(rows("vehicle_pose")[0])
    lasers = []
    for row in rows("lidar"):
        component = v2_lidar.LiDARComponent.from_dict(row)
        laser = row["key.laser_name"]
        calibration = calibrations[laser]
        pixel = pixel_poses.get(laser)
        result = {}
        for index, image in enumerate(component.range_image_returns):
            v2 = lidar_utils.convert_range_image_to_point_cloud(
                image, calibration, pixel.range_image_return1 if pixel else None, frame_pose if pixel else None,
                keep_polar_features=True).numpy()
            tensor = tf.convert_to_tensor(np.asarray(image.values, np.float64).reshape(image.shape))
            if calibration.beam_inclination.values is not None:
                inclination = tf.constant(calibration.beam_inclination.values, tf.float64)
            else:
                inclination = range_image_utils.compute_inclination(
                    tf.constant([calibration.beam_inclination.min, calibration.beam_inclination.max], tf.float64),
                    height=image.shape[0])
            inclination = tf.reverse(inclination, axis=[-1])
            extrinsic = tf.constant(np.asarray(calibration.extrinsic.transform, np.float64).reshape(4, 4))
            pixel_pose = frame_tensor = None
            if pixel:
                values = np.asarray(pixel.range_image_return1.values, np.float64).reshape(pixel.range_image_return1.shape)
                rotation = transform_utils.get_rotation_matrix(
                    tf.constant(values[..., 0]), tf.constant(values[..., 1]), tf.constant(values[..., 2]))
                pixel_pose = transform_utils.get_transform(rotation, tf.constant(values[..., 3:]))[None]
                frame_tensor = tf.constant(np.asarray(frame_pose.world_from_vehicle.transform, np.float64).reshape(1, 4, 4))
            cartesian = range_image_utils.extract_point_cloud_from_range_image(
                tensor[None, ..., 0], extrinsic[None], inclination[None], pixel_pose=pixel_pose, frame_pose=frame_tensor,
                dtype=tf.float64)[0].numpy()
            f64 = cartesian[tensor.numpy()[..., 0] > 0]
            result[f"v2_return{index + 1}"] = v2
            result[f"f64_return{index + 1}"] = f64
        np.savez(out / f"points_{laser}.npz", **result)
        lasers.append(laser)
    print(json.dumps({"context": name, "lasers": sorted(lasers)}))


if __name__ == "__main__":
    main()
