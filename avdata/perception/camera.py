"""A simulated camera detector: the objects one camera sees, as 3D detections carrying their 2D boxes in its image.

AVstack's camera agents detect in 3D from one camera and are scored in 2D as well. Here, per frame:

* **what the camera sees**: where the scene has visibility labels of that camera (KITTI's camera 2, a generated
  camera), an object is seen when its label puts it in the field of view with a 2D box (a generated camera
  gives none to an object hidden entirely), with the label's occlusion level;
  in a scene without them (Lyft, Argoverse 2), when its 3D box projects into the image and its centre lies
  within ``max_range_m`` of the camera (occlusion unknown: level 0);
* **the detections**: :class:`~avdata.perception.detections.DetectionSimulator` (the same noise levels, misses by
  occlusion, Poisson false positives over the camera's horizontal field of view) applied in the camera's
  *upright* frame: at the camera, x along its optical axis levelled, z up. The noise model's axes are a
  ground vehicle's (heading noise about z), which the optical frame (z forward, y down) is not;
* **the 2D boxes**: each detection's 3D box projected into the image by :meth:`avdata.frames.Boxes3D.image_boxes`
  through the scene's camera calibration (:func:`avdata.loaders.items.projection`: rectification and
  intrinsics; lens distortion is not applied, as in the loaders), kept in ``Detections.extras["box2d_px"]``.
  A detection whose box falls outside the image is dropped: the camera cannot report it. A scene whose camera
  has labels but no calibration (KITTI sequences converted without images) gets its detections with NaN 2D
  boxes, and no 2D score.

Every draw is seeded by (seed, scene, frame, camera), so the same inputs give the same detections anywhere.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from avdata.errors import InputError
from avdata.frames import Boxes3D, Transform
from avdata.perception.collaboration import boxes_by_frame
from avdata.perception.detections import NOISE_LEVELS, Detections, DetectionSimulator, rng_for
from avdata.schema import DatasetReader, SceneReader, topics

__all__ = ["CameraPerception", "CameraView", "label_boxes_2d"]

#: The horizontal field of view false positives are spread over when a scene has no calibration of the camera.
_UNCALIBRATED_FOV_DEG = 90.0


class CameraView:
    """How one camera of a scene images boxes in ``world``: its calibration and its pose at each time.

    Args:
        reader: the scene.
        camera: the camera's frame (``ego/cam2``).

    Attributes:
        calibrated: whether the scene has the camera's calibration (else nothing can be projected).
        size_px: (width, height) of its image ((0, 0) without calibration).
        horizontal_fov_deg: its horizontal field of view (from the calibration).
    """

    def __init__(self, reader: SceneReader, camera: str):
        cameras = sorted(name for name, spec in reader.sensors().items() if spec.get("kind") == "camera")
        if camera not in cameras:
            raise InputError(f"scene {reader.name!r}: expected a camera named {camera!r}, got cameras {cameras}")
        self.camera = camera
        self.graph = reader.graph
        self.calibrated = topics.sensor_topic(camera, topics.CALIBRATION_SUFFIX) in reader.topics
        self._reader = reader
        self.size_px = (0, 0)
        self.horizontal_fov_deg = _UNCALIBRATED_FOV_DEG
        if self.calibrated:
            calibration = reader.camera_calibration(camera)
            self.size_px = (int(calibration.width), int(calibration.height))
            focal_px = float(np.asarray(calibration.P, dtype=np.float64)[0])
            if self.size_px[0] > 0 and focal_px > 0:
                self.horizontal_fov_deg = float(np.degrees(2.0 * np.arctan(self.size_px[0] / 2.0 / focal_px)))

    def world_T_camera(self, time_ns: int) -> Transform:
        """The camera's (optical frame's) pose in ``world`` at ``time_ns``."""
        return self.graph.lookup("world", self.camera, time_ns)

    def boxes_2d(self, boxes_world: Boxes3D, time_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """((N, 4) pixel boxes ``x0, y0, x1, y1`` clipped to the image, NaN where none; (N,) in the image) at ``time_ns``."""
        if not self.calibrated:
            raise InputError(f"scene {self._reader.name!r}: camera {self.camera!r} has no calibration to project with")
        from avdata.loaders.items import projection

        calibration = self._reader.camera_calibration(self.camera, time_ns)
        pixels_T_world = projection(calibration, self.world_T_camera(time_ns).inverse())
        xyxy, _, in_image = boxes_world.image_boxes(pixels_T_world, self.size_px)
        return np.where(in_image[:, None], xyxy, np.nan), in_image


def label_boxes_2d(dataset: DatasetReader, scene: str, camera: str) -> pa.Table:
    """The scene's own 2D boxes of ``camera`` (its visibility labels: KITTI's label boxes, a renderer's).

    Returns:
        ``frame_index``, ``object_id``, ``box2d_{x0,y0,x1,y1}_px`` and ``occlusion`` of the labelled objects in
        the camera's field of view (rows with a finite box); no rows where the scene has no labels of it.
    """
    vis = dataset.visibility()
    vis = vis.filter(pc.and_(pc.equal(vis["scene"], scene), pc.equal(vis["sensor"], camera)))
    if len(vis):
        box = np.stack([vis[c].to_numpy(zero_copy_only=False).astype(np.float64) for c in _BOX_COLUMNS], axis=1)
        vis = vis.filter(pa.array(vis["in_fov"].to_numpy(zero_copy_only=False).astype(bool)
                                  & np.all(np.isfinite(box), axis=1)))
    return vis.select(["frame_index", "object_id", *_BOX_COLUMNS, "occlusion"])


_BOX_COLUMNS = ("box2d_x0_px", "box2d_y0_px", "box2d_x1_px", "box2d_y1_px")


@dataclass(frozen=True, slots=True)
class CameraFrame:
    """One frame of a camera detector: its index, time and detections in ``world`` (``extras["box2d_px"]``)."""

    frame_index: int
    timestamp_ns: int
    detections: Detections


class CameraPerception:
    """Simulated detections of one camera over one scene (module docstring).

    Args:
        dataset: the unified dataset.
        scene: the scene.
        camera: the camera's frame.
        noise: a level of :data:`~avdata.perception.detections.NOISE_LEVELS`.
        max_range_m: an unlabelled scene's objects are seen within this distance of the camera; false
            positives are placed within it.
        seed: the seed of every draw.
    """

    def __init__(self, dataset: DatasetReader, scene: str, camera: str, noise: str, *, max_range_m: float = 100.0,
                 seed: int = 0):
        if noise not in NOISE_LEVELS:
            raise InputError(f"camera detector: expected noise in {sorted(NOISE_LEVELS)}, got {noise!r}")
        reader = dataset.scene(scene)
        self.view = CameraView(reader, camera)
        self.scene, self.camera, self.seed = scene, camera, seed
        frames = dataset.frames().filter(pc.equal(dataset.frames()["scene"], scene))
        self.frame_index = frames["frame_index"].to_numpy().astype(np.int64)
        self.timestamp_ns = frames["timestamp_ns"].to_numpy().astype(np.int64)
        agents = reader.metadata.get("agents", {})
        #: Object ids that are agents themselves (never detected, never scored).
        self.own_object_ids = sorted(str(a["object_id"]) for a in agents.values() if isinstance(a, dict) and "object_id" in a)
        objects = dataset.objects().filter(pc.equal(dataset.objects()["scene"], scene))
        objects = objects.filter(pc.invert(pc.is_in(objects["object_id"], pa.array(self.own_object_ids, pa.string()))))
        self._objects = boxes_by_frame(objects)
        labels = label_boxes_2d(dataset, scene, camera)
        self.labelled = len(labels) > 0
        if not self.labelled and not self.view.calibrated:
            raise InputError(f"scene {scene!r}: camera {camera!r} has neither visibility labels nor a calibration: "
                             "nothing says what it sees")
        label_frame = labels["frame_index"].to_numpy().astype(np.int64)
        self._labels = {int(f): (labels["object_id"].to_numpy(zero_copy_only=False).astype(str)[label_frame == f],
                                 labels["occlusion"].to_numpy().astype(np.int64)[label_frame == f])
                        for f in np.unique(label_frame)}
        self._simulator = DetectionSimulator(noise=NOISE_LEVELS[noise], min_points=1, max_range_m=max_range_m,
                                             horizontal_fov_deg=self.view.horizontal_fov_deg)
        self.max_range_m = max_range_m

    @property
    def has_2d_boxes(self) -> bool:
        """Whether the detections carry 2D boxes (the scene has the camera's calibration)."""
        return self.view.calibrated

    def run(self) -> Iterator[CameraFrame]:
        """The camera's detections at every frame, in order, in ``world``."""
        no_boxes = Boxes3D.empty("world")
        no_boxes = replace(no_boxes, ids=np.zeros(0, dtype=str), classes=np.zeros(0, dtype=str))
        for frame, t_ns in zip(self.frame_index.tolist(), self.timestamp_ns.tolist(), strict=True):
            yield CameraFrame(frame, t_ns, self._detect(frame, t_ns, self._objects.get(frame, no_boxes)))

    def _seen(self, frame: int, gt: Boxes3D, t_ns: int, world_T_camera: Transform) -> tuple[np.ndarray, np.ndarray]:
        """(N,) whether the camera sees each box, (N,) its occlusion level."""
        gt_ids = np.asarray(gt.ids, dtype=str)
        if self.labelled:
            ids, occlusion = self._labels.get(frame, (np.zeros(0, dtype=str), np.zeros(0, np.int64)))
            order = np.lexsort((occlusion, ids))  # per id, the lowest occlusion first
            ids, occlusion = ids[order], occlusion[order]
            pos = np.clip(np.searchsorted(ids, gt_ids), 0, max(len(ids) - 1, 0))
            found = ids[pos] == gt_ids if len(ids) else np.zeros(len(gt), bool)
            return found, np.where(found, occlusion[pos] if len(ids) else 3, 3)
        _, in_image = self.view.boxes_2d(gt, t_ns)
        near = np.linalg.norm(world_T_camera.inverse().apply(gt.center), axis=1) <= self.max_range_m
        return in_image & near, np.zeros(len(gt), np.int64)

    def _detect(self, frame: int, t_ns: int, gt: Boxes3D) -> Detections:
        world_T_camera = self.view.world_T_camera(t_ns)
        seen, occlusion = self._seen(frame, gt, t_ns, world_T_camera)
        world_T_upright = _upright(world_T_camera)
        rng = rng_for(self.seed, self.scene, frame, self.camera)
        found = self._simulator.detect(gt, seen.astype(np.int64), occlusion, world_T_upright, self.camera, t_ns, rng)
        world = found.to("world", world_T_upright)
        if not self.view.calibrated:
            return replace(world, extras={"box2d_px": np.full((len(world), 4), np.nan)})
        box2d, in_image = self.view.boxes_2d(world.boxes, t_ns)
        return replace(world.select(in_image), extras={"box2d_px": box2d[in_image]})


def _upright(world_T_camera: Transform) -> Transform:
    """The camera's upright frame in ``world``: at the camera, x along its optical axis levelled, z up."""
    optical_axis = world_T_camera.rotation[:, 2]
    heading = float(np.arctan2(optical_axis[1], optical_axis[0]))
    c, s = np.cos(heading), np.sin(heading)
    return Transform(rotation=np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]),
                     translation=world_T_camera.translation)
