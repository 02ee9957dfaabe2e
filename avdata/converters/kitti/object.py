"""KITTI 3D object detection (``training/`` and ``testing/`` with calib, label_2, velodyne, image_2).

Scenes: KITTI object samples are unrelated snapshots (shuffled across drives, each with its own
calibration and no ego pose). A scene per sample would make 7481 files (and as many open readers);
one scene of 7481 frames is awkward to share out. So a scene holds the samples whose ids fall in
``[start, start + scene_size)`` (default 100) and is named ``<split>_<start:06d>``, e.g.
``training_000100``. The original sample id of each frame is in the scene metadata
(``kitti_sample_ids``) and in every object's extras (``kitti_sample``).

Frames and time: there is no ego pose, so ``ego`` is the velodyne-aligned body frame
(``ego/velodyne`` = ego, identity on ``/tf_static``) and ``world`` = ego (an identity pose on ``/tf`` at
every frame). Frame k of a scene is at k·100 ms, scene-relative and flagged nominal. Because every
sample has its own calibration, the camera and IMU poses below ego are written on ``/tf`` at each
frame's time (not ``/tf_static``), and each camera's CameraCalibration at that time too; query them at
the frame's time.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np

from avdata.converters.base import ConvertConfig, Report
from avdata.converters.kitti import common
from avdata.errors import InputError
from avdata.frames import Transform
from avdata.inputs import Source, is_present, list_names, require_file
from avdata.schema import DatasetWriter, ObjectLabels
from avdata.sources.kitti import (
    KittiCalib,
    KittiLabels,
    geometry,
    png_size,
    read_calib,
    read_labels,
    velodyne_problem,
)

SPLITS = ("training", "testing")
_FOLDERS = {"calib": ".txt", "label_2": ".txt", "velodyne": ".bin", "image_2": ".png", "image_3": ".png"}


@dataclass(frozen=True, slots=True, kw_only=True)
class _Sample:
    """One readable sample: its id, calibration, labels (None for testing) and existing files."""

    sample_id: int
    calib: KittiCalib
    labels: KittiLabels | None
    velodyne: Source | None
    images: dict[int, tuple[Source, tuple[int, int]]]


@dataclass(frozen=True, slots=True, kw_only=True)
class KittiObjectOptions(common.KittiOptions):
    """Options of the KITTI object converter."""

    scene_size: int = field(default=100, metadata={
        "help": "samples per scene: ids [k*N, (k+1)*N) form scene <split>_<k*N> (default 100)"})

    def __post_init__(self) -> None:
        if self.scene_size < 1:
            raise InputError(f"expected --scene-size >= 1, got {self.scene_size}")


class KittiObjectConverter(common.KittiConverter):
    """KITTI 3D object detection: training/ and testing/ with calib, label_2, velodyne, image_2 (image_3)."""

    name = "kitti-object"
    source = "kitti-object"
    Options = KittiObjectOptions
    reads_stores = True

    def source_version(self) -> str:
        """The source's version, for the manifest."""
        return "KITTI 3D object 2017"

    def __init__(self, config: ConvertConfig):
        super().__init__(config)
        #: split -> its sorted sample ids (see :meth:`_sample_ids`)
        self._listed_ids: dict[str, list[int]] = {}

    @property
    def _scene_size(self) -> int:
        return int(self.options.scene_size)

    def source_files(self, scene: str) -> list[Source]:
        """The files this scene is made from (its resume fingerprint covers them)."""
        split, _, start_text = scene.rpartition("_")
        folders = [(self.config.src / split / folder, suffix) for folder, suffix in _FOLDERS.items()]
        return [directory / f"{sample_id:06d}{suffix}"
                for sample_id in self._scene_ids(split, int(start_text)) for directory, suffix in folders]

    def _scene_ids(self, split: str, start: int) -> list[int]:
        """The listed sample ids of the scene starting at ``start``.

        Not ``range(start, start + scene_size)``: --scene-size 2**31 made billions of paths (a hang). A sample
        added later is a new listed id, so the resume fingerprint still sees it.
        """
        all_ids = self._sample_ids(split)
        return all_ids[bisect.bisect_left(all_ids, start):bisect.bisect_left(all_ids, start + self._scene_size)]

    def _sample_ids(self, split: str) -> list[int]:
        """The sorted sample ids with any file in ``split``.

        Listed by :meth:`list_scenes` and kept (workers get them with the converter): every scene takes
        its slice, and listing the folders again per scene cost (scenes x samples) name checks.
        """
        listed = self._listed_ids
        if split not in listed:
            ids: set[int] = set()
            for folder, suffix in _FOLDERS.items():
                directory = self.config.src / split / folder
                if not directory.is_dir() and is_present(directory):
                    # else each sample's file is "missing": one error per sample and one for the empty scene
                    raise InputError(f"{directory}: expected a folder of <sample>{suffix} files, got a file, a "
                                     f"broken link or a special file")
                if directory.is_dir():
                    ids.update(int(name[:-len(suffix)]) for name in list_names(directory)
                               if name.endswith(suffix) and name[:-len(suffix)].isascii()
                               and name[:-len(suffix)].isdigit())
            listed[split] = sorted(ids)
        return listed[split]

    def list_scenes(self) -> list[str]:
        """Every scene of the source, in a stable order."""
        src = self.config.src
        if not (src / "training").is_dir() and not (src / "testing").is_dir():
            raise InputError(f"{src}: expected the folder that contains training/ (and testing/), got neither")
        size = self._scene_size
        self._listed_ids.clear()  # a new run lists the source again
        scenes: list[str] = []
        for split in SPLITS:
            starts = sorted({sample // size * size for sample in self._sample_ids(split)})
            scenes.extend(f"{split}_{start:06d}" for start in starts)
        return scenes

    def convert_scene(self, scene: str, writer: DatasetWriter, report: Report) -> None:
        """Converts one scene into writer; problems of single records go to report."""
        split, _, start_text = scene.rpartition("_")
        start = int(start_text)
        ids = self._scene_ids(split, start)
        samples = [s for s in (self._load(split, sample_id, report) for sample_id in ids) if s is not None]
        if not samples:
            raise InputError(f"{self.config.src / split}: no readable sample with ids in [{start}, "
                             f"{start + self._scene_size})")
        cameras = [0, 1, 2, 3]
        metadata = {
            "split": split,
            "kitti_sample_ids": [s.sample_id for s in samples],
            "world_origin": "world = ego = the velodyne frame of each sample (KITTI object has no ego pose)",
            "ego_origin": "the Velodyne HDL-64E's origin, axes x forward, y left, z up",
            "time": "nominal: frame k at k * 100 ms, scene-relative (KITTI object has no timestamps)",
            "time_nominal": True,
            "calibration": "per sample: camera/IMU poses on /tf and CameraCalibration at each frame's time",
            "source_frames": {
                "labels": "rectified camera 0 (x right, y down, z forward), bottom centre, h w l, rotation_y",
                "ego/cam0..cam3": "rectified cameras at their own optical centres; cam_i_T_cam0 = (I, K_i^-1 P_i[:, 3]); "
                                  "CameraCalibration P = [K_i | 0] in that frame; KITTI's matrices in kitti_calibration",
                "ego/cam0_unrectified": "camera 0 before R0_rect (Tr_velo_to_cam's target)",
                "ego/imu": "Tr_imu_to_velo^-1 (the OXTS unit; no poses in KITTI object)",
            },
            "occlusion": "KITTI occluded 0..3 stored as is (same scale as avdata's)",
            "kitti_calibration": {f"{s.sample_id:06d}": common.source_calibration(s.calib) for s in samples},
        }
        velo = common.sensor(geometry.VELODYNE)
        identity = Transform.identity()
        # Every sample's labels at once, so the samples of one calibration share one batch of box arithmetic.
        # The id is the line's index in the file, so a dropped line does not renumber the others.
        labelled = [(sample, sample.labels) for sample in samples if sample.labels is not None]
        converted = iter(common.camera_labels(
            [(labels, np.array([f"{sample.sample_id:06d}_{line - 1}" for line in labels.line.tolist()]),
              geometry.velo_T_sensors(sample.calib)["cam0"]) for sample, labels in labelled],
            tracking=False, extras=[{"kitti_sample": float(sample.sample_id)} for sample, _ in labelled]))
        with writer.scene(scene, metadata) as out:
            out.add_agent(common.AGENT, kind="vehicle", origin="velodyne (KITTI object has no ego pose)")
            common.declare_sensors(out, cameras, {i: size for i, (_, size) in samples[0].images.items()})
            out.add_static_transform(common.AGENT, velo, identity)
            for frame_index, sample in enumerate(samples):
                time_ns = frame_index * common.PERIOD_NS
                out.add_transform("world", common.AGENT, time_ns, identity)
                sizes = {i: size for i, (_, size) in sample.images.items()}
                common.write_calibration(out, time_ns, sample.calib, identity, cameras, sizes, stamped=True)
                sensor_times = {}
                if sample.velodyne is not None and common.add_velodyne(
                        out, velo, time_ns, sample.velodyne, report, f"sample {sample.sample_id:06d}"):
                    sensor_times[velo] = time_ns
                for i, (path, _) in sorted(sample.images.items()):
                    cam = common.sensor(geometry.camera_frame(i))
                    if common.add_png(out, cam, time_ns, path, report, f"sample {sample.sample_id:06d}"):
                        sensor_times[cam] = time_ns
                if sample.labels is None:
                    out.add_frame(frame_index, time_ns, ObjectLabels.empty("world"), sensor_times, annotated=False)
                    continue
                labels, visibility = next(converted)
                out.add_frame(frame_index, time_ns, labels, sensor_times)
                out.add_visibility(common.sensor("cam2"), frame_index, time_ns, visibility)

    def _load(self, split: str, sample_id: int, report: Report) -> _Sample | None:
        """Reads and checks one sample's text files and sizes; reports and returns None if unusable."""
        root = self.config.src / split
        name = f"{sample_id:06d}"
        try:
            calib = read_calib(root / "calib" / f"{name}.txt")
        except InputError as error:
            report.error(root / "calib" / f"{name}.txt", f"{error}; sample {name} skipped")
            return None
        common.report_calib_warnings(report, calib)
        labels = None
        label_path = root / "label_2" / f"{name}.txt"
        if split == "training":
            try:
                require_file(label_path, "label file")
            except InputError as error:
                report.error(label_path, f"{error}; sample {name} skipped")
                return None
            labels, problems = read_labels(label_path, tracking=False)
            for problem in problems:
                report.error(label_path, f"{problem.message}; object dropped, sample {name} written without it")
        velodyne_path = root / "velodyne" / f"{name}.bin"
        velodyne: Source | None = None
        if not is_present(velodyne_path):
            report.warn(velodyne_path, f"missing: sample {name} written without its point cloud (partial download?)")
        elif not velodyne_path.is_file():  # a folder, a broken link or a FIFO is damage, not a partial download
            report.error(velodyne_path, f"expected a file, got a folder, a broken link or a special file; sample {name} "
                                        "written without its point cloud")
        elif (size_problem := velodyne_problem(velodyne_path)) is not None:  # costs itself, like a missing scan
            report.error(velodyne_path, f"{size_problem}; sample {name} written without its point cloud")
        else:
            velodyne = velodyne_path
        images: dict[int, tuple[Source, tuple[int, int]]] = {}
        for i in (2, 3):
            folder = root / f"image_{i}"
            path = folder / f"{name}.png"
            if not is_present(path):
                if i == 2 or folder.is_dir():
                    report.warn(path, f"missing: sample {name} written without this image (partial download?)")
                continue
            if not path.is_file():  # a folder, a broken link or a FIFO is damage, not a partial download
                report.error(path, f"expected a file, got a folder, a broken link or a special file; sample {name} "
                                   "written without this image")
                continue
            try:
                images[i] = (path, png_size(path, decode=self.options.decode_images))
            except InputError as error:  # like a missing image, it costs itself: the sample keeps the rest
                report.error(path, f"{error}; sample {name} written without this image")
        return _Sample(sample_id=sample_id, calib=calib, labels=labels, velodyne=velodyne, images=images)
