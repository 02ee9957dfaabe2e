"""KITTI object tracking (``training/`` and ``testing/`` with calib, oxts, label_02, velodyne, image_02/03).

One scene per sequence, named ``<split>_<sequence>`` (``training_0001``). Frames are oxts packets:
KITTI tracking has no timestamp files, so frame k is at k·100 ms (10 Hz), scene-relative, and the
scene metadata says the times are nominal. ``world`` is the first oxts pose and ``ego`` the IMU/GPS
body frame (x forward, y left, z up); ``ego/velodyne`` = ``Tr_imu_velo^-1``, the rectified cameras
``ego/cam0..cam3`` from ``R_rect · Tr_velo_cam`` and the 4th columns of P0..P3 (see ``geometry``).
Calibration files use ``R_rect``, ``Tr_velo_cam``, ``Tr_imu_velo`` without colons; both spellings are read.

Labels: ``track_id`` becomes the object id; truncation is a level 0/1/2 (not a fraction), kept as
``kitti_truncation_level`` in the extras, and the camera-2 truncation fraction is 0 for level 0 and
unknown (NaN) otherwise. A partial copy (velodyne or images for some frames only) converts every
pose and label and warns once per sensor folder about the frames without files. A sequence without an oxts
file (as AB3DMOT shares its validation sequences) converts with identity poses, so ``world`` is the ego frame
of each frame (no ego motion): one warning, and the scene metadata's ``world_origin`` and ``pose`` say so;
its frames run to its last labelled frame or sensor file.
"""

from __future__ import annotations

from pathlib import PurePosixPath

import numpy as np

from avdata.converters.base import Report
from avdata.converters.kitti import common
from avdata.errors import InputError
from avdata.frames import Transform
from avdata.inputs import Source, is_present, list_names, require_file
from avdata.schema import DatasetWriter, ObjectLabels
from avdata.sources.kitti import (
    KittiLabels,
    geometry,
    png_size,
    read_calib,
    read_labels,
    read_oxts_file,
    velodyne_problem,
)

SPLITS = ("training", "testing")
CAMERAS = (2, 3)


class KittiTrackingConverter(common.KittiConverter):
    """KITTI tracking: one scene per sequence; labels with track ids, oxts poses, velodyne, image_02/03."""

    name = "kitti-tracking"
    source = "kitti-tracking"
    reads_stores = True

    def source_version(self) -> str:
        """The source's version, for the manifest."""
        return "KITTI tracking 2012"

    def list_scenes(self) -> list[str]:
        """Every scene of the source, in a stable order."""
        src = self.config.src
        if not (src / "training").is_dir() and not (src / "testing").is_dir():
            raise InputError(f"{src}: expected the folder that contains training/ (and testing/), got neither")
        scenes: list[str] = []
        for split in SPLITS:
            sequences: set[str] = set()
            for folder in ("calib", "oxts", "label_02"):
                directory = src / split / folder
                if directory.is_dir():
                    sequences.update(n[:-4] for n in list_names(directory) if n.endswith(".txt") and n[:-4].isdigit())
            for folder in ("velodyne", "image_02", "image_03"):
                directory = src / split / folder
                if directory.is_dir():
                    sequences.update(n for n in list_names(directory) if n.isdigit())
            scenes.extend(f"{split}_{sequence}" for sequence in sorted(sequences))
        return scenes

    def source_files(self, scene: str) -> list[Source]:
        """The files this scene is made from (its resume fingerprint covers them)."""
        split, _, sequence = scene.rpartition("_")
        root = self.config.src / split
        texts = [root / folder / f"{sequence}.txt" for folder in ("calib", "oxts", "label_02")]
        sensors = [root / folder / sequence / name for folder in ("velodyne", "image_02", "image_03")
                   for name in _names(root / folder / sequence)]
        return texts + sensors

    def convert_scene(self, scene: str, writer: DatasetWriter, report: Report) -> None:
        """Converts one scene into writer; problems of single records go to report."""
        split, _, sequence = scene.rpartition("_")
        root = self.config.src / split
        calib = read_calib(root / "calib" / f"{sequence}.txt")
        common.report_calib_warnings(report, calib)
        if calib.imu_to_velo is None:
            raise InputError(f"{root / 'calib' / f'{sequence}.txt'}: expected Tr_imu_velo (the ego frame is the IMU)")
        oxts_path = root / "oxts" / f"{sequence}.txt"
        if is_present(oxts_path):
            n_frames, bad_frames, world_T_ego = self._oxts_poses(oxts_path, report)
            pose_origin = "the first oxts pose (IMU/GPS unit) of the sequence"
            pose = ("oxts: Mercator with the first packet's latitude scale; R = Rz(yaw) Ry(pitch) Rx(roll), "
                    "yaw 0 = east, counter-clockwise")
        else:
            # AB3DMOT's validation sequences are shared without oxts; they are still usable in the sensor frame.
            n_frames = self._frames_without_oxts(root, sequence)
            bad_frames = set()
            world_T_ego = Transform(rotation=np.tile(np.eye(3), (n_frames, 1, 1)), translation=np.zeros((n_frames, 3)))
            report.warn(oxts_path, "no oxts file: every ego pose is the identity (world = the ego frame of each "
                                   "frame, no ego motion); frames from the labels and sensor files")
            pose_origin = "no oxts file: the ego (IMU) frame of every frame; world_T_ego is the identity"
            pose = "none: no oxts file, identity poses (objects' world boxes are ego boxes; speeds include ego motion)"
        labels = self._labels(root / "label_02" / f"{sequence}.txt", n_frames, split, report)
        files, sizes = self._sensor_files(root, sequence, n_frames, report)
        ego_T_velo = geometry.rigid(calib.imu_to_velo).inverse()
        ego_T_cam0 = ego_T_velo @ geometry.velo_T_sensors(calib)["cam0"]
        metadata = {
            "split": split,
            "kitti_sequence": sequence,
            "world_origin": pose_origin,
            "ego_origin": "the OXTS RT3003 IMU/GPS unit, axes x forward, y left, z up",
            "time": "nominal: frame k at k * 100 ms, scene-relative (KITTI tracking has no timestamp files); "
                    "the real sweep period is ~103 ms and synced oxts packets are 100 or 110 ms apart, so "
                    "speeds from these times read ~3 % high on average and up to 10 % on single frames",
            "time_nominal": True,
            "pose": pose,
            "source_frames": {
                "labels": "rectified camera 0 (x right, y down, z forward), bottom centre, h w l, rotation_y",
                "ego/cam0..cam3": "rectified cameras at their own optical centres; cam_i_T_cam0 = (I, K_i^-1 P_i[:, 3]); "
                                  "CameraCalibration P = [K_i | 0] in that frame; KITTI's matrices in kitti_calibration",
                "ego/cam0_unrectified": "camera 0 before R_rect (Tr_velo_cam's target)",
            },
            "occlusion": "KITTI occluded 0..3 stored as is (same scale as avdata's)",
            "kitti_calibration": common.source_calibration(calib),
        }
        velo = common.sensor(geometry.VELODYNE)
        with writer.scene(scene, metadata) as out:
            out.add_agent(common.AGENT, kind="vehicle", origin="OXTS IMU/GPS unit")
            common.declare_sensors(out, [0, 1, 2, 3], sizes)
            out.add_static_transform(common.AGENT, velo, ego_T_velo)
            common.write_calibration(out, 0, calib, ego_T_velo, [0, 1, 2, 3], sizes, stamped=False)
            frame_index = 0
            for kitti_frame in range(n_frames):
                if kitti_frame in bad_frames:
                    continue
                time_ns = kitti_frame * common.PERIOD_NS
                out.add_transform("world", common.AGENT, time_ns, world_T_ego[kitti_frame])
                sensor_times = {}
                for name, path in files[kitti_frame].items():
                    add = common.add_velodyne if name == velo else common.add_png
                    if add(out, name, time_ns, path, report, f"frame {kitti_frame}"):
                        sensor_times[name] = time_ns
                if labels is None:
                    out.add_frame(frame_index, time_ns, ObjectLabels.empty("world"), sensor_times, annotated=False)
                else:
                    rows = labels.select(labels.frame == kitti_frame)
                    world_T_cam0 = world_T_ego[kitti_frame] @ ego_T_cam0
                    [(objects, visibility)] = common.camera_labels([(rows, rows.track_id.astype(str), world_T_cam0)],
                                                                   tracking=True)
                    out.add_frame(frame_index, time_ns, objects, sensor_times)
                    out.add_visibility(common.sensor("cam2"), frame_index, time_ns, visibility)
                frame_index += 1

    def _oxts_poses(self, oxts_path: Source, report: Report) -> tuple[int, set[int], Transform]:
        """(frames, frames without a pose, world_T_ego per frame) from a sequence's oxts file."""
        require_file(oxts_path, "oxts file")
        oxts, oxts_problems = read_oxts_file(oxts_path)
        if not len(oxts):
            raise InputError(f"{oxts_path}: expected one oxts packet per frame, got an empty file")
        n_frames = len(oxts)
        posed = ~np.isnan(oxts[:, 0])
        bad_frames = set(np.flatnonzero(~posed).tolist())
        for (line, problem), frame in zip(oxts_problems, sorted(bad_frames), strict=True):
            report.error(oxts_path, f"line {line}: {problem}; frame {frame} skipped (no pose)")
        if not np.any(posed):
            raise InputError(f"{oxts_path}: no readable oxts packet; the sequence has no ego poses")
        # Two real packets always differ (IMU noise in every last digit); a repeated line would give each later
        # frame the pose of the frame before it, so no pose of the sequence can be trusted.
        repeated = np.flatnonzero(np.all(oxts[1:] == oxts[:-1], axis=1))
        if len(repeated):
            line = int(repeated[0]) + 1
            raise InputError(f"{oxts_path}: packets {line} and {line + 1} (0-based frames {line - 1} and {line}) are "
                             f"identical: a repeated line shifts every later frame's pose by one; the sequence is refused")
        # world is the first readable packet's pose; rows of unreadable packets are never looked up.
        world_T_ego = geometry.oxts_poses(oxts[posed])[np.cumsum(posed) - 1]
        return n_frames, bad_frames, world_T_ego

    def _frames_without_oxts(self, root: Source, sequence: str) -> int:
        """Frames of a sequence without oxts: up to its last labelled frame or sensor file."""
        last = -1
        label_path = root / "label_02" / f"{sequence}.txt"
        if is_present(label_path):
            frames = read_labels(label_path, tracking=True)[0].frame
            last = int(frames.max(initial=-1))
        for folder in ("velodyne", "image_02", "image_03"):
            # six ASCII digits: the only names looked up per frame (a damaged 999999999999.bin would be 10^12 frames)
            names = [stem for stem in (PurePosixPath(n).stem for n in _names(root / folder / sequence))
                     if len(stem) == 6 and stem.isascii() and stem.isdigit()]
            last = max([last, *map(int, names)])
        if last < 0:
            raise InputError(f"{root / 'oxts' / f'{sequence}.txt'}: no oxts file, no labels and no sensor files: "
                             f"the sequence has no frames")
        return last + 1

    def _labels(self, path: Source, n_frames: int, split: str, report: Report) -> KittiLabels | None:
        if split == "testing" and not is_present(path):
            return None
        require_file(path, "label file")
        labels, problems = read_labels(path, tracking=True)
        for problem in problems:
            written = f", frame {problem.frame} written without it" if problem.frame >= 0 else ""
            report.error(path, f"{problem.message}; object dropped{written}")
        beyond = labels.frame >= n_frames
        if np.any(beyond):
            # Labels of a frame without a pose: a damaged frame number, or an oxts file missing packets (each
            # missing line would also shift the poses after it); either way input is damaged, not partial.
            report.error(path, f"line {int(labels.line[beyond][0])}: labels for frames up to "
                               f"{int(labels.frame.max())}, but the oxts file has {n_frames} packets (frames 0.."
                               f"{n_frames - 1}); {int(beyond.sum())} label line(s) dropped")
        return labels

    def _sensor_files(self, root: Source, sequence: str, n_frames: int,
                      report: Report) -> tuple[list[dict[str, Source]], dict[int, tuple[int, int]]]:
        """Per frame, the sensor files that exist and are readable (a damaged one costs itself); image sizes."""
        decode = self.options.decode_images
        files: list[dict[str, Source]] = [{} for _ in range(n_frames)]
        sizes: dict[int, tuple[int, int]] = {}
        folders: list[tuple[str, str, str, int | None]] = [("velodyne", ".bin", common.sensor(geometry.VELODYNE), None)]
        folders += [(f"image_0{i}", ".png", common.sensor(geometry.camera_frame(i)), i) for i in CAMERAS]
        for folder, suffix, name, camera in folders:
            directory = root / folder / sequence
            # One listing per folder instead of a look-up per frame (a request each in an object store).
            present = set(_all_names(directory))
            missing = []
            for frame in range(n_frames):
                path = directory / f"{frame:06d}{suffix}"
                if path.name not in present:
                    missing.append(path.name)
                    continue
                try:
                    if not path.is_file():  # a folder, a broken link or a FIFO is damage, not a partial download
                        raise InputError(f"{path}: expected a file, got a folder, a broken link or a special file")
                    if camera is None:
                        problem = velodyne_problem(path)
                        if problem is not None:
                            raise InputError(f"{path}: {problem}")
                    else:
                        size = png_size(path, decode=decode)
                        if sizes.setdefault(camera, size) != size:
                            raise InputError(f"{path}: expected {sizes[camera]} pixels like the sequence's first "
                                             f"image, got {size}")
                except InputError as error:  # like a missing file, it costs itself: the frame keeps the rest
                    report.error(path, f"{error}; frame {frame} written without it")
                    continue
                files[frame][name] = path
            beyond = sorted(name for name in present if name.endswith(suffix) and len(name) == 6 + len(suffix)
                            and name[:6].isascii() and name[:6].isdigit() and int(name[:6]) >= n_frames)
            if beyond:  # (not only frame n_frames': a scan of frame 999 was dropped without a word)
                first = int(beyond[0][:6])
                more = f" (and {len(beyond) - 1} more)" if len(beyond) > 1 else ""
                report.error(directory / beyond[0], f"a file of frame {first}{more}, but the oxts file has {n_frames} "
                                                    f"packets (frames 0..{n_frames - 1}): frames without a pose are not "
                                                    f"converted (packets missing?)")
            if missing:
                report.warn(directory, f"{len(missing)} of {n_frames} frames have no {suffix} file (first: "
                                       f"{missing[0]}); they are written with labels and poses only (partial download?)")
        return files, sizes


def _all_names(folder: Source) -> list[str]:
    """Every name in ``folder`` (none when it is not a folder)."""
    return list_names(folder) if folder.is_dir() else []


def _names(folder: Source) -> list[str]:
    """The names ``folder.glob("*")`` gives: every name but hidden ones (none when it is not a folder)."""
    return [name for name in _all_names(folder) if not name.startswith(".")]
