"""Item assembly: the frame an item is about, its label boxes, its camera images and calibrations.

Projection: a camera frame sits at that camera's own optical centre, so ``camera_T_frame`` already
holds any stereo baseline. The fourth column of ``P`` is, by the ROS/Foxglove (and KITTI P2/P3)
convention, the same baseline relative to the stereo pair's first camera, for points given in
that first camera's frame; it is therefore left out, and ``P[:, :3] @ R`` maps the camera frame to
rectified pixels. For KITTI this reproduces ``P2 @ R0_rect @ Tr_velo_to_cam``.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from avdata.errors import AvdataError, InputError
from avdata.frames import Transform
from avdata.loaders.frame_index import VisibilityIndex
from avdata.loaders.options import FrameOptions, agent_of, matches
from avdata.loaders.transforms import SceneTransforms, is_identity
from avdata.schema import ObjectLabels, SceneReader


@dataclass(frozen=True, slots=True, kw_only=True)
class ItemFrame:
    """One item being assembled: its scene and frame, and the frame and time everything is expressed in.

    Attributes:
        options: the dataset's options.
        visibility: the dataset's visibility rows.
        reader: the scene's reader.
        transforms: the scene's memoised lookups.
        scene: the scene name.
        frame_index: the frame index.
        time_ns: the frame's time (the time of its labels).
        prev_time_ns: the scene's previous frame time, -1 for its first frame.
        ego: the ego frame ("" for a scene without one).
        frame: the frame everything is expressed in.
        frame_time_ns: the time of ``frame`` (the frame's time, or a SequenceDataset's reference time).
    """

    options: FrameOptions
    visibility: VisibilityIndex
    reader: SceneReader
    transforms: SceneTransforms
    scene: str
    frame_index: int
    time_ns: int
    prev_time_ns: int
    ego: str
    frame: str
    frame_time_ns: int

    def own_object(self, agent: str) -> str | None:
        """The object id of an agent that is itself a labelled object (generated data name it), else None."""
        object_id = self.reader.metadata.get("agents", {}).get(agent, {}).get("object_id")
        return None if object_id is None else str(object_id)

    def seen(self, frame_index: int, sensors: list[str], object_ids: np.ndarray) -> np.ndarray:
        """(N,) whether any of ``sensors`` saw each object in a frame, under the label filter's thresholds."""
        seen = np.zeros(len(object_ids), dtype=bool)
        for sensor in sensors:
            seen |= self.visibility.passes(self.scene, frame_index, sensor, object_ids, self.options.labels)
        return seen


def frame_boxes(at: ItemFrame, labels: ObjectLabels, agents: list[str] | None, captures: Mapping[str, int]) -> dict[str, Any]:
    """The item's boxes, labels and object ids in ``at.frame`` (and ``visible_by`` for collaborative items).

    Args:
        at: the item's frame.
        labels: the frame's labels.
        agents: the item's agents (collaborative items), else None.
        captures: received agent -> the frame index of the capture it sent: its sensors' visibility is
            read there (a delayed agent's visibility belongs to the same capture as its points).
    """
    options = at.options.labels
    boxes = labels.boxes
    all_ids, all_classes = np.asarray(boxes.ids), np.asarray(boxes.classes)  # ObjectLabels always has both
    frame_T_labels = at.transforms.between(at.frame, at.frame_time_ns, boxes.frame, at.time_ns)
    class_index = class_indices(all_classes, options.classes)
    keep = class_index >= 0
    # An agent that is itself a labelled object is not a target of its own sensors.
    own_object = at.own_object(at.ego)
    if own_object is not None:
        keep &= all_ids != own_object
    if options.max_range_m is not None and len(boxes):
        if not at.ego:
            raise AvdataError(f"scene {at.scene!r}: max_range_m needs an ego frame, got a scene without one")
        centers_ego = at.transforms.lookup(at.ego, boxes.frame, at.time_ns).apply(boxes.center)
        keep &= np.hypot(centers_ego[:, 0], centers_ego[:, 1]) <= options.max_range_m
    if options.visible_to is not None:
        visible_to = options.visible_to
        if agents is None:
            sensors = at.visibility.sensors_of(at.scene, at.frame_index)
            keep &= at.seen(at.frame_index, [s for s in sensors if matches(s, visible_to)], all_ids)
        else:
            seen = np.zeros(len(boxes), dtype=bool)
            for agent, k in captures.items():
                seen |= at.seen(k, [s for s in at.visibility.sensors_of(at.scene, k)
                                    if agent_of(s) == agent and matches(s, visible_to)], all_ids)
            keep &= seen
    # Every box is moved (one vectorised call), then the kept ones taken: cheaper than a subset first.
    # Labels already in the item's frame (world items of world-frame labels) are not moved: an identity
    # move costs as much as any other (~0.17 ms per item) and would only round-trip the quaternions.
    moved = boxes if is_identity(frame_T_labels) else boxes.transform(frame_T_labels, at.frame)
    ids = all_ids[keep]
    columns = [moved.center[keep], moved.size_lwh[keep], moved.yaw()[keep, None]]
    if at.options.with_velocity:
        columns.append(moved.velocity[keep, :2] if moved.velocity is not None else np.full((len(ids), 2), np.nan))
    result: dict[str, Any] = {
        "boxes": np.concatenate(columns, axis=1).astype(np.float32),
        "labels": class_index[keep],
        "object_ids": ids.tolist(),
    }
    if at.options.with_quaternions:
        result["boxes_quat_wxyz"] = moved.quat_wxyz[keep]
    if agents is not None:
        visible_by = np.zeros((len(agents), len(ids)), dtype=bool)
        for a, agent in enumerate(agents):
            if agent in captures:
                k = captures[agent]
                visible_by[a] = at.seen(k, [s for s in at.visibility.sensors_of(at.scene, k) if agent_of(s) == agent], ids)
        result["visible_by"] = visible_by
    return result


def class_indices(classes: np.ndarray, names: tuple[str, ...]) -> np.ndarray:
    """(N,) int64 index of each class name (N,) in ``names`` (non-empty), -1 for a class not there."""
    order, sorted_names = _sorted(names)
    at = np.minimum(np.searchsorted(sorted_names, classes), len(names) - 1)
    found: np.ndarray = np.where(sorted_names[at] == classes, order[at], -1).astype(np.int64)
    return found


@functools.lru_cache(maxsize=16)
def _sorted(names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(order, names[order]) of a dataset's class names: sorted once, not for every item."""
    order = np.argsort(names)
    sorted_names = np.asarray(names)[order]
    order.flags.writeable = sorted_names.flags.writeable = False  # shared by every caller
    return order, sorted_names


def decode_image(data: bytes, where: str) -> np.ndarray:
    """(C, H, W) uint8 RGB(A) or (1, H, W) grey array from encoded PNG/JPEG bytes (OpenCV, BGR converted)."""
    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"{where}: image bytes could not be decoded by OpenCV")
    if image.dtype != np.uint8:
        raise InputError(f"{where}: expected an 8-bit image, got {image.dtype}")
    if image.ndim == 2:
        image = image[:, :, None]
    elif image.shape[2] == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    elif image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGBA)
    channels_first: np.ndarray = image.transpose(2, 0, 1)
    return channels_first


def calibration_dict(calibration: Any) -> dict[str, Any]:
    """The item's calibration entry of a camera: K (3, 3), D (k,), R (3, 3), P (3, 4) float64, size, model."""
    return {
        "K": np.asarray(calibration.K, dtype=np.float64).reshape(3, 3),
        "D": np.asarray(calibration.D, dtype=np.float64),
        "R": np.asarray(calibration.R, dtype=np.float64).reshape(3, 3),
        "P": np.asarray(calibration.P, dtype=np.float64).reshape(3, 4),
        "width": int(calibration.width),
        "height": int(calibration.height),
        "distortion_model": str(calibration.distortion_model),
    }


def projection(calibration: Any, camera_T_frame: Transform) -> np.ndarray:
    """(3, 4) ``P[:, :3] @ [R | 0] @ camera_T_frame`` (module docstring: why P's 4th column is dropped)."""
    R = np.asarray(calibration.R, dtype=np.float64).reshape(3, 3)
    P = np.asarray(calibration.P, dtype=np.float64).reshape(3, 4)
    frame_to_pixels: np.ndarray = P[:, :3] @ R @ camera_T_frame.as_matrix()[:3, :]
    return frame_to_pixels
