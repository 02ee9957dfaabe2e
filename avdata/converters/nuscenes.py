"""nuScenes and nuScenes-schema datasets (Lyft Level 5) -> the unified format.

The source's rows of docs/conventions.md, and what this module does with each:

=================  ==========================================================================
nuScenes           how it is converted
=================  ==========================================================================
frame of labels    global (map) frame -> ``world`` (scene metadata says so; not re-centred)
box origin         centre -> centre
size order         **w, l, h** -> l, w, h (``Boxes3D.from_nuscenes``)
rotation           quaternion (w, x, y, z) of the box in global -> same, in ``world``
ego z              the ego pose's z is 0 in nuScenes (poses are in the map plane); kept as given
ego poses          every sample_data has its own ego_pose -> one ``world -> ego`` entry on ``/tf``
                   stamped with the *sample_data's* timestamp (see Lyft below), de-duplicated
sweeps             non-key-frame sample_data -> sensor messages at their own times, not frames
cameras            images already undistorted -> CameraCalibration with K and empty D; camera
                   sensor frames are already optical -> calibrated_sensor goes to /tf_static as is
lidar              ``.pcd.bin`` = 5 float32 (x, y, z, intensity, ring) -> stored untouched in the
                   sensor's own frame (LIDAR_TOP is turned 90° about z; that is on /tf_static)
radar              binary ``.pcd`` -> header parsed, every field kept
Lyft timestamps    float microseconds (``1556675185903083.2``) -> int64 ns, see :func:`us_to_ns`
=================  ==========================================================================

Frames are samples (key frames); a frame's ``sensor_timestamps_ns`` holds each channel's key-frame
sample_data time. Sensor frames are ``ego/<channel lower-case>`` (``ego/lidar_top``, ``ego/cam_front``).

V2X-Sim 2.0 (``--variant v2x-sim``) uses the same schema for several agents: channel
``<CHANNEL>_id_<k>`` belongs to agent k (k = 0 the road-side unit -> agent ``infra_0``, kind
infrastructure; k = 1 -> ``ego``; k >= 2 -> ``cav_<k>``), and each sample_data's ego_pose is the pose
of its own agent, so every agent gets its ``world -> agent`` poses on ``/tf`` and its sensors below it
(``infra_0/lidar_top``). Its ``ego_pose.timestamp`` values are small integers, not times; poses are
stamped with their sample_data's time, as for Lyft.

Lyft quirk: every Lyft ego_pose row carries the LiDAR's timestamp although the poses referenced by
camera sample_data were interpolated to each camera's capture time (7 different poses share one
``ego_pose.timestamp``). Stamping each pose with its sample_data's timestamp (in nuScenes both are
equal) keeps lookups at a camera's time on that camera's own pose.

The tables are read without nuscenes-devkit and without building its object graph: the big tables
(sample_data, ego_pose, sample_annotation) are stream-parsed record by record and only the fields
used here are kept, grouped by scene; scenes are converted one at a time.
"""

from __future__ import annotations

import json
import os
import re
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from avdata.converters.base import ConvertConfig, Converter, ConverterOptions, Report
from avdata.errors import InputError
from avdata.frames import Boxes3D, Transform
from avdata.inputs import is_present, read_regular_file
from avdata.outputs import checked_name
from avdata.schema import DatasetWriter, ObjectLabels
from avdata.sources.jpeg import jpeg_problem
from avdata.sources.nuscenes import (
    DANGLING,
    NuScenesTables,
    SampleDataRow,
    box_velocity,
    read_lidar_bin,
    unified_class,
)
from avdata.sources.pcd import decode_pcd
from avdata.storage import Location

#: ``--variant`` values: the nuScenes schema as nuScenes and Lyft use it, or V2X-Sim 2.0's multi-agent channels.
VARIANTS = ("nuscenes", "v2x-sim")
#: V2X-Sim 2.0 channel names: ``<CHANNEL>_id_<k>``, agent k (k = 0 the road-side unit).
_V2X_SIM_CHANNEL = re.compile(r"(.+)_id_(\d+)")
V2X_SIM_AGENTS = "V2X-Sim channels <CHANNEL>_id_<k>: k = 0 the road-side unit (agent infra_0), k = 1 ego, k >= 2 cav_<k>"


@dataclass(frozen=True, slots=True, kw_only=True)
class NuScenesOptions(ConverterOptions):
    """Options of the nuScenes converter."""

    version: str | None = field(default=None, metadata={
        "help": "table folder under SRC, e.g. v1.0-mini, v1.0-trainval, v1.01-train (default: the only one present)"})
    variant: str = field(default="nuscenes", metadata={
        "choices": VARIANTS,
        "help": "nuscenes (also Lyft): one ego agent; v2x-sim: channels <CHANNEL>_id_<k> are agent k's sensors "
                "(k = 0 the road-side unit infra_0, k = 1 ego, k >= 2 cav_<k>), each with its own ego poses"})

    def __post_init__(self) -> None:
        # One folder under SRC, by the rule of every name in a path: '..' or '/' read tables outside SRC, a name
        # over 255 bytes was a traceback, and '' chose the only version present without a word.
        if self.version is not None:
            checked_name(self.version, "--version")


class NuScenesConverter(Converter):
    """nuScenes / Lyft Level 5 (nuScenes schema): every sample_data, ego pose, calibration and box."""

    name = "nuscenes"
    source = "nuscenes"
    licence = "CC BY-NC-SA 4.0 (nuScenes / Lyft Level 5 terms of use)"
    reads_stores = True
    Options = NuScenesOptions

    def __init__(self, config: ConvertConfig):
        super().__init__(config)
        self._tables: NuScenesTables | None = None

    def __getstate__(self) -> dict[str, Any]:
        return {"config": self.config, "_tables": None}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.config = state["config"]
        self._tables = None

    def release(self) -> None:
        """Drops the parsed tables (tens of MB on trainval) before the index is built."""
        self._tables = None

    def source_files(self, scene: str) -> list[Path | Location]:
        """Every table of the version folder (each scene reads several) and the scene's sensor files."""
        tables = self.tables()
        rows = tables.sample_data_rows(tables.scene_by_name[scene])
        src = self.config.src
        found: list[Path | Location] = [*tables.table_dir.iterdir()]
        return [*sorted((p for p in found if p.name.endswith(".json")), key=str), *(src / row.filename for row in rows)]

    def source_version(self) -> str:
        """The source's version, for the manifest."""
        return self.table_dir().name

    def table_dir(self) -> Path | Location:
        """``SRC/<version>``; with no version given, the one sub-folder of SRC holding ``scene.json``."""
        src = self.config.src
        version: str | None = self.options.version
        if version is not None:
            path = src / version
            if not path.is_dir():
                raise InputError(f"{src}: expected a table folder {version!r}, got none")
            return path
        # A scene.json that is a folder, a broken link or a FIFO still marks its version folder (and is then named
        # as unreadable) rather than letting another version be chosen without a word.
        folders: list[Path | Location] = [*src.iterdir()] if src.is_dir() else []
        found = sorted((p for p in folders if is_present(p / "scene.json")), key=lambda p: p.name)
        if len(found) != 1:
            raise InputError(
                f"{src}: expected one version folder holding scene.json (pass --version), got {[p.name for p in found]}"
            )
        return found[0]

    def tables(self) -> NuScenesTables:
        """The lookups, built once per process."""
        if self._tables is None:
            self._tables = NuScenesTables(self.table_dir())
        return self._tables

    def list_scenes(self) -> list[str]:
        """Every scene of the source, in a stable order."""
        tables = self.tables()
        if not tables.scene_by_name:  # the problems are reported with the first scene: without one, here
            found = "; ".join(f"{file}: {message}" for file, message in tables.orphans[:3])
            raise InputError(f"{tables.table_dir / 'scene.json'}: expected at least one valid scene, got none"
                             + (f" ({found})" if found else ""))
        return sorted(tables.scene_by_name)

    def convert_scene(self, scene: str, writer: DatasetWriter, report: Report) -> None:
        """Converts one scene into writer; problems of single records go to report."""
        tables = self.tables()
        if scene == self.list_scenes()[0]:
            for file, message in tables.orphans:
                report.error(file, message)
            for file, message in tables.warnings:
                report.warn(file, message)
        _SceneConversion(tables, self.config.src, scene, report, self.options.variant).write(writer)


class _SceneConversion:
    """Converts one scene (kept as one object so its lookups die with it)."""

    def __init__(self, tables: NuScenesTables, dataroot: Path | Location, name: str, report: Report, variant: str):
        self.tables = tables
        self.variant = variant
        self.dataroot = dataroot
        self.name = name
        self.report = report
        self.scene_token = tables.scene_by_name[name]
        self.scene = tables.scene[self.scene_token]
        self.version = tables.table_dir.name

    def metadata(self) -> dict[str, Any]:
        log = self.tables.log.get(self.scene["log_token"])
        if log is None:
            self.report.error("scene.json", f"scene {self.scene_token}: dangling log_token {self.scene['log_token']}")
            log = {}
        map_row = self.tables.map_of_log.get(self.scene["log_token"], {})
        return {
            "scene_token": self.scene_token,
            "description": self._text("scene", self.scene, "description"),
            "log": self._text("log", log, "logfile"),
            "log_token": self.scene["log_token"],
            "vehicle": self._text("log", log, "vehicle"),
            "location": self._text("log", log, "location"),
            "date_captured": self._text("log", log, "date_captured"),
            "map": map_row.get("filename", ""),
            "map_token": map_row.get("token", ""),
            "split": self.version,
            "world": "the nuScenes global (map) frame of this log, z up; not re-centred",
            "ego_origin": "midpoint of the rear axle (nuScenes ego_pose; Lyft uses the same schema)",
            "time": "UTC epoch (nuScenes / Lyft microseconds x 1000)",
        } | ({"variant": "v2x-sim", "agents_from": V2X_SIM_AGENTS} if self.variant == "v2x-sim" else {})

    def _text(self, table: str, row: dict[str, Any], key: str) -> str:
        """A descriptive field of ``row`` for the scene metadata; one that is not a string costs itself, not the scene.

        A NaN there made the metadata unwritable (not JSON) and the whole scene was lost.
        """
        value = row.get(key, "")
        if isinstance(value, str):
            return value
        self.report.error(f"{table}.json", f"{table} {row.get('token')}: field {key!r}: expected a string, got "
                                           f"{json.dumps(value)[:60]}; left empty in the scene metadata")
        return ""

    def write(self, writer: DatasetWriter) -> None:
        tables = self.tables
        metadata = self.metadata()
        for file, message in tables.problems.get(self.scene_token, []):
            self.report.error(file, message)
        samples = self._samples()
        sample_index = {self.tables.sample_tokens[row]: i for i, row in enumerate(samples)}
        data_rows = self._valid_sample_data()
        channels = self._sensors(data_rows)
        data_rows = [row for row in data_rows if row.calibrated_sensor_token in channels]
        with writer.scene(self.name, metadata) as scene:
            for agent in sorted({frame.partition("/")[0] for frame, _, _ in channels.values()} or {"ego"}):
                infrastructure = agent.startswith("infra")
                scene.add_agent(agent, "infrastructure" if infrastructure else "vehicle",
                                "the road-side unit's ego_pose (V2X-Sim agent 0)" if infrastructure
                                else metadata["ego_origin"])
            first_time: dict[str, int] = {}
            for row in data_rows:
                first_time.setdefault(row.calibrated_sensor_token, row.timestamp_ns)
            for cs_token, (frame, modality, channel) in channels.items():
                calibration = tables.calibrated_sensor[cs_token]
                scene.add_sensor(
                    frame,
                    modality,
                    channel=channel,
                    sensor_token=calibration["sensor_token"],
                    calibrated_sensor_token=cs_token,
                )
                ego_T_sensor = Transform.from_quat_wxyz(
                    np.asarray(calibration["rotation"], dtype=np.float64),
                    np.asarray(calibration["translation"], dtype=np.float64),
                )
                scene.add_static_transform(frame.partition("/")[0], frame, ego_T_sensor)
                if modality == "camera" and cs_token in first_time:
                    size = self._camera_size([r for r in data_rows if r.calibrated_sensor_token == cs_token])
                    try:  # a malformed intrinsic costs this camera's calibration only
                        K = np.asarray(calibration.get("camera_intrinsic"), dtype=np.float64).reshape(3, 3)
                    except (TypeError, ValueError):
                        K = np.full((3, 3), np.nan)
                    if not np.all(np.isfinite(K)):
                        self.report.error("calibrated_sensor.json", f"calibrated_sensor {cs_token}: camera_intrinsic: "
                                          f"expected 3x3 finite numbers, got {calibration.get('camera_intrinsic')!r:.120}")
                        continue
                    scene.add_camera_calibration(frame, first_time[cs_token], K, *size, D=np.zeros(0))
            agent_of = {cs: frame.partition("/")[0] for cs, (frame, _, _) in channels.items()}
            poses = [pose for agent in sorted(set(agent_of.values())) for pose in
                     self._poses(agent, [r for r in data_rows if agent_of[r.calibrated_sensor_token] == agent])]
            # /tf is one time-ordered topic for every agent.
            for time_ns, agent, world_T_agent in sorted(poses, key=lambda pose: (pose[0], pose[1])):
                scene.add_transform("world", agent, time_ns, world_T_agent)
            key_times: dict[str, dict[str, int]] = defaultdict(dict)
            for row in data_rows:
                frame, modality, _ = channels[row.calibrated_sensor_token]
                # A frame lists only the sensor messages that were written (a missing file costs its sensor).
                if self._write_sensor_data(scene, row, frame, modality) and row.is_key_frame:
                    key_times[row.sample_token][frame] = row.timestamp_ns
            labels = self._labels(samples, sample_index)
            for i, sample_row in enumerate(samples):
                try:  # a frame the index could not place costs that sample only
                    scene.add_frame(
                        scene.n_frames,
                        int(tables.sample_ns[sample_row]),
                        labels[i],
                        sensor_timestamps_ns=dict(sorted(key_times[tables.sample_tokens[sample_row]].items())),
                        annotated=True,
                    )
                except InputError as error:
                    self.report.error("sample.json", f"sample {tables.sample_tokens[sample_row]}: {error}")

    def _samples(self) -> list[int]:
        """The scene's sample rows (indexes into the sample columns) in time order."""
        rows = np.flatnonzero(self.tables.sample_scene == self.tables.scene_tokens.index(self.scene_token))
        if not len(rows):
            raise InputError(f"scene {self.name} ({self.scene_token}): expected samples, got none in sample.json")
        ordered: list[int] = rows[np.argsort(self.tables.sample_ns[rows], kind="stable")].tolist()
        return ordered

    def _valid_sample_data(self) -> list[SampleDataRow]:
        """The scene's sample_data in time order, without rows whose sensor dangles."""
        rows = []
        for row in self.tables.sample_data_rows(self.scene_token):
            calibration = self.tables.calibrated_sensor[row.calibrated_sensor_token]
            if calibration["sensor_token"] not in self.tables.sensor:
                self.report.error(
                    "calibrated_sensor.json",
                    f"calibrated_sensor {row.calibrated_sensor_token}: dangling sensor_token {calibration['sensor_token']}",
                )
                continue
            rows.append(row)
        rows.sort(key=lambda r: (r.timestamp_ns, r.token))
        return rows

    def _sensors(self, rows: list[SampleDataRow]) -> dict[str, tuple[str, str, str]]:
        """calibrated_sensor token -> (sensor frame, modality, channel); one calibration per channel."""
        channels: dict[str, tuple[str, str, str]] = {}
        token_of_channel: dict[str, str] = {}
        for row in rows:
            cs_token = row.calibrated_sensor_token
            if cs_token in channels:
                continue
            calibration = self.tables.calibrated_sensor[cs_token]
            sensor = self.tables.sensor[calibration["sensor_token"]]
            channel = sensor["channel"]
            first = token_of_channel.setdefault(channel, cs_token)
            if first != cs_token:
                old = self.tables.calibrated_sensor[first]
                same = all(np.allclose(old[key], calibration[key]) for key in ("rotation", "translation")) and (
                    np.asarray(old.get("camera_intrinsic") or []).tolist()
                    == np.asarray(calibration.get("camera_intrinsic") or []).tolist()
                )
                if not same:
                    self.report.error(
                        "calibrated_sensor.json",
                        f"channel {channel}: calibration changes within the scene "
                        f"({first} then {cs_token}); sample_data of the second is skipped",
                    )
                    continue
            agent, name = self._agent_sensor(channel)
            channels[cs_token] = (f"{agent}/{name}", sensor["modality"], channel)
        return channels

    def _agent_sensor(self, channel: str) -> tuple[str, str]:
        """(agent, sensor name) of a channel: ``("ego", "lidar_top")``; V2X-Sim ``LIDAR_TOP_id_0`` -> infra_0."""
        if self.variant != "v2x-sim":
            return "ego", channel.lower()
        match = _V2X_SIM_CHANNEL.fullmatch(channel)
        if match is None:
            return "ego", channel.lower()
        k = int(match.group(2))
        return ("infra_0" if k == 0 else "ego" if k == 1 else f"cav_{k}"), match.group(1).lower()

    def _poses(self, agent: str, rows: list[SampleDataRow]) -> list[tuple[int, str, Transform]]:
        """(time, agent, ``world_T_agent``) at every time of the agent's sample_data, stamped with that time.

        One entry per distinct (time, ego_pose) pair; two different poses at one time keep the first
        (by pose row) and warn.
        """
        if not rows:
            return []
        stamped = np.asarray(sorted({(row.timestamp_ns, row.ego_pose_row) for row in rows}), dtype=np.int64)
        times_ns, pose_rows = stamped.reshape(-1, 2).T
        repeated = np.flatnonzero(times_ns[1:] == times_ns[:-1]) + 1
        for k in repeated:
            kept, dropped = self.tables.ego_pose[pose_rows[k - 1]], self.tables.ego_pose[pose_rows[k]]
            if not np.array_equal(kept, dropped):
                who = "" if agent == "ego" else f"{agent}: "
                self.report.warn("ego_pose.json",
                                 f"{who}two different ego poses at {times_ns[k]} ns (row {pose_rows[k]} dropped)")
        keep = np.ones(len(times_ns), dtype=bool)
        keep[repeated] = False
        poses = self.tables.ego_pose[pose_rows[keep]]
        world_T_ego = Transform.from_quat_wxyz(poses[:, :4], poses[:, 4:])
        return [(time_ns, agent, world_T_ego[j]) for j, time_ns in enumerate(times_ns[keep].tolist())]

    def _camera_size(self, rows: list[SampleDataRow]) -> tuple[int, int]:
        """(width, height) of a camera's calibration: what its rows state, a damaged row costing its own image only.

        Real tables state one size per camera. Where rows disagree, the size of the first row whose JPEG
        has the size it states (each image is checked against its row when written), else the commonest.
        """
        sizes = Counter((row.width, row.height) for row in rows)
        if len(sizes) > 1:
            for row in rows:
                try:
                    data = read_regular_file(self.dataroot / row.filename if isinstance(self.dataroot, Location)
                                             else os.path.join(self.dataroot, row.filename))
                except (OSError, InputError):
                    continue  # reported when the image itself is written
                if jpeg_problem(data) == (None, (row.width, row.height)):
                    return row.width, row.height
        return sizes.most_common(1)[0][0]

    def _write_sensor_data(self, scene: Any, row: SampleDataRow, frame: str, modality: str) -> bool:
        """Writes one sample_data's file; False (with a warning) when it is missing or unreadable."""
        path: str | Location
        if isinstance(self.dataroot, Location):
            path = self.dataroot / row.filename
        else:
            path = os.path.join(self.dataroot, row.filename)  # not pathlib: one Path per file cost more than an image
        try:
            data = read_regular_file(path)
        except FileNotFoundError:
            # A link to nowhere is damage, not a partial download (looked at on a miss only; a store has no links).
            if not isinstance(path, Location) and os.path.islink(path):
                self.report.error(row.filename, f"expected a sensor file, got a broken symbolic link "
                                                f"(sample_data {row.token})")
            else:
                self.report.warn(row.filename, f"sensor file missing (sample_data {row.token})")
            return False
        except OSError as error:  # a folder or a symlink loop: damage, not a partial download
            self.report.error(row.filename, f"expected a sensor file, got {error.strerror} (sample_data {row.token})")
            return False
        except InputError as error:
            self.report.error(row.filename, f"unreadable sensor file (sample_data {row.token}): {error}")
            return False
        try:
            if modality == "camera":
                problem, (width_px, height_px) = jpeg_problem(data)
                if problem is not None:
                    raise InputError(f"{row.filename}: {problem}")
                if (width_px, height_px) != (row.width, row.height):
                    raise InputError(f"{row.filename}: expected the {row.width} x {row.height} px that sample_data.json "
                                     f"states (width, height), got a {width_px} x {height_px} px JPEG")
                scene.add_image(frame, row.timestamp_ns, data, "jpeg")
            elif modality == "radar" or row.filename.endswith(".pcd"):
                scene.add_point_cloud(frame, row.timestamp_ns, decode_pcd(data, row.filename))
            else:
                scene.add_point_cloud(frame, row.timestamp_ns, read_lidar_bin(data, row.filename))
        except InputError as error:
            self.report.error(row.filename, f"unreadable sensor file (sample_data {row.token}): {error}")
            return False
        return True

    def _labels(self, samples: list[int], sample_index: dict[str, int]) -> list[ObjectLabels]:
        """Each sample's objects in ``world``, velocities as the devkit's ``box_velocity`` computes them.

        Vectorised over the scene's annotations; each frame's objects keep their table order.

        Args:
            samples: the scene's sample rows in time order.
            sample_index: sample token -> frame index.
        """
        tables, report = self.tables, self.report
        c = tables.annotation_columns(self.scene_token)
        n = len(c["token"])
        if not n:
            return [ObjectLabels.empty("world") for _ in samples]
        # Per distinct sample and instance of the scene, then spread to the annotations.
        sample_rows, sample_of = np.unique(c["sample"], return_inverse=True)
        sample_us = {tables.sample_tokens[row]: float(tables.sample_us[row]) for row in samples}
        frame = np.array([sample_index[tables.sample_tokens[row]] for row in sample_rows.tolist()])[sample_of]
        time_us = np.array([sample_us[tables.sample_tokens[row]] for row in sample_rows.tolist()])[sample_of]
        instance_rows, instance_of = np.unique(c["instance"], return_inverse=True)
        instance_tokens = [tables.instance_tokens[row] for row in instance_rows.tolist()]
        category_tokens = [tables.instance_category[row] for row in instance_rows.tolist()]
        known = np.array([token in tables.category for token in category_tokens])[instance_of]
        for k in np.flatnonzero(~known).tolist():
            token = instance_tokens[instance_of[k]]
            report.error("instance.json", f"instance {token}: dangling category_token {category_tokens[instance_of[k]]}")
        categories = np.array([tables.category[token]["name"] if token in tables.category else ""
                               for token in category_tokens])[instance_of]
        classes = np.array([unified_class(name) for name in categories.tolist()])
        ids = np.array(instance_tokens)[instance_of]

        # prev / next: the linked annotation's position in this scene (< 0: none, or outside the scene).
        prev, nxt = c["prev"], c["next"]
        dangling_prev = known & (prev == DANGLING)
        dangling_next = known & (nxt == DANGLING)
        n_dangling = int(dangling_prev.sum() + dangling_next.sum())
        if n_dangling:
            k = int(np.flatnonzero(dangling_prev | dangling_next)[0])
            example = tables.dangling_link(self.scene_token, k, "prev" if dangling_prev[k] else "next")
            report.warn(
                "sample_annotation.json",
                f"{n_dangling} prev/next links point outside the "
                f"tables (e.g. {example}); velocities use the neighbours present",
            )
        box = c["box"]
        first = np.where(prev >= 0, prev, np.arange(n))
        last = np.where(nxt >= 0, nxt, np.arange(n))
        velocity = box_velocity(box[first, :3], box[last, :3], time_us[first], time_us[last], prev >= 0, nxt >= 0)

        attribute_names = [{tables.attribute[t]["name"]: "true" for t in tokens} for tokens in tables.attribute_sets]
        levels = [tables.visibility[t]["level"] for t in tables.visibility_tokens]
        rows_of_frame = np.flatnonzero(known)
        rows_of_frame = rows_of_frame[np.argsort(frame[rows_of_frame], kind="stable")]
        bounds = np.searchsorted(frame[rows_of_frame], np.arange(len(samples) + 1))
        labels = []
        for f in range(len(samples)):
            rows = rows_of_frame[bounds[f]:bounds[f + 1]]
            if not len(rows):
                labels.append(ObjectLabels.empty("world"))
                continue
            attributes = []
            for token, attribute_set, visibility in zip(c["token"][rows].tolist(), c["attributes"][rows].tolist(),
                                                        c["visibility"][rows].tolist(), strict=True):
                attrs = dict(attribute_names[attribute_set])
                attrs["annotation_token"] = token.decode()
                if visibility >= 0:
                    attrs["visibility_token"] = tables.visibility_tokens[visibility]
                    attrs["visibility"] = levels[visibility]
                attributes.append(attrs)
            extras = [{"num_lidar_pts": float(lidar), "num_radar_pts": float(radar)} for lidar, radar in
                      zip(c["num_lidar_pts"][rows].tolist(), c["num_radar_pts"][rows].tolist(), strict=True)]
            boxes = Boxes3D.from_nuscenes(box[rows, :3], box[rows, 3:6], box[rows, 6:], "world", ids=ids[rows],
                                          classes=classes[rows], velocity=velocity[rows])
            labels.append(ObjectLabels(boxes=boxes, source_classes=categories[rows], attributes=attributes,
                                       extras=extras))
        return labels
