"""KITTI raw, synced and rectified drives (``<date>/<date>_drive_<n>_sync/`` beside the day's calib files).

SRC is the folder holding the date folders (``2011_09_26/``), or one date folder itself. One scene
per drive, named as the drive folder (``2011_09_26_drive_0001_sync``).

Times are real: every sensor's ``timestamps.txt`` is parsed to int64 ns exactly (the files carry no
zone; read as UTC). Frame i is at the oxts packet's time: ``world_T_ego`` is written at the oxts times
and each sensor message at its own time (the ``sensor_timestamps_ns`` of the frame). The first
velodyne sweep and images can precede the first oxts packet (by ~13 ms in 2011_09_26_drive_0001), and
the last ones follow the last packet: so that every message has a world pose, one extra ``world_T_ego``
sample is written at the earliest (latest) message time, moved from the first (last) packet's pose at
that packet's constant body velocity and turn rates, when the gap is at most 100 ms (scene metadata
``pose_extrapolated_ns``).

``world`` is the first oxts pose, ``ego`` the IMU/GPS body frame (x forward, y left, z up),
``ego/velodyne`` = ``T_imu_to_velo^-1``, ``ego/cam0..cam3`` the rectified cameras from
``R_rect_00 · T_velo_to_cam`` and ``P_rect_0i``. ``tracklet_labels.xml`` is read when present: boxes
(bottom centre, h w l, yaw about velodyne z) go to ``world``; its occlusion (0 visible, 1 partly, 2 fully)
and truncation (0 in image, 1 truncated, 2 out of image, 99 behind) levels become camera-2 visibility
and the extras ``kitti_occlusion_level`` / ``kitti_truncation_level``. Without it frames are not annotated.
"""

from __future__ import annotations

import fnmatch

import numpy as np

from avdata.converters.base import Report
from avdata.converters.kitti import common
from avdata.errors import InputError
from avdata.frames import Boxes3D, Transform
from avdata.inputs import Source, files_under, folder_entries, is_present, list_names, read_text_bytes
from avdata.schema import DatasetWriter, ObjectLabels, VisibilityLabels
from avdata.sources.kitti import (
    Tracklets,
    geometry,
    png_size,
    read_oxts_lines,
    read_raw_calib,
    read_timestamps,
    read_tracklets,
    unified_classes,
    velodyne_problem,
)

CAMERAS = (0, 1, 2, 3)
#: The longest gap between the first (last) oxts packet and a sensor message bridged by extrapolation.
_MAX_POSE_EXTRAPOLATION_NS = 100_000_000


class KittiRawConverter(common.KittiConverter):
    """KITTI raw synced+rectified drives: oxts poses, velodyne, four cameras, tracklets when present."""

    name = "kitti-raw"
    source = "kitti-raw"
    reads_stores = True

    def source_version(self) -> str:
        """The source's version, for the manifest."""
        return "KITTI raw 2011 (synced + rectified)"

    def _drives(self) -> dict[str, Source]:
        src = self.config.src
        # A calib_cam_to_cam.txt that is a folder, a broken link or a FIFO still marks a date folder: its drives
        # then fail with that named, instead of the date being left out without a word.
        if is_present(src / "calib_cam_to_cam.txt"):
            dates = [src]
        elif src.is_dir():
            dates = [p for p in folder_entries(src) if p.is_dir() and is_present(p / "calib_cam_to_cam.txt")]
        else:
            dates = []
        if not dates:
            raise InputError(f"{src}: expected date folders (2011_09_26/) holding calib_cam_to_cam.txt, got none")
        return {p.name: p for date in dates for p in folder_entries(date) if p.is_dir() and p.name.endswith("_sync")}

    def list_scenes(self) -> list[str]:
        """Every scene of the source, in a stable order."""
        return sorted(self._drives())

    def source_files(self, scene: str) -> list[Source]:
        """The files this scene is made from (its resume fingerprint covers them)."""
        drive = self._drives()[scene]
        calibrations = [p for p in folder_entries(drive.parent) if fnmatch.fnmatchcase(p.name, "calib_*.txt")]
        return calibrations + files_under(drive)

    def convert_scene(self, scene: str, writer: DatasetWriter, report: Report) -> None:
        """Converts one scene into writer; problems of single records go to report."""
        drive = self._drives()[scene]
        calib = read_raw_calib(drive.parent)
        common.report_calib_warnings(report, calib)
        if calib.imu_to_velo is None or calib.image_size is None:
            raise InputError(f"{drive.parent}: expected calib_imu_to_velo.txt and S_rect_0i sizes, got neither")
        oxts_times, bad_times = read_timestamps(drive / "oxts" / "timestamps.txt")
        oxts, frames = self._oxts(drive, oxts_times, bad_times, report)
        world_T_ego = geometry.oxts_poses(oxts)
        ego_T_velo = geometry.rigid(calib.imu_to_velo).inverse()
        sizes = {i: (int(calib.image_size[i][0]), int(calib.image_size[i][1])) for i in CAMERAS}
        sensors = self._sensors(drive, len(oxts_times), report)
        tracklets = self._tracklets(drive / "tracklet_labels.xml", report)
        if tracklets is not None and np.any(beyond := tracklets.frame >= len(oxts_times)):  # a damaged first_frame
            ids = sorted(set(tracklets.tracklet[beyond].tolist()))
            report.warn(drive / "tracklet_labels.xml", f"tracklets {ids[:5]}: expected poses within the drive's "
                                                       f"{len(oxts_times)} frames, got up to frame "
                                                       f"{int(tracklets.frame[beyond].max())}; {int(beyond.sum())} box(es) "
                                                       "left out")
        metadata = {
            "kitti_drive": scene,
            "world_origin": "the first oxts pose (IMU/GPS unit) of the drive",
            "ego_origin": "the OXTS RT3003 IMU/GPS unit, axes x forward, y left, z up",
            "time": "UTC epoch ns from the drive's timestamps.txt files (no zone in the files; read as UTC); "
                    "frame time = the oxts packet's time",
            "time_nominal": False,
            "pose": "oxts: Mercator with the first packet's latitude scale; R = Rz(yaw) Ry(pitch) Rx(roll), "
                    "yaw 0 = east, counter-clockwise",
            "source_frames": {
                "tracklets": "velodyne frame, bottom centre, h w l, yaw about z",
                "ego/cam0..cam3": "rectified cameras at their own optical centres; cam_i_T_cam0 = (I, K_i^-1 P_rect_0i[:, 3]); "
                                  "CameraCalibration P = [K_i | 0] in that frame; KITTI's matrices in kitti_calibration",
                "ego/cam0_unrectified": "camera 0 before R_rect_00 (T_velo_to_cam's target)",
            },
            "annotated": tracklets is not None,
            "kitti_calibration": common.source_calibration(calib),
        }
        sensor_ns = [int(times[f]) for times, paths in sensors.values() for f in frames if paths[f] is not None]
        first_ns, last_ns = int(oxts_times[frames[0]]), int(oxts_times[frames[-1]])
        before_ns = min(sensor_ns, default=first_ns)
        after_ns = max(sensor_ns, default=last_ns)
        before_ns = before_ns if 0 < first_ns - before_ns <= _MAX_POSE_EXTRAPOLATION_NS else first_ns
        after_ns = after_ns if 0 < after_ns - last_ns <= _MAX_POSE_EXTRAPOLATION_NS else last_ns
        metadata["pose_extrapolated_ns"] = [first_ns - before_ns, after_ns - last_ns]
        velo = common.sensor(geometry.VELODYNE)
        with writer.scene(scene, metadata) as out:
            out.add_agent(common.AGENT, kind="vehicle", origin="OXTS IMU/GPS unit")
            common.declare_sensors(out, list(CAMERAS), sizes)
            out.add_static_transform(common.AGENT, velo, ego_T_velo)
            common.write_calibration(out, before_ns, calib, ego_T_velo, list(CAMERAS), sizes, stamped=False)
            if before_ns < first_ns:
                out.add_transform("world", common.AGENT, before_ns, geometry.extrapolate_pose(
                    world_T_ego[0], oxts[0], (before_ns - first_ns) / 1e9))
            for frame_index, frame in enumerate(frames):
                world_T_ego_i = world_T_ego[frame_index]
                time_ns = int(oxts_times[frame])
                out.add_transform("world", common.AGENT, time_ns, world_T_ego_i)
                sensor_times = {}
                for name, (times, paths) in sensors.items():
                    path = paths[frame]
                    if path is None:
                        continue
                    add = common.add_velodyne if name == velo else common.add_png
                    if add(out, name, int(times[frame]), path, report, f"frame {frame}"):
                        sensor_times[name] = int(times[frame])
                if tracklets is None:
                    out.add_frame(frame_index, time_ns, ObjectLabels.empty("world"), sensor_times, annotated=False)
                    continue
                rows = tracklets.select(tracklets.frame == frame)
                objects, visibility = _tracklet_labels(rows, world_T_ego_i @ ego_T_velo)
                out.add_frame(frame_index, time_ns, objects, sensor_times)
                out.add_visibility(common.sensor("cam2"), frame_index, time_ns, visibility)
            if after_ns > last_ns:
                out.add_transform("world", common.AGENT, after_ns, geometry.extrapolate_pose(
                    world_T_ego[len(frames) - 1], oxts[-1], (after_ns - last_ns) / 1e9))

    def _oxts(self, drive: Source, oxts_times: np.ndarray, bad_times: dict[int, str],
              report: Report) -> tuple[np.ndarray, list[int]]:
        """(F, 30) packets of the frames with a readable oxts file and a usable time, and those frame numbers.

        Problems shared by many frames are reported once, with the frame ranges ("frames 1-107: oxts
        packet missing").
        """
        data_dir = drive / "oxts" / "data"
        times_path = drive / "oxts" / "timestamps.txt"
        # One listing instead of a look-up per packet (a request each in an object store).
        names = set(list_names(data_dir)) if data_dir.is_dir() else set()
        existing = sorted(int(name[:-4]) for name in names if name.endswith(".txt") and name[:-4].isascii()
                          and name[:-4].isdigit())
        n_frames = max(len(oxts_times), existing[-1] + 1 if existing else 0)
        if n_frames > len(oxts_times):
            # the packets there are (a damaged name such as 99999999999.txt must not make a list of 10^11 frames)
            untimed = [frame for frame in existing if frame >= len(oxts_times)]
            report.error(times_path, f"expected a time per oxts packet, got {len(oxts_times)} lines for "
                                     f"{n_frames} packets; frames {common.frame_ranges(untimed)} skipped (no time)")
        for frame, message in bad_times.items():  # a malformed line costs its frame
            report.error(times_path, f"{message}; frame {frame} skipped (no time)")
        later = [f for f in _not_increasing(oxts_times).tolist() if f not in bad_times]
        for frame in later:
            report.error(times_path, f"line {frame + 1}: expected times increasing, got {oxts_times[frame]} ns after "
                                     f"{oxts_times[:frame].max()} ns; frame {frame} skipped")
        skipped = set(later) | set(bad_times)
        packets, frames = [], []
        missing: list[int] = []
        for frame in range(len(oxts_times)):
            if frame in skipped:
                continue
            path = data_dir / f"{frame:010d}.txt"
            if path.name not in names:
                missing.append(frame)
                continue
            try:
                lines = [line for line in read_text_bytes(path).decode().splitlines() if line.strip()]
                if len(lines) != 1:
                    raise InputError(f"expected one oxts packet line, got {len(lines)}")
                packets.append(read_oxts_lines(path, lines))
            except (InputError, OSError, UnicodeDecodeError) as error:
                report.error(path, f"{str(error).removeprefix(f'{path}: ')}; frame {frame} skipped (no pose)")
                continue
            frames.append(frame)
        if missing:
            report.error(data_dir, f"frames {common.frame_ranges(missing)}: oxts packet missing; skipped (no pose)")
        if not frames:
            raise InputError(f"{data_dir}: no readable oxts packet; the drive has no poses")
        return np.concatenate(packets), frames

    @staticmethod
    def _tracklets(path: Source, report: Report) -> Tracklets | None:
        """The drive's tracklets; None when it has none or they are unreadable (then the drive is written unlabelled).

        The labels are one record of the drive: a damaged file costs them, not the poses and sensor data.
        """
        if not is_present(path):
            return None
        try:
            return read_tracklets(path)
        except InputError as error:
            report.error(path, f"{error}; the drive is written without labels")
            return None

    def _sensors(self, drive: Source, n_frames: int,
                 report: Report) -> dict[str, tuple[np.ndarray, list[Source | None]]]:
        """Sensor frame -> (timestamps (T,), per frame its readable file or None)."""
        decode = self.options.decode_images
        folders = [("velodyne_points", ".bin", common.sensor(geometry.VELODYNE))]
        folders += [(f"image_0{i}", ".png", common.sensor(geometry.camera_frame(i))) for i in CAMERAS]
        out: dict[str, tuple[np.ndarray, list[Source | None]]] = {}
        for folder, suffix, name in folders:
            directory = drive / folder
            stamps = directory / "timestamps.txt"
            if not is_present(stamps):
                report.warn(directory, "no timestamps.txt: this sensor is not written (partial download?)")
                continue
            if not stamps.is_file():  # a folder, a broken link or a FIFO is damage, not a partial download
                report.error(stamps, "expected a file, got a folder, a broken link or a special file; this sensor is "
                                     "not written")
                continue
            times, bad_times = read_timestamps(stamps)
            for frame, message in bad_times.items():  # a malformed line costs this sensor in its frame
                report.error(stamps, f"{message}; frame {frame} written without this sensor")
            existing = set(list_names(directory / "data")) if (directory / "data").is_dir() else set()
            # A message not later than the sensor's previous one would give the topic a step back in time.
            untimely = set(_not_increasing(times).tolist()) - set(bad_times)
            if untimely:
                plural = "s" if len(untimely) > 1 else ""
                report.error(directory / "timestamps.txt",
                             f"line{plural} {common.frame_ranges([f + 1 for f in untimely])}: expected times increasing, "
                             f"got repeated or earlier times; frame{plural} {common.frame_ranges(sorted(untimely))} "
                             f"written without this sensor")
            paths: list[Source | None] = []
            missing = []
            untimed = []  # files that are there but have no line in timestamps.txt: the file is damaged, not partial
            for frame in range(n_frames):
                path = directory / "data" / f"{frame:010d}{suffix}"
                if frame in untimely or frame in bad_times:
                    paths.append(None)
                    continue
                if frame >= len(times) and path.name in existing:
                    untimed.append(frame)
                    paths.append(None)
                    continue
                if frame >= len(times) or path.name not in existing:
                    missing.append(path.name)
                    paths.append(None)
                    continue
                problem = velodyne_problem(path) if suffix == ".bin" else None
                try:
                    if problem is not None:
                        raise InputError(f"{path}: {problem}")
                    if suffix == ".png":
                        png_size(path, decode=decode)
                except InputError as error:
                    report.error(path, f"{error}; file skipped, frame {frame} written without it")
                    paths.append(None)
                    continue
                paths.append(path)
            if untimed:
                report.error(stamps, f"expected a time per frame ({n_frames}), got {len(times)}; frames "
                                     f"{common.frame_ranges(untimed)} written without this sensor")
            if missing:
                report.warn(directory, f"{len(missing)} of {n_frames} frames have no {suffix} file or timestamp "
                                       f"(first: {missing[0]}); they are written without it (partial download?)")
            out[name] = (times, paths)
        return out


def _tracklet_labels(rows: Tracklets, world_T_velo: Transform) -> tuple[ObjectLabels, VisibilityLabels]:
    """One frame's tracklet poses as objects in ``world`` and camera-2 visibility."""
    velo_R_box = Transform.from_euler("xyz", rows.rotation).rotation.reshape(-1, 3, 3)
    center = rows.translation + velo_R_box[:, :, 2] * (rows.hwl[:, :1] / 2.0)
    ids = rows.tracklet.astype(str)
    boxes = Boxes3D.from_rotation(center, rows.hwl[:, [2, 1, 0]], velo_R_box, common.sensor(geometry.VELODYNE),
                                  ids=ids, classes=unified_classes(rows.cls))
    extras = [{"kitti_occlusion_level": float(o), "kitti_truncation_level": float(t)}
              for o, t in zip(rows.occlusion.tolist(), rows.truncation.tolist(), strict=True)]
    labels = ObjectLabels(boxes=boxes.transform(world_T_velo, "world"), source_classes=rows.cls, extras=extras)
    visibility = VisibilityLabels(
        object_ids=ids,
        in_fov=np.isin(rows.truncation, (0, 1)),
        occlusion=np.array([common.RAW_OCCLUSION.get(o, 3) for o in rows.occlusion.tolist()], dtype=np.int32),
        truncation=np.where(rows.truncation == 0, 0.0, np.nan),
    )
    return labels, visibility


def _not_increasing(times_ns: np.ndarray) -> np.ndarray:
    """(K,) indices of times not later than every time before them (duplicates and steps back)."""
    if not len(times_ns):
        return np.zeros(0, dtype=np.int64)
    previous_max = np.maximum.accumulate(times_ns)
    return np.flatnonzero(times_ns[1:] <= previous_max[:-1]) + 1
