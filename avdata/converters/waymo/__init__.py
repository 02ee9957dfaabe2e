"""Waymo Open Dataset v2 (Parquet components) -> the unified format.

``avdata convert waymo WAYMO_V2_ROOT DST``: the root holds ``<component>/<context>.parquet`` files
(optionally under split folders); each context (segment) becomes one scene. Read with pyarrow only; the root may
be an object-store prefix (``gs://``, ``s3://``), whose files are read by ranged requests of the columns used.

The source's rows of docs/conventions.md, and what this module does with each:

=================  ==========================================================================
Waymo v2           how it is converted
=================  ==========================================================================
world              Waymo's global frame of the segment (``vehicle_pose.world_from_vehicle``), z up,
                   not re-centred. Poses are float32 in the files (real ones off orthonormality by up
                   to ~1e-7): repaired silently up to 1e-6, with a warning up to 1e-2, refused beyond
ego                Waymo's vehicle frame (x forward, y left, z up; origin at the rear axle centre)
                   -> ``ego``; ``world -> ego`` on ``/tf`` at every frame time and at every camera
                   image's ``pose_timestamp`` (the SDC pose Waymo stores with the image)
frame of labels    vehicle frame at the frame time -> boxes stay in ``ego``, unchanged
box                centre, size (length along heading, width, height), heading about +z ->
                   ``Boxes3D.from_waymo``; ``speed`` -> velocity and ``acceleration`` (ego axes);
                   ``num_lidar_points_in_box``, ``num_top_lidar_points_in_box``, detection and
                   tracking difficulty levels -> extras; ``TYPE_*`` verbatim as source class
lidar              range images (both returns) -> points with Waymo's formulas
                   (:mod:`avdata.sources.waymo.lidar`): beam inclinations uniform or per beam, the
                   extrinsic's azimuth correction, and for the top lidar the per-pixel vehicle pose
                   (rolling sweep), so the points are Waymo's vehicle-frame points at the frame
                   time. They are stored in each lidar's own axes (``lidar_T_ego`` applied; the
                   extrinsic is on ``/tf_static``), with fields range, intensity, elongation,
                   no_label_zone, return_index (0, 1), laser_name (1..5), row, column
cameras            Waymo's camera frame is x forward, y left, z up -> the optical frame through
                   ``XFWD_T_OPTICAL`` on ``/tf_static``; intrinsics f_u, f_v, c_u, c_v and
                   distortion (k1, k2, p1, p2, k3: OpenCV's plumb_bob order); JPEG bytes untouched,
                   stamped with ``pose_timestamp``; rolling-shutter direction and per-image
                   parameters (shutter, trigger and readout-done times) in the scene metadata
projected boxes    ``projected_lidar_box`` -> each camera's ``/visibility`` 2D boxes (pixels)
time               UTC epoch: ``frame_timestamp_micros`` x 1000; image times from seconds, rounded
=================  ==========================================================================

Native camera boxes (``camera_box``, 2D labels with their own ids) have no place in the unified
format yet; their count is in the scene metadata. Memory: one context at a time; the large
components (lidar, lidar_pose, camera_image) are read a few rows at a time and joined on their
keys through a buffer that holds only rows not yet used (a few when both files are in frame order).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from avdata.converters.base import ConvertConfig, Converter, Report
from avdata.converters.waymo.cameras import camera_calibrations, camera_images, camera_poses
from avdata.converters.waymo.labels import object_labels, projected_boxes
from avdata.converters.waymo.lidar import lidar_calibrations, lidar_points
from avdata.converters.waymo.segment import Segment, camera_frame, id_set, lidar_frame
from avdata.errors import InputError
from avdata.schema import DatasetWriter, ObjectLabels
from avdata.sources.waymo import CLASS_MAP, COMPONENTS, ComponentFile, find_component_files
from avdata.sources.waymo.components import TIME_KEY
from avdata.storage import Location

__all__ = ["CLASS_MAP", "COMPONENTS", "WaymoConverter", "camera_frame", "lidar_frame"]


class WaymoConverter(Converter):
    """Waymo Open Dataset v2 (Parquet components; one scene per context)."""

    name = "waymo"
    source = "Waymo Open Dataset"
    licence = "Waymo Dataset License Agreement for Non-Commercial Use"
    reads_stores = True

    def __init__(self, config: ConvertConfig):
        """A converter of ``config.src``; its component files are found on first use (:meth:`files`)."""
        super().__init__(config)
        self._files: dict[str, dict[str, ComponentFile]] | None = None

    def __getstate__(self) -> dict[str, Any]:
        """The converter without its file map.

        A worker finds the map once (``files``); pickled with every task, the map of every segment's files went
        to the workers once per segment.
        """
        return {**self.__dict__, "_files": None}

    def source_version(self) -> str:
        """The source's version, for the manifest."""
        return "v2 (Parquet components)"

    def files(self) -> dict[str, dict[str, ComponentFile]]:
        """Context -> component -> file, found once per process."""
        if self._files is None:
            self._files = find_component_files(self.config.src)
        return self._files

    def release(self) -> None:
        """Drops the cached source tables before the index is built."""
        self._files = None

    def list_scenes(self) -> list[str]:
        """Every scene of the source, in a stable order."""
        return list(self.files())

    def source_files(self, scene: str) -> list[Path | Location]:
        """The context's component files."""
        return sorted((f.path for f in self.files()[scene].values()), key=str)

    def convert_scene(self, scene: str, writer: DatasetWriter, report: Report) -> None:
        """Converts one scene into writer; problems of single records go to report."""
        _SceneConversion(scene, self.files()[scene], report).write(writer)


class _SceneConversion(Segment):
    """Converts one context: its poses, sensors, frames and labels into one scene."""

    def write(self, writer: DatasetWriter) -> None:
        times_us, poses, world_T_ego = self.poses()
        frame_of_time = {int(t): i for i, t in enumerate(times_us.tolist())}
        metadata: dict[str, Any] = {
            "context": self.context,
            "split": self.split,
            "world": "Waymo's global frame of the segment (vehicle_pose world_from_vehicle), z up; not re-centred",
            "ego_origin": "Waymo vehicle frame: centre of the rear axle, x forward, y left, z up",
            "time": "UTC epoch (Waymo microseconds x 1000)",
            "labels_frame": "ego (Waymo's vehicle frame at the frame time)",
        }
        metadata.update(self._stats())
        metadata["camera_rolling_shutter"], image_poses = camera_poses(self)
        metadata["camera_box_count"] = self._camera_box_count()
        with writer.scene(self.context, metadata) as scene:
            scene.add_agent("ego", "vehicle", metadata["ego_origin"])
            # Frame poses and the poses stored with camera images, in time order (a frame pose wins a tie).
            stamped = {t * 1000: pose for t, pose in zip(times_us.tolist(), world_T_ego, strict=True)}
            for time_ns, matrix in sorted(image_poses.items()):
                if time_ns in stamped:
                    continue
                path = self.files["camera_image"].path
                try:
                    stamped[time_ns] = self.transform(matrix, path, f"image pose at {time_ns} ns")
                except InputError as error:  # the image is skipped: /tf may not reach its time
                    self.report.error(path, f"{str(error).removeprefix(f'{path}: ')}; that image is skipped")
                    self.unposed_ns.add(time_ns)
            for time_ns, pose in sorted(stamped.items()):
                scene.add_transform("world", "ego", time_ns, pose)
            sensor_times: list[dict[str, int]] = [{} for _ in times_us]
            lidars = lidar_calibrations(self, scene)
            cameras = camera_calibrations(self, scene, int(times_us[0]) * 1000)
            lidar_points(self, scene, lidars, frame_of_time, poses, sensor_times)
            camera_images(self, scene, cameras, frame_of_time, sensor_times)
            labels = object_labels(self, frame_of_time)
            written: dict[int, int] = {}  # frame of the segment -> its index in the scene
            for i, time_us in enumerate(times_us.tolist()):
                frame_labels = labels[i] if labels is not None else ObjectLabels.empty("ego")
                try:  # a frame the index could not place costs that frame only
                    scene.add_frame(scene.n_frames, time_us * 1000, frame_labels,
                                    sensor_timestamps_ns=dict(sorted(sensor_times[i].items())), annotated=labels is not None)
                except InputError as error:
                    self.report.error(self.files["vehicle_pose"].path, f"frame at {time_us} us: {error}")
                    continue
                written[i] = scene.n_frames - 1
            boxed_ids = None if labels is None else {
                t: id_set(labels[i].boxes.ids) for t, i in frame_of_time.items()}
            projected_boxes(self, scene, {t: written[i] for t, i in frame_of_time.items() if i in written},
                                  boxed_ids, set(cameras))

    def _stats(self) -> dict[str, Any]:
        table = self.read("stats", ["time_of_day", "location", "weather"])
        if table is None or not table.num_rows:
            return {}
        row = table.slice(0, 1).to_pylist()[0]
        return {name: row[self.files["stats"].column(name)] for name in ("time_of_day", "location", "weather")}

    def _camera_box_count(self) -> int:
        table = self.read("camera_box", ["type"], (TIME_KEY,))
        return 0 if table is None else table.num_rows
