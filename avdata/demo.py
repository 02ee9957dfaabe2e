"""A small built-in example dataset (``avdata demo``), made from analytic geometry, no downloads.

One scene, 10 Hz, ego driving along a straight road at 8 m/s past a parked car, an oncoming car
and a crossing pedestrian. A roof lidar (32 beams, ray-cast analytically against the ground plane
and the objects' boxes) and a front camera (PNG drawn with OpenCV: ground, sky, projected boxes)
give a point cloud, an image and a calibration per frame; labels include visibility for both.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from avdata.errors import AvdataError
from avdata.executors.lock import prepare_folder
from avdata.frames import Boxes3D, Transform
from avdata.schema import DatasetWriter, ObjectLabels, SceneWriter, VisibilityLabels

N_FRAMES = 5
PERIOD_NS = 100_000_000
START_NS = 1_700_000_000_000_000_000
EGO_SPEED_MPS = 8.0
IMAGE_SIZE = (640, 360)
LIDAR_HEIGHT_M = 1.8

#: ``ego_T_lidar``: roof lidar, 1.8 m above the ego origin (rear axle on the ground).
EGO_T_LIDAR = Transform(rotation=np.eye(3), translation=np.array([1.0, 0.0, LIDAR_HEIGHT_M]))
#: ``ego_T_camera``: front camera looking forward, optical axes (x right, y down, z forward).
EGO_T_CAMERA = Transform(
    rotation=np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]),
    translation=np.array([1.5, 0.0, 1.5]),
)
CAMERA_K = np.array([[400.0, 0.0, 320.0], [0.0, 400.0, 180.0], [0.0, 0.0, 1.0]])

# id, class, start centre (world), size lwh, yaw, velocity (world)
_OBJECTS = [
    ("1", "car", (20.0, -3.5, 0.8), (4.5, 1.9, 1.6), 0.0, (0.0, 0.0, 0.0)),
    ("2", "car", (45.0, 3.5, 0.8), (4.2, 1.8, 1.5), np.pi, (-10.0, 0.0, 0.0)),
    ("3", "pedestrian", (15.0, 6.0, 0.9), (0.6, 0.6, 1.8), -np.pi / 2, (0.0, -1.4, 0.0)),
]


def write_demo(dst: str | Path) -> Path:
    """Writes the demo dataset to ``dst`` and returns its path; InputError (one line) when ``dst`` cannot be a folder."""
    dst = prepare_folder(Path(dst))
    with DatasetWriter(dst, source="avdata-demo", source_version="1", licence="CC0-1.0",
                       description="analytic example scene built into avdata") as writer:
        metadata = {"description": "ego passes a parked car, an oncoming car and a crossing pedestrian",
                    "world_origin": "ego pose at the first frame", "time": "nominal 10 Hz"}
        with writer.scene("demo-0000", metadata) as scene:
            scene.add_agent("ego", kind="vehicle", origin="rear axle centre on the ground")
            scene.add_sensor("ego/lidar_top", kind="lidar", beams=32, rate_hz=10.0)
            scene.add_sensor("ego/cam_front", kind="camera", width=IMAGE_SIZE[0], height=IMAGE_SIZE[1], rate_hz=10.0)
            scene.add_static_transform("ego", "ego/lidar_top", EGO_T_LIDAR)
            scene.add_static_transform("ego", "ego/cam_front", EGO_T_CAMERA)
            scene.add_camera_calibration("ego/cam_front", START_NS, CAMERA_K, *IMAGE_SIZE)
            for index in range(N_FRAMES):
                _write_frame(scene, index)
    return dst


def _write_frame(scene: SceneWriter, index: int) -> None:
    t_ns = START_NS + index * PERIOD_NS
    elapsed_s = index * PERIOD_NS / 1e9
    world_T_ego = Transform(rotation=np.eye(3), translation=np.array([EGO_SPEED_MPS * elapsed_s, 0.0, 0.0]))
    ids, classes, centers, sizes, yaws, velocities = zip(*_OBJECTS, strict=True)
    centers_world = np.array(centers) + np.array(velocities) * elapsed_s
    boxes_world = Boxes3D.from_yaw(centers_world, np.array(sizes), np.array(yaws), "world",
                                   ids=np.array(ids), classes=np.array(classes), velocity=np.array(velocities))
    scene.add_transform("world", "ego", t_ns, world_T_ego)
    world_T_lidar = world_T_ego @ EGO_T_LIDAR
    boxes_lidar = boxes_world.transform(world_T_lidar.inverse(), "ego/lidar_top")
    points_lidar, hit_box = _cast_lidar(boxes_lidar)
    scene.add_point_cloud("ego/lidar_top", t_ns, {
        "x": points_lidar[:, 0], "y": points_lidar[:, 1], "z": points_lidar[:, 2],
        "intensity": np.where(hit_box >= 0, 0.8, 0.2).astype(np.float32),
    })
    boxes_camera = boxes_world.transform((world_T_ego @ EGO_T_CAMERA).inverse(), "ego/cam_front")
    png, box2d, in_image = _render_camera(boxes_camera)
    scene.add_image("ego/cam_front", t_ns, png, "png")
    scene.add_frame(index, t_ns, ObjectLabels(boxes=boxes_world),
                    {"ego/lidar_top": t_ns, "ego/cam_front": t_ns})
    n_points = np.array([(hit_box == i).sum() for i in range(len(boxes_world))], dtype=np.int32)
    scene.add_visibility("ego/lidar_top", index, t_ns, VisibilityLabels(
        object_ids=np.array(ids), in_fov=np.linalg.norm(boxes_lidar.center, axis=1) < 60.0,
        n_points=n_points, occlusion=np.where(n_points > 0, 0, 3)))
    scene.add_visibility("ego/cam_front", index, t_ns, VisibilityLabels(
        object_ids=np.array(ids), in_fov=in_image, box2d_xyxy=box2d, occlusion=np.where(in_image, 0, 3)))


def _cast_lidar(boxes_lidar: Boxes3D) -> tuple[np.ndarray, np.ndarray]:
    """Analytic ray cast: 32 beams x 720 azimuths against the ground and the boxes (slab method)."""
    elevation = np.radians(np.linspace(-25.0, 5.0, 32))
    azimuth = np.radians(np.arange(720) * 0.5)
    el, az = np.meshgrid(elevation, azimuth, indexing="ij")
    directions = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1).reshape(-1, 3)
    ranges = np.full(len(directions), np.inf)
    down = directions[:, 2] < -1e-6
    ranges[down] = -LIDAR_HEIGHT_M / directions[down, 2]
    hit = np.full(len(directions), -1)
    rotation = boxes_lidar.rotation_matrix()
    for i in range(len(boxes_lidar)):
        origin_box = rotation[i].T @ (-boxes_lidar.center[i])
        dirs_box = directions @ rotation[i]
        half = boxes_lidar.size_lwh[i] / 2.0
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-half - origin_box) / dirs_box
            t2 = (half - origin_box) / dirs_box
        t_near = np.nanmax(np.minimum(t1, t2), axis=1)
        t_far = np.nanmin(np.maximum(t1, t2), axis=1)
        closer = (t_near <= t_far) & (t_near > 0) & (t_near < ranges)
        ranges[closer] = t_near[closer]
        hit[closer] = i
    keep = np.isfinite(ranges) & (ranges < 80.0)
    return (directions[keep] * ranges[keep, None]).astype(np.float32), hit[keep]


def _render_camera(boxes_camera: Boxes3D) -> tuple[bytes, np.ndarray, np.ndarray]:
    width, height = IMAGE_SIZE
    image = np.zeros((height, width, 3), dtype=np.uint8)
    image[: height // 2] = (235, 206, 135)
    image[height // 2 :] = (90, 90, 90)
    corners = boxes_camera.corners()
    classes = [cls for _, cls, *_ in _OBJECTS]
    box2d = np.full((len(boxes_camera), 4), np.nan, dtype=np.float32)
    in_image = np.zeros(len(boxes_camera), dtype=bool)
    for i in np.argsort(-boxes_camera.center[:, 2]):
        if np.any(corners[i, :, 2] <= 0.1):
            continue
        uv = (CAMERA_K @ corners[i].T).T
        uv = uv[:, :2] / uv[:, 2:3]
        x0, y0 = np.clip(uv.min(axis=0), 0, [width - 1, height - 1])
        x1, y1 = np.clip(uv.max(axis=0), 0, [width - 1, height - 1])
        if x1 <= x0 or y1 <= y0:
            continue
        box2d[i] = (x0, y0, x1, y1)
        in_image[i] = True
        color = (40, 40, 220) if classes[i] == "car" else (40, 200, 40)
        cv2.rectangle(image, (int(x0), int(y0)), (int(x1), int(y1)), color, thickness=-1)
    ok, png = cv2.imencode(".png", image)
    if not ok:
        raise AvdataError("demo: OpenCV could not encode the camera image as PNG")
    return png.tobytes(), box2d, in_image
