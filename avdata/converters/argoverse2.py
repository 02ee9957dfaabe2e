"""Argoverse 2 sensor dataset (``AV2_ROOT/{train,val,test}/<log_id>/``) -> the unified format.

The source's rows of docs/conventions.md, and what this module does with each (av2-api 0.3.6 is the
reference; ``avdata.sources.argoverse2`` reads the files):

=================  ==========================================================================
Argoverse 2        how it is converted
=================  ==========================================================================
scenes             one scene per log, named by its log id; the split is in the metadata
``world``          the log's city frame (e.g. PIT), z up, as ``city_SE3_egovehicle`` gives it;
                   not re-centred (origin = the city map's origin)
ego poses          every ``city_SE3_egovehicle`` row (lidar and camera times) -> ``world -> ego``
                   on ``/tf`` at that row's timestamp
ego frame          egovehicle: x forward, y left, z up, rear-axle centre on the ground
frames             one per lidar sweep (10 Hz) and per annotation timestamp; ``annotated`` when the
                   log has ``annotations.feather`` (train/val; test logs have none)
lidar              a sweep is stored in the egovehicle frame at its timestamp, motion-compensated,
                   both lidars stacked. Points are kept untouched in ``ego/lidar``: a frame equal to
                   ``ego`` (identity on ``/tf_static``), stamped with the sweep time, so
                   ``world_T_lidar(t) = world_T_ego(t)`` exactly as av2 applies
                   ``city_SE3_egovehicle`` to a sweep. Fields x, y, z float32 (float16 widened:
                   exact, ``float16(x) == original``), intensity uint8, laser_number uint8 (0-63
                   over both lidars), offset_ns int32, all as stored. The two lidars' own poses
                   are on ``/tf_static`` as ``ego/up_lidar``, ``ego/down_lidar``
cameras            already optical -> ``ego/<camera>`` with ``egovehicle_SE3_sensor`` as is; JPEG
                   bytes untouched; CameraCalibration K from fx, fy, cx, cy and
                   D = (k1, k2, 0, 0, k3) plumb_bob (AV2's radial model, no tangential terms);
                   images are *not* undistorted (av2's ``PinholeCamera`` projects without D)
cuboids            centre/size l, w, h/quaternion (w, x, y, z) in egovehicle at the sweep time ->
                   ``Boxes3D.from_av2`` in ``ego`` -> ``world`` through the pose at that exact
                   timestamp (av2: ``CuboidList.transform(city_SE3_ego)``)
ids, classes       ``track_uuid`` (stable within a log) -> object id; ``category`` kept verbatim
                   as the source class, mapped to the unified taxonomy (``CLASS_MAP``);
                   ``num_interior_pts`` in the extras
time               int64 ns as AV2 stores them; they count from near the GPS epoch (1980), not
                   capture UTC (AV2 shifts its clocks), so the metadata flags them
=================  ==========================================================================

Bad input costs the record it is in: a missing or unreadable sweep loses that sweep's points (the
frame keeps its labels), an impossible annotation row (null, negative time, absurd number) loses that
row, a bad intrinsics row that camera, a sensor pose given twice that sensor; an annotation table of 0
rows leaves the frames unannotated; a missing or damaged pose table, calibration or log folder loses
the log. Each is one error line naming the file.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from avdata.converters.base import Converter, Report
from avdata.errors import InputError
from avdata.frames import Boxes3D, Transform
from avdata.inputs import Source, files_under, folder_entries, read_regular_file
from avdata.schema import DatasetWriter, ObjectLabels
from avdata.sources import argoverse2 as av2
from avdata.sources.jpeg import jpeg_problem

#: The splits of a sensor-dataset root, in the order their logs are listed.
SPLITS: tuple[str, ...] = ("train", "val", "test")

#: The sensor frame holding each sweep's points (identical to ``ego``; see the module docstring).
LIDAR_FRAME = "ego/lidar"

#: Files every log folder must hold (annotations only outside the test split).
REQUIRED_FILES: tuple[str, ...] = ("city_SE3_egovehicle.feather", "calibration/egovehicle_SE3_sensor.feather")



class Argoverse2Converter(Converter):
    """Argoverse 2 sensor dataset: log folders under train/, val/ and test/ (lidar, ring cameras, cuboids)."""

    name = "argoverse2"
    source = "argoverse2-sensor"
    licence = "CC BY-NC-SA 4.0"
    reads_stores = True

    def source_version(self) -> str:
        """The source's version, for the manifest."""
        return "2.0"

    def _logs(self) -> tuple[dict[str, Source], dict[str, list[Source]]]:
        """(log id -> log folder, log id -> later folders of the same id, ignored); splits in SPLITS order."""
        root = self.config.src
        folders = {p.name: p for p in folder_entries(root) if p.is_dir()}
        splits = [folders[s] for s in SPLITS if s in folders]
        if not splits:
            raise InputError(f"{root}: expected an Argoverse 2 sensor root holding {'/, '.join(SPLITS)}/, got none of them")
        logs: dict[str, Source] = {}
        duplicates: dict[str, list[Source]] = {}
        for split in splits:
            for log_dir in (p for p in folder_entries(split) if p.is_dir()):
                if log_dir.name in logs:
                    duplicates.setdefault(log_dir.name, []).append(log_dir)
                else:
                    logs[log_dir.name] = log_dir
        return logs, duplicates

    def list_scenes(self) -> list[str]:
        """Every scene of the source, in a stable order."""
        return sorted(self._logs()[0])

    def source_files(self, scene: str) -> list[Source]:
        """Every file of the log's folder (and of a same-named log in another split, which is reported)."""
        logs, duplicates = self._logs()
        return [p for folder in [logs[scene], *duplicates.get(scene, [])] for p in files_under(folder)]

    def convert_scene(self, scene: str, writer: DatasetWriter, report: Report) -> None:
        """Converts one scene into writer; problems of single records go to report."""
        logs, duplicates = self._logs()
        for duplicate in duplicates.get(scene, []):
            report.error(duplicate, f"log id also in {logs[scene].parent.name}/; converted from there only")
        _LogConversion(logs[scene], report).write(writer)


class _LogConversion:
    """Converts one log (kept as one object so its tables die with it)."""

    def __init__(self, log_dir: Source, report: Report):
        self.log_dir = log_dir
        self.report = report
        self.split = log_dir.parent.name
        missing = [f for f in REQUIRED_FILES if not (log_dir / f).is_file()]
        if missing:
            raise InputError(f"{log_dir / missing[0]}: expected this file of the log, got none")
        poses_path = log_dir / "city_SE3_egovehicle.feather"
        self.poses = self._reported(poses_path, av2.read_poses(poses_path), "row dropped; frames at its time lose "
                                    "what needs the ego pose").columns
        if not len(self.poses["timestamp_ns"]):
            raise InputError(f"{poses_path}: expected ego poses, got no usable rows")
        sensors_path = log_dir / "calibration" / "egovehicle_SE3_sensor.feather"
        self.sensor_poses, rows = av2.read_sensor_poses(sensors_path)
        self._reported(sensors_path, rows, "that sensor is not converted")
        self.intrinsics = self._intrinsics()
        self.sweep_times, self.sweep_paths, strays = av2.timestamp_files(log_dir / "sensors" / "lidar", "feather")
        for path in strays:
            report.warn(path, "not a <timestamp_ns>.feather sweep; ignored")
        self.annotations = self._annotations()

    def _intrinsics(self) -> dict[str, av2.Intrinsics]:
        path = self.log_dir / "calibration" / "intrinsics.feather"
        try:
            intrinsics, dropped = av2.read_intrinsics(path)
        except InputError as error:
            self.report.error(path, f"{error}; cameras skipped")
            return {}
        for message in dropped:
            self.report.error(path, message)
        unknown = sorted(set(intrinsics) - set(self.sensor_poses))
        if unknown:
            self.report.error(path, f"cameras {unknown} have intrinsics but no pose in egovehicle_SE3_sensor.feather; skipped")
        return {name: value for name, value in intrinsics.items() if name in self.sensor_poses}

    def _annotations(self) -> dict[str, np.ndarray] | None:
        """The good annotation rows, or None when the log has no (readable) annotations."""
        path = self.log_dir / "annotations.feather"
        if not path.is_file():
            if self.split != "test":
                self.report.error(path, f"expected the annotations of a {self.split} log, got none; frames unannotated")
            return None
        try:
            rows = av2.read_annotations(path)
        except InputError as error:
            self.report.error(path, f"{error}; frames unannotated")
            return None
        if not len(rows.columns["timestamp_ns"]) and not rows.dropped:  # a train/val log always has cuboids
            self.report.error(path, "expected the cuboids of an annotated log, got 0 rows; frames unannotated")
            return None
        return self._reported(path, rows, "row dropped").columns

    def _reported(self, path: Source, rows: av2.Rows, cost: str) -> av2.Rows:
        """Reports a table's dropped rows (errors, each with what it costs) and repaired ones (warnings)."""
        for message in rows.dropped:
            self.report.error(path, f"{message}; {cost}")
        for message in rows.repaired:
            self.report.warn(path, message)
        return rows

    def metadata(self) -> dict[str, Any]:
        city = av2.city_name(self.log_dir)
        return {
            "log_id": self.log_dir.name,
            "split": self.split,
            "city": city,
            "world": f"the Argoverse 2 city frame of {city or 'this log'} (city_SE3_egovehicle), z up; not re-centred",
            "ego_origin": "egovehicle: centre of the rear axle on the ground (Argoverse 2)",
            "lidar": (
                "ego/lidar = ego (identity): sweeps as AV2 stores them, motion-compensated into the egovehicle "
                "frame at the sweep time; up_lidar / down_lidar poses on /tf_static; laser_number 0-63 as stored"
            ),
            "time": "int64 ns as Argoverse 2 stores them (shifted clock near the GPS epoch, not capture UTC)",
            "time_is_utc": False,
        }

    def write(self, writer: DatasetWriter) -> None:
        log_dir = self.log_dir
        frame_times = np.union1d(self.sweep_times, self._label_times())
        cameras = self._camera_files()
        with writer.scene(log_dir.name, self.metadata()) as scene:
            scene.add_agent("ego", "vehicle", "egovehicle: centre of the rear axle on the ground")
            start_ns = int(min(self.poses["timestamp_ns"][0], frame_times[0] if len(frame_times) else 2**62))
            scene.add_sensor(LIDAR_FRAME, "lidar", channel="lidar", sources=list(av2.LIDARS), rate_hz=10)
            scene.add_static_transform("ego", LIDAR_FRAME, Transform.identity())
            for name, (quat_wxyz, translation_m) in self.sensor_poses.items():
                scene.add_static_transform("ego", f"ego/{name}", Transform.from_quat_wxyz(quat_wxyz, translation_m))
            for name, intr in self.intrinsics.items():
                frame = f"ego/{name}"
                scene.add_sensor(frame, "camera", channel=name, rate_hz=20, width=intr.width_px, height=intr.height_px)
                scene.add_camera_calibration(frame, start_ns, intr.K, intr.width_px, intr.height_px, D=intr.D_plumb_bob)
            world_T_ego = Transform.from_quat_wxyz(self.poses["quat_wxyz"], self.poses["translation_m"])
            for i, time_ns in enumerate(self.poses["timestamp_ns"].tolist()):
                scene.add_transform("world", "ego", time_ns, world_T_ego[i])
            swept = self._write_sweeps(scene)
            # A sweep lists the nearest image that was written (a damaged one costs only itself).
            written_images = {name: (times[self._write_images(scene, f"ego/{name}", times, paths)], paths)
                              for name, (times, paths) in cameras.items()}
            self._write_frames(scene, frame_times, swept, written_images, world_T_ego)

    def _label_times(self) -> np.ndarray:
        return np.zeros(0, dtype=np.int64) if self.annotations is None else np.unique(self.annotations["timestamp_ns"])

    def _camera_files(self) -> dict[str, tuple[np.ndarray, list[Source]]]:
        """Camera -> (image times (N,), paths) for the cameras with intrinsics."""
        found = {p.name: p for p in folder_entries(self.log_dir / "sensors" / "cameras")}
        out = {}
        for name in self.intrinsics:
            if name not in found:  # a camera without images (the folder is listed only when it is there)
                continue
            times, paths, strays = av2.timestamp_files(found[name], "jpg")
            for path in strays:
                self.report.warn(path, "not a <timestamp_ns>.jpg image; ignored")
            if len(times):
                out[name] = (times, paths)
        for name in sorted(set(found) - set(self.intrinsics)):
            self.report.error(found[name], "camera without intrinsics in calibration/intrinsics.feather; skipped")
        return out

    def _write_sweeps(self, scene: Any) -> set[int]:
        """Writes every readable sweep; returns their times."""
        written: set[int] = set()
        pose_times = self.poses["timestamp_ns"]
        for time_ns, path in zip(self.sweep_times.tolist(), self.sweep_paths, strict=True):
            if not pose_times[0] <= time_ns <= pose_times[-1]:
                continue  # its frame cannot be placed and is refused with one line; points there would fail validate
            try:
                sweep = av2.read_sweep(path)
            except InputError as error:
                self.report.error(path, f"{error}; the frame keeps its labels, without points")
                continue
            scene.add_point_cloud(
                LIDAR_FRAME,
                time_ns,
                {
                    "x": sweep["x"].astype(np.float32),
                    "y": sweep["y"].astype(np.float32),
                    "z": sweep["z"].astype(np.float32),
                    "intensity": sweep["intensity"],
                    "laser_number": sweep["laser_number"],
                    "offset_ns": sweep["offset_ns"],
                },
            )
            written.add(time_ns)
        return written

    def _write_images(self, scene: Any, frame: str, times: np.ndarray, paths: list[Source]) -> np.ndarray:
        """Writes one camera's images; (N,) True where an image was written."""
        written = np.zeros(len(paths), dtype=bool)
        for i, (time_ns, path) in enumerate(zip(times.tolist(), paths, strict=True)):
            try:
                data = read_regular_file(path)  # a FIFO is refused, not waited on
            except InputError as error:
                self.report.error(path, str(error))
                continue
            except OSError as error:  # a folder or a broken link where the image should be
                self.report.error(path, f"cannot read ({error.strerror or error}); skipped")
                continue
            problem, _ = jpeg_problem(data)
            if problem is not None:
                self.report.error(path, f"{problem}; skipped")
                continue
            scene.add_image(frame, time_ns, data, "jpeg")
            written[i] = True
        return written

    def _write_frames(
        self,
        scene: Any,
        frame_times: np.ndarray,
        swept: set[int],
        cameras: dict[str, tuple[np.ndarray, list[Source]]],
        world_T_ego: Transform,
    ) -> None:
        pose_times = self.poses["timestamp_ns"]
        missing = np.setdiff1d(self._label_times(), self.sweep_times).tolist()
        if missing:
            first = self.log_dir / "sensors" / "lidar" / f"{missing[0]}.feather"
            self.report.error(
                first,
                f"missing sweep of an annotated time ({len(missing)} missing in this log, first named); "
                "those frames keep their labels, without points",
            )
        rows_by_time: dict[int, np.ndarray] = {}
        annotations = self.annotations
        if annotations is not None and len(annotations["timestamp_ns"]):  # every row dropped: frames without objects
            times = annotations["timestamp_ns"]
            order = np.argsort(times, kind="stable")
            starts = np.flatnonzero(np.r_[True, times[order][1:] != times[order][:-1]])
            for group in np.split(order, starts[1:]):
                rows_by_time[int(times[group[0]])] = group
        for index, time_ns in enumerate(frame_times.tolist()):
            sensor_times = {LIDAR_FRAME: time_ns} if time_ns in swept else {}
            for name, (image_times, _) in cameras.items():
                if not len(image_times):
                    continue
                nearest = int(np.argmin(np.abs(image_times - time_ns)))
                if abs(int(image_times[nearest]) - time_ns) <= av2.MAX_LIDAR_CAM_TIMESTAMP_DIFF_NS:
                    sensor_times[f"ego/{name}"] = int(image_times[nearest])
            labels = ObjectLabels.empty("world")
            rows = rows_by_time.get(time_ns)
            if annotations is not None and rows is not None:
                pose = int(np.searchsorted(pose_times, time_ns))
                if pose < len(pose_times) and pose_times[pose] == time_ns:
                    labels = _objects(annotations, rows, world_T_ego[pose])
                else:
                    self.report.error(
                        self.log_dir / "annotations.feather",
                        f"timestamp_ns {time_ns}: no ego pose at this time in city_SE3_egovehicle.feather; "
                        f"{len(rows)} cuboids dropped",
                    )
            try:  # a sweep the index could not place (e.g. no ego pose at its time) costs that sweep only
                scene.add_frame(scene.n_frames, time_ns, labels, sensor_timestamps_ns=dict(sorted(sensor_times.items())),
                                annotated=annotations is not None)
            except InputError as error:
                self.report.error(self.log_dir, f"sweep {index}: {error}")


def _objects(annotations: dict[str, np.ndarray], rows: np.ndarray, world_T_ego: Transform) -> ObjectLabels:
    """The cuboids of one sweep (annotation rows ``rows``) as boxes in ``world``."""
    a = annotations
    categories = a["category"][rows]
    boxes_ego = Boxes3D.from_av2(
        np.stack([a["tx_m"][rows], a["ty_m"][rows], a["tz_m"][rows]], axis=1),
        np.stack([a["length_m"][rows], a["width_m"][rows], a["height_m"][rows]], axis=1),
        np.stack([a["qw"][rows], a["qx"][rows], a["qy"][rows], a["qz"][rows]], axis=1),
        "ego",
        ids=a["track_uuid"][rows],
        classes=np.asarray([av2.unified_class(c) for c in categories.tolist()]),
    )
    return ObjectLabels(
        boxes=boxes_ego.transform(world_T_ego, "world"),
        source_classes=categories,
        extras=[{"num_interior_pts": float(n)} for n in a["num_interior_pts"][rows].tolist()],
    )
