"""Pictures of a frame: a bird's-eye view and every camera with its projected boxes; videos of a scene.

Bird's-eye view (display frame ``ego`` by default, x up, y left): each lidar's points moved through the frame
graph (sensor pose at its own message time, the display frame at the frame time), coloured by height in
the display frame or by agent; label boxes in their class colour with a heading tick and their id; agents as
dots with their lidars' horizontal field of view and range; range rings. Cameras: the image as stored, each
label box moved into the camera frame through the graph at the image time and projected with the
calibration's K (images in the unified format are rectified or, for generated data, distortion-free; a
camera with a non-zero distortion is drawn with K alone, and the picture says so), 2D boxes of the
visibility labels as thin white rectangles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from avdata.errors import InputError, OutputError
from avdata.outputs import temporary_path
from avdata.schema import DatasetReader, topics
from avdata.schema.records import CLASS_COLORS, OTHER_CLASS_COLOR, required_ids_and_classes

__all__ = ["BevView", "frame_pictures", "render_bev", "render_camera", "render_frame", "render_video"]

_EDGES = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4], [0, 4], [1, 5], [2, 6], [3, 7]])
#: Side of the largest bird's-eye view drawn (8192 px: 200 MB as BGR); a larger range is refused, not allocated.
MAX_BEV_SIDE_PX = 8192
#: Side of the smallest (16 px: a 1 m range at 8 px/m); a range rounding to 0 px has no picture to draw in.
MIN_BEV_SIDE_PX = 16
_AGENT_BGR = [(255, 255, 255), (80, 220, 80), (60, 180, 255), (255, 120, 200), (120, 255, 255), (200, 160, 90)]


@dataclass(frozen=True, slots=True, kw_only=True)
class BevView:
    """What the bird's-eye view shows.

    Attributes:
        frame: the display frame (``ego``, ``world``, an agent).
        range_m: half the side of the square shown, metres.
        pixels_per_m: scale.
        color_by: ``"height"`` (in the display frame) or ``"agent"``.
        ring_step_m: distance between range rings.
    """

    frame: str = "ego"
    range_m: float = 60.0
    pixels_per_m: float = 8.0
    color_by: str = "height"
    ring_step_m: float = 20.0

    def __post_init__(self) -> None:
        if self.color_by not in ("height", "agent"):
            raise InputError(f"render: expected color_by 'height' or 'agent', got {self.color_by!r}")
        values = (self.range_m, self.pixels_per_m, self.ring_step_m)
        if not all(math.isfinite(v) and v > 0 for v in values):
            raise InputError(f"render: expected finite positive range, scale and ring step, got {self.range_m}, "
                             f"{self.pixels_per_m}, {self.ring_step_m}")
        side_px = 2 * self.range_m * self.pixels_per_m
        if side_px < MIN_BEV_SIDE_PX:  # a view rounded to 0 px made OpenCV fail with a traceback
            raise InputError(f"render: expected --range-m at least {MIN_BEV_SIDE_PX / 2 / self.pixels_per_m:g} m "
                             f"(a bird's-eye view of at least {MIN_BEV_SIDE_PX} px at {self.pixels_per_m:g} px/m), "
                             f"got {self.range_m:g}")
        if side_px > MAX_BEV_SIDE_PX:
            raise InputError(f"render: expected --range-m at most {MAX_BEV_SIDE_PX / 2 / self.pixels_per_m:g} m "
                             f"(a bird's-eye view of at most {MAX_BEV_SIDE_PX} px at {self.pixels_per_m:g} px/m), "
                             f"got {self.range_m:g}")


def _bgr(cls: str) -> tuple[int, int, int]:
    r, g, b = CLASS_COLORS.get(cls, OTHER_CLASS_COLOR)
    return int(b * 255), int(g * 255), int(r * 255)


def render_bev(ds: DatasetReader, scene: str, frame_index: int, view: BevView = BevView()) -> np.ndarray:
    """(H, W, 3) uint8 BGR bird's-eye view of one frame."""
    reader = ds.scene(scene)
    graph = reader.graph
    info, labels = reader.labels(frame_index)
    t = info.timestamp_ns
    size = int(round(2 * view.range_m * view.pixels_per_m))
    image = np.full((size, size, 3), 24, np.uint8)
    centre = size / 2.0

    def to_px(xy: np.ndarray) -> np.ndarray:  # display x forward -> up, y left -> left
        return np.stack([centre - xy[..., 1] * view.pixels_per_m, centre - xy[..., 0] * view.pixels_per_m], axis=-1)

    for ring in np.arange(view.ring_step_m, view.range_m * 1.5, view.ring_step_m):
        cv2.circle(image, (int(centre), int(centre)), int(ring * view.pixels_per_m), (70, 70, 70), 1, cv2.LINE_AA)
        cv2.putText(image, f"{ring:.0f} m", (int(centre + 3), int(centre - ring * view.pixels_per_m - 3)),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.35, (110, 110, 110), 1, cv2.LINE_AA)
    sensors = reader.sensors()
    agents = sorted({s.split("/")[0] for s in sensors})
    for sensor in sorted(sensors):
        topic = topics.sensor_topic(sensor, topics.POINTS_SUFFIX)
        t_sensor = info.sensor_timestamps_ns.get(sensor)
        if topic not in reader.topics or t_sensor is None:
            continue
        points = reader.points(sensor, t_sensor)
        xyz = np.stack([points["x"], points["y"], points["z"]], axis=1).astype(np.float64)
        xyz = graph.lookup_fixed(view.frame, t, sensor, t_sensor).apply(xyz)
        px = to_px(xyz[:, :2]).astype(np.int64)
        inside = (px[:, 0] >= 0) & (px[:, 0] < size) & (px[:, 1] >= 0) & (px[:, 1] < size)
        px, z = px[inside], xyz[inside, 2]
        if not len(px):
            continue
        if view.color_by == "height":
            level = np.clip((z + 2.0) / 6.0 * 255.0, 0, 255).astype(np.uint8)
            colors = cv2.applyColorMap(level.reshape(-1, 1), cv2.COLORMAP_TURBO).reshape(-1, 3)
        else:
            colors = np.tile(np.array(_AGENT_BGR[agents.index(sensor.split("/")[0]) % len(_AGENT_BGR)], np.uint8), (len(px), 1))
        image[px[:, 1], px[:, 0]] = colors
    for agent in agents:
        if not graph.can_lookup(view.frame, agent, t):
            continue
        pose = graph.lookup(view.frame, agent, t)
        p = to_px(pose.translation[:2]).astype(int)
        cv2.circle(image, (int(p[0]), int(p[1])), 5, (255, 255, 255), -1, cv2.LINE_AA)
        cv2.putText(image, agent, (int(p[0]) + 7, int(p[1]) - 7), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
        for sensor, spec in sensors.items():
            fov = float(spec.get("horizontal_fov_deg", 360.0))
            if sensor.split("/")[0] != agent or spec.get("kind") != "lidar" or fov >= 360.0:
                continue
            sensor_pose = graph.lookup(view.frame, sensor, t)
            heading = np.arctan2(sensor_pose.rotation[1, 0], sensor_pose.rotation[0, 0])
            angles = heading + np.deg2rad(np.linspace(-fov / 2, fov / 2, 33))
            reach = float(spec.get("max_range_m", 50.0))
            origin = sensor_pose.translation[:2]
            arc = origin + reach * np.stack([np.cos(angles), np.sin(angles)], axis=1)
            wedge = np.ascontiguousarray(to_px(np.vstack([origin, arc, origin])), dtype=np.int32)
            cv2.polylines(image, [wedge], False, (90, 90, 90), 1, cv2.LINE_AA)
    boxes = labels.boxes.to(view.frame, graph, t)
    if len(boxes):
        footprint = np.ascontiguousarray(to_px(boxes.bev_corners()), dtype=np.int32)
        front = to_px((boxes.bev_corners()[:, 0] + boxes.bev_corners()[:, 3]) / 2).astype(int)
        centres = to_px(boxes.center[:, :2]).astype(int)
        ids, classes = required_ids_and_classes(boxes)
        for i in range(len(boxes)):  # drawing is per box in OpenCV; the geometry above is batched
            color = _bgr(str(classes[i]))
            cv2.polylines(image, [footprint[i]], True, color, 2, cv2.LINE_AA)
            cv2.line(image, tuple(centres[i]), tuple(front[i]), color, 1, cv2.LINE_AA)
            cv2.putText(image, str(ids[i]), (int(centres[i][0]) + 4, int(centres[i][1]) + 4),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.3, color, 1, cv2.LINE_AA)
    cv2.putText(image, f"{scene}  frame {frame_index}  t={t / 1e9:.3f} s  ({view.frame})", (8, 18),
                cv2.FONT_HERSHEY_SIMPLEX, 0.5, (230, 230, 230), 1, cv2.LINE_AA)
    return image


def render_camera(ds: DatasetReader, scene: str, frame_index: int, camera: str) -> np.ndarray | None:
    """(H, W, 3) BGR image of ``camera`` at the frame with projected 3D boxes and 2D boxes; None without an image."""
    reader = ds.scene(scene)
    info, labels = reader.labels(frame_index)
    t_cam = info.sensor_timestamps_ns.get(camera)
    if t_cam is None or topics.sensor_topic(camera, topics.IMAGE_SUFFIX) not in reader.topics:
        return None
    data, _ = reader.image(camera, t_cam)
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise InputError(f"{reader.path}: the image of {camera} at {t_cam} ns does not decode")
    calibration = reader.camera_calibration(camera, t_cam)
    k = np.asarray(calibration.K, dtype=np.float64).reshape(3, 3)
    boxes = labels.boxes
    if len(boxes):
        in_camera = boxes.transform(reader.graph.lookup_fixed(camera, t_cam, boxes.frame, info.timestamp_ns), camera)
        corners = in_camera.corners()
        ahead = np.all(corners[:, :, 2] > 0.1, axis=1)
        uvw = corners[ahead] @ k.T
        uv = np.ascontiguousarray(uvw[:, :, :2] / uvw[:, :, 2:3], dtype=np.int32)
        # Drawing only (OpenCV draws one polyline at a time); the projection above is batched.
        for cls, pts in zip(required_ids_and_classes(in_camera)[1][ahead], uv, strict=True):
            color = _bgr(str(cls))
            for a, b in _EDGES:
                cv2.line(image, tuple(pts[a]), tuple(pts[b]), color, 2 if a < 4 and b < 4 else 1, cv2.LINE_AA)
    visibility = reader.visibility(camera, frame_index)
    if visibility is not None and visibility.box2d_xyxy is not None:
        for x0, y0, x1, y1 in np.nan_to_num(np.asarray(visibility.box2d_xyxy, dtype=np.float64), nan=-1).astype(int):
            if x1 > x0 >= 0 and y1 > y0 >= 0:
                cv2.rectangle(image, (x0, y0), (x1, y1), (255, 255, 255), 1, cv2.LINE_AA)
    note = camera if not any(calibration.D) else f"{camera} (distortion not applied to overlays)"
    cv2.putText(image, note, (8, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return image


def render_frame(ds: DatasetReader, scene: str, frame_index: int, view: BevView = BevView()) -> np.ndarray:
    """The bird's-eye view with every camera image below it, scaled to its width."""
    if scene not in ds.scenes:
        raise InputError(f"{ds.root}: expected a scene of {ds.scenes}, got {scene!r}")
    bev = render_bev(ds, scene, frame_index, view)
    width = bev.shape[1]
    parts = [bev]
    for camera, spec in sorted(ds.scene(scene).sensors().items()):
        if spec.get("kind") != "camera":
            continue
        picture = render_camera(ds, scene, frame_index, camera)
        if picture is not None:
            height = int(round(picture.shape[0] * width / picture.shape[1]))
            parts.append(cv2.resize(picture, (width, height), interpolation=cv2.INTER_AREA))
    return np.vstack(parts)


def render_video(ds: DatasetReader, scene: str, out: str | Path, view: BevView = BevView(), fps: float = 10.0) -> Path:
    """Writes every frame of ``scene`` as an MP4 (OpenCV, mp4v) to ``out``."""
    out = Path(out)
    if out.is_dir():
        raise OutputError(f"{out}: cannot write this file (a folder is in its place)")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise OutputError(f"{out}: cannot write this file (a file is where its folder should be)") from None
    except OSError as error:
        raise OutputError(f"{out}: cannot write this file ({error.strerror or error})") from None
    n = len(ds.scene(scene).frame_infos())
    tmp = temporary_path(out, keep_suffix=True)
    writer = None
    try:
        for frame_index in range(n):
            picture = render_frame(ds, scene, frame_index, view)
            if writer is None:
                writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter.fourcc(*"mp4v"), fps, (picture.shape[1], picture.shape[0]))
                if not writer.isOpened():
                    raise OutputError(f"{out}: OpenCV cannot write an MP4 video here")
            writer.write(picture)
        if writer is not None:
            writer.release()
            writer = None
        tmp.replace(out)
    except OSError as error:
        raise OutputError(f"{out}: cannot write this file ({error.strerror or error})") from None
    finally:
        if writer is not None:
            writer.release()
        tmp.unlink(missing_ok=True)
    return out


def frame_pictures(root: str | Path, count: int = 2, width_px: int = 480) -> tuple[list[tuple[str, bytes]], list[str]]:
    """PNGs of up to ``count`` frames spread over the dataset's scenes (first frame of each, then later ones).

    For reports: each is :func:`render_frame` scaled to ``width_px``. A frame that cannot be drawn (a damaged
    file) costs only its picture.

    Returns:
        (caption, PNG bytes) per picture, and one line per frame that could not be drawn, saying why.
    """
    ds = DatasetReader(root, verify=True)
    picks: list[tuple[str, int]] = []
    for scene in ds.scenes:
        n = len(ds.scene(scene).frame_infos())
        picks += [(scene, i) for i in sorted({0, n // 2}) if i < n]
    # First frames of the first scenes, then middle frames: the most variety for a few pictures.
    picks = sorted(picks, key=lambda p: (p[1] > 0, ds.scenes.index(p[0])))[:count]
    pictures, notes = [], []
    for scene, frame_index in picks:
        try:
            picture = render_frame(ds, scene, frame_index)
        except InputError as error:
            notes.append(f"{Path(root).name} {scene} frame {frame_index}: not drawn ({error})")
            continue
        height = max(1, int(round(picture.shape[0] * width_px / picture.shape[1])))
        ok, png = cv2.imencode(".png", cv2.resize(picture, (width_px, height), interpolation=cv2.INTER_AREA))
        if ok:
            pictures.append((f"{Path(root).name}: {scene}, frame {frame_index}", png.tobytes()))
    return pictures, notes
