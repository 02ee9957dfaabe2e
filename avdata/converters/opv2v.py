"""OPV2V / V2XSet (CARLA) and V2V4Real (real, 4x4 poses) -> multi-agent unified scenes.

One scene per ``split/scenario`` folder (scene name ``<split>.<scenario>``, split kept in the metadata).
The variant is detected per scene from ``lidar_pose``: six numbers (OPV2V, V2XSet) or a 4x4 matrix
(V2V4Real). The source's rows of docs/conventions.md and what this module does with each:

==================  ==================================================================================
OPV2V / V2XSet      how it is converted
==================  ==================================================================================
map frame           CARLA, left-handed, degrees -> ``world`` = the map reflected by ``RH_T_CARLA``
                    (y -> -y), once, at this boundary; not re-centred
poses               [x, y, z, roll, yaw, pitch] deg, OpenCOOD ``x_to_world`` ->
                    ``world_T = RH_T_CARLA @ x_to_world(pose) @ RH_T_CARLA^-1`` (proper)
agent body frame    the agent's LiDAR (``lidar_pose``: the frame OpenCOOD works in), reflected;
                    ``<agent>/lidar`` is the identity on /tf_static
``true_ego_pos``    the vehicle's own pose -> stamped frame ``<agent>/vehicle`` under ``world``
``predicted_ego``   the GPS-noised pose -> stamped frame ``<agent>/vehicle_predicted`` under ``world``
points              ``x y z rgb`` PCD, left-handed lidar axes -> y negated; ``intensity`` = red byte
                    / 255 (OpenCOOD reads open3d's ``colors[:, 0]``); ``rgb`` dropped
boxes               centre = ``location + center`` in MAP axes (OpenCOOD ``project_world_objects``:
                    ``center`` is not rotated), half ``extent`` x 2, ``angle`` [roll, yaw, pitch]
                    -> ``boxes_from_carla`` (roll, pitch, yaw) into ``world``; velocity = ``speed``
                    km/h / 3.6 along the box heading
objects             union over the agents' ``vehicles`` (first agent wins, ego first; a later agent
                    placing the same actor > 1 mm away is warned about), CARLA actor
                    id as object id; other CAVs are labelled objects too (their peers list them),
                    and each vehicle agent names its own ``object_id`` so loaders drop it for itself
cameras             ``extrinsic`` = camera_T_lidar in Unreal camera axes -> optical frame
                    ``<agent>/camera<k>``: ``lidar_T_optical = RH @ inv(extrinsic) @ UE_T_OPTICAL``
                    from the agent's first frame; images stored as given, K = ``intrinsic``
RSU                 negative id or ``RSU: true`` -> agent ``infra_<|id|>``, kind infrastructure,
                    pose fixed on /tf_static from its first frame
time                frame number x 0.05 s (CARLA's fixed step), scene-relative from the first frame
==================  ==================================================================================

==================  ==================================================================================
V2V4Real            how it is converted
==================  ==================================================================================
poses               ``lidar_pose`` 4x4 lidar-to-world (right-handed) -> ``world -> <agent>`` as is
boxes               in each CAV's lidar frame: ``location + center``, x_to_world(angle) (a proper
                    rotation) -> moved to ``world`` with that CAV's pose
object ids          ``ass_id`` >= 0 -> that number, shared by both CAVs (the ego's box kept);
                    ``ass_id`` -1 -> ``<cav id>_<object id>`` (OpenCOOD folds these into
                    ``object_id + 100 * cav_id``, which can collide; a string cannot)
time                frame number x 0.1 s (10 Hz LiDAR), scene-relative
cameras             not converted: the release publishes no camera calibration (docs/v2x.md); camera
                    entries or images in an agent folder are named in one warning per agent
==================  ==================================================================================

The ego is OpenCOOD's: the first agent folder in sorted (string) order that is not an RSU; it is the
agent named ``ego``, the other vehicles are ``cav_<id>``. Each agent's own ``vehicles`` list is written
as its lidar's visibility (``in_fov``): which objects that agent annotated.
"""

from __future__ import annotations

import fnmatch
import re
from dataclasses import dataclass

import numpy as np

from avdata.converters.base import Converter, Report
from avdata.errors import InputError
from avdata.frames import RH_T_CARLA, Boxes3D, Transform
from avdata.inputs import Source, files_under, folder_entries, list_names, read_regular_file
from avdata.schema import DatasetWriter, ObjectLabels, SceneWriter, VisibilityLabels
from avdata.sources.opv2v import (
    CLASS_MAP,
    UE_T_OPTICAL,
    AgentFrame,
    boxes_from_carla,
    carla_pose_matrix,
    frame_files,
    intensity_from_rgb,
    png_size,
    read_agent_frame,
    world_T_carla_pose,
)
from avdata.sources.pcd import read_pcd

AGENT_DIR = re.compile(r"^-?\d+$")
STEP_NS = {"opv2v": 50_000_000, "v2v4real": 100_000_000}
#: A static calibration read from the first frame may drift this much in later frames (float32 noise).
STATIC_TOLERANCE = 1e-3
#: OPV2V agents record one simulator tick: their boxes of one actor may differ by float noise only.
AGREEMENT_TOLERANCE_M = 1e-3


@dataclass(frozen=True, slots=True, kw_only=True)
class _Agent:
    source_id: str
    name: str
    rsu: bool
    frames: dict[int, AgentFrame]
    folder: Source
    stems: dict[int, str]  # frame number -> file stem as published ("000069")
    names: frozenset[str]  # what the folder holds: one listing, not a look-up per file (a request in a store)

    def file(self, number: int, suffix: str) -> Source:
        """The frame's file ``<stem><suffix>`` (".yaml", ".pcd", "_camera0.png")."""
        return self.folder / f"{self.stems[number]}{suffix}"


class Opv2vConverter(Converter):
    """OPV2V / V2XSet (CARLA) and V2V4Real cooperative scenes (split/scenario/<agent>/<frame>.yaml)."""

    name = "opv2v"
    source = "OPV2V"
    licence = "research use only (OPV2V / V2XSet / V2V4Real terms)"
    reads_stores = True

    def list_scenes(self) -> list[str]:
        """Every scene of the source, in a stable order."""
        root = self.config.src
        if not root.is_dir():
            raise InputError(f"{root}: expected the dataset folder (split/scenario/<agent id>/), got no folder")
        scenes = []
        # folder_entries: one listing per folder in a store, whose entries know whether they are folders.
        for split in (p for p in folder_entries(root) if p.is_dir()):
            for scenario in (p for p in folder_entries(split) if p.is_dir()):
                if any(AGENT_DIR.match(a.name) and a.is_dir() for a in folder_entries(scenario)):
                    scenes.append(f"{split.name}.{scenario.name}")
        if not scenes:
            raise InputError(f"{root}: expected split/scenario/<agent id>/ folders, got none")
        return scenes

    def source_files(self, scene: str) -> list[Source]:
        """Every file of the scenario's folder (``split.scenario`` -> ``SRC/split/scenario``)."""
        split, scenario = scene.split(".", 1)
        return files_under(self.config.src / split / scenario)

    def convert_scene(self, scene: str, writer: DatasetWriter, report: Report) -> None:
        """Converts one scene into writer; problems of single records go to report."""
        split, scenario = scene.split(".", 1)
        folder = self.config.src / split / scenario
        agents = self._read_agents(folder, report)
        variant = _variant(agents, folder)
        step_ns = STEP_NS[variant]
        ego = agents[0]
        frame_numbers = sorted(set().union(*(a.frames for a in agents)))
        first = frame_numbers[0]
        metadata = {
            "split": split,
            "scenario": scenario,
            "variant": variant,
            "ego_source_id": ego.source_id,
            "world_origin": ("CARLA map origin, reflected y -> -y (RH_T_CARLA), z up" if variant == "opv2v"
                             else "V2V4Real map frame of lidar_pose, z up"),
            "handedness_before_conversion": "left (CARLA)" if variant == "opv2v" else "right",
            "time": f"scene-relative: (frame number - {first}) x {step_ns / 1e9} s",
            "box_centre": "location + center, center added in the parent frame's axes (OpenCOOD)",
        }
        with writer.scene(scene, metadata) as out:
            calibrations = {a.name: self._declare_agent(out, a, variant, report) for a in agents}
            for number in frame_numbers:
                if number not in ego.frames:
                    # The frame's labels and every other agent are placed relative to the ego: without
                    # its pose (its file unreadable or absent) the frame cannot stand.
                    where = ego.file(number, ".yaml") if number in ego.stems else ego.folder
                    report.warn(where, f"frame {number:06d} left out: no readable frame file of the ego agent "
                                       f"{ego.source_id}, so no ego pose")
                    continue
                time_ns = (number - first) * step_ns
                self._write_frame(out, agents, variant, number, time_ns, calibrations, report)

    # ----------------------------------------------------------------- reading
    def _read_agents(self, folder: Source, report: Report) -> list[_Agent]:
        # OpenCOOD's order: sorted folder names, an RSU (negative id) never first.
        ids = sorted(p.name for p in folder_entries(folder) if p.is_dir() and AGENT_DIR.match(p.name))
        agents = []
        for source_id in ids:
            frames = {}
            names = frozenset(list_names(folder / source_id))
            files = frame_files(folder / source_id, names)
            for number, path in files.items():
                try:
                    frame = read_agent_frame(path)
                except InputError as error:
                    report.error(path, str(error))
                    continue
                for message in frame.bad_vehicles:
                    report.error(path, message)
                for message in frame.warnings:
                    report.warn(path, message)
                frames[number] = frame
            if not frames:
                report.warn(folder / source_id, "agent folder without a readable frame file: left out")
                continue
            rsu = int(source_id) < 0 or any(f.rsu for f in frames.values())
            agents.append(_Agent(source_id=source_id, name="", rsu=rsu, frames=frames, folder=folder / source_id,
                                 stems={number: path.stem for number, path in files.items()}, names=names))
        vehicles = [a for a in agents if not a.rsu]
        if not vehicles:
            raise InputError(f"{folder}: expected at least one vehicle agent folder with frame files, got none")
        named = []
        for agent in vehicles + [a for a in agents if a.rsu]:
            name = ("ego" if agent is vehicles[0] else f"infra_{abs(int(agent.source_id))}" if agent.rsu
                    else f"cav_{agent.source_id}")
            named.append(_Agent(source_id=agent.source_id, name=name, rsu=agent.rsu, frames=agent.frames,
                                folder=agent.folder, stems=agent.stems, names=agent.names))
        return named

    # ----------------------------------------------------------------- agents and calibration
    def _declare_agent(self, out: SceneWriter, agent: _Agent, variant: str, report: Report) -> dict[str, Transform]:
        """Declares the agent, its lidar and cameras; returns camera frame -> lidar_T_optical."""
        first_number, first = next(iter(agent.frames.items()))
        spec = {"source_id": agent.source_id}
        if not agent.rsu and variant == "opv2v":
            spec["object_id"] = agent.source_id  # its peers label it with this CARLA actor id
        origin = ("the LiDAR (lidar_pose), right-handed: x forward, y left, z up" if variant == "opv2v"
                  else "the LiDAR (lidar_pose 4x4)")
        out.add_agent(agent.name, kind="infrastructure" if agent.rsu else "vehicle", origin=origin, **spec)
        lidar = f"{agent.name}/lidar"
        out.add_sensor(lidar, kind="lidar", source="<frame>.pcd")
        out.add_static_transform(agent.name, lidar, Transform.identity())
        if agent.rsu:
            world_T_agent = _world_T_lidar(first, variant)
            for number, frame in agent.frames.items():
                drift = _max_difference(_world_T_lidar(frame, variant), world_T_agent)
                if drift > STATIC_TOLERANCE:
                    report.warn(agent.file(number, ".yaml"),
                                f"field lidar_pose: RSU pose differs from frame {first_number} by {drift:.3g}; "
                                "the first frame's pose is used")
            out.add_static_transform("world", agent.name, world_T_agent)
        cameras: dict[str, Transform] = {}
        if variant == "v2v4real":
            _ignore_v2v4real_cameras(agent, report)
            return cameras
        for key, camera in first.cameras.items():
            frame_name = f"{agent.name}/{key}"
            lidar_T_optical = _lidar_T_optical(camera.extrinsic)
            size = _first_image_size(agent, key)
            out.add_sensor(frame_name, kind="camera", width=size[0], height=size[1], source=f"<frame>_{key}.png")
            out.add_static_transform(agent.name, frame_name, lidar_T_optical)
            cameras[frame_name] = lidar_T_optical
        return cameras

    # ----------------------------------------------------------------- one frame
    def _write_frame(self, out: SceneWriter, agents: list[_Agent], variant: str, number: int,
                     time_ns: int, calibrations: dict[str, dict[str, Transform]], report: Report) -> None:
        sensor_times: dict[str, int] = {}
        boxes_per_agent: list[tuple[_Agent, ObjectLabels]] = []
        clouds: dict[str, np.ndarray] = {}
        for agent in agents:
            frame = agent.frames.get(number)
            if frame is None:
                continue
            world_T_lidar = _world_T_lidar(frame, variant)
            if not agent.rsu:
                out.add_transform("world", agent.name, time_ns, world_T_lidar)
                for key, child in (("true_ego_pos", "vehicle"), ("predicted_ego_pos", "vehicle_predicted")):
                    pose = getattr(frame, key)
                    if pose is not None:
                        out.add_transform("world", f"{agent.name}/{child}", time_ns, world_T_carla_pose(pose))
            pcd = agent.file(number, ".pcd")
            if pcd.name in agent.names:  # a folder or a broken link is an error, not a missing cloud
                try:
                    fields = _points(read_pcd(pcd), variant, pcd)
                    out.add_point_cloud(f"{agent.name}/lidar", time_ns, fields)
                    sensor_times[f"{agent.name}/lidar"] = time_ns
                    clouds[agent.name] = world_T_lidar.apply(np.stack([fields["x"], fields["y"], fields["z"]], axis=1)
                                                            .astype(np.float64))
                except InputError as error:
                    report.error(pcd, str(error))
            else:
                report.warn(pcd, "point cloud missing")
            self._write_cameras(out, agent, frame, number, time_ns, calibrations[agent.name], sensor_times, report)
            labels = _labels(frame, agent, variant, world_T_lidar)
            boxes_per_agent.append((agent, labels))
        merged = _union([labels for _, labels in boxes_per_agent])
        if variant == "opv2v":  # one simulator tick: every agent must list an actor at the same place
            lookup = {key: i for i, key in enumerate(merged.boxes.ids if merged.boxes.ids is not None else [])}
            for agent, labels in boxes_per_agent:
                ids = labels.boxes.ids if labels.boxes.ids is not None else np.zeros(0, dtype=str)
                rows = np.array([lookup[key] for key in ids.tolist()], dtype=np.int64)
                offset = np.linalg.norm(labels.boxes.center - merged.boxes.center[rows], axis=1) if len(rows) else rows
                bad = offset > AGREEMENT_TOLERANCE_M
                if np.any(bad):
                    report.warn(agent.file(number, ".yaml"),
                                f"field vehicles: actors {ids[bad][:5].tolist()} lie up to {offset[bad].max():.3g} m from "
                                "where an earlier agent lists them at the same tick; the earlier agent's box is kept")
        index = out.n_frames
        try:  # a frame the index could not place costs that frame only
            out.add_frame(index, time_ns, merged, sensor_timestamps_ns=sensor_times)
        except InputError as error:
            report.error(agents[0].file(number, ".yaml"), str(error))
            return
        for agent, labels in boxes_per_agent:
            if agent.name in clouds:
                out.add_visibility(f"{agent.name}/lidar", index, time_ns,
                                   lidar_visibility(merged.boxes, labels.boxes.ids, clouds[agent.name]))

    def _write_cameras(self, out: SceneWriter, agent: _Agent, frame: AgentFrame, number: int, time_ns: int,
                       calibration: dict[str, Transform], sensor_times: dict[str, int], report: Report) -> None:
        for key, camera in frame.cameras.items():
            frame_name = f"{agent.name}/{key}"
            path = agent.file(number, f"_{key}.png")
            if frame_name not in calibration:
                continue  # V2V4Real (cameras not converted) or a camera absent from the agent's first frame
            drift = _max_difference(_lidar_T_optical(camera.extrinsic), calibration[frame_name])
            if drift > STATIC_TOLERANCE:
                report.warn(agent.file(number, ".yaml"),
                            f"field {key}.extrinsic: differs from the first frame's by {drift:.3g}; first frame's used")
            if path.name not in agent.names:
                report.warn(path, "image missing")
                continue
            K = camera.intrinsic  # noqa: N806 - the matrix's usual name
            if not (np.all(np.isfinite(K)) and K[0, 0] > 0 and K[1, 1] > 0):  # refused by the writer: cost the scenario
                report.error(agent.file(number, ".yaml"), f"field {key}.intrinsic: expected finite values with positive "
                                                          f"focal lengths, got {K.ravel().tolist()}; image skipped")
                continue
            try:
                data = read_regular_file(path)  # a FIFO is refused, not waited on
                width, height = png_size(data, path)
            except OSError as error:
                report.error(path, f"cannot read ({error.strerror or error})")
                continue
            except InputError as error:
                report.error(path, str(error))
                continue
            out.add_image(frame_name, time_ns, data, "png")
            out.add_camera_calibration(frame_name, time_ns, K=camera.intrinsic, width=width, height=height,
                                       D=np.zeros(0))
            sensor_times[frame_name] = time_ns


def _ignore_v2v4real_cameras(agent: _Agent, report: Report) -> None:
    """One warning per agent whose V2V4Real folder holds camera entries or images: they are not converted.

    V2V4Real's release publishes no camera calibration (its OpenCOOD fork lists ``<frame>_camera0..3.png``
    paths and never opens them, and reads no intrinsic or extrinsic; docs/v2x.md), so the axes of a
    ``cameraN`` entry there would be a guess: OPV2V's are CARLA's Unreal axes, V2V4Real's lidars are not.
    """
    keys = sorted({key for frame in agent.frames.values() for key in frame.cameras})
    images = sorted(name for name in agent.names if fnmatch.fnmatchcase(name, "*_camera*.png"))
    if keys or images:
        found = ", ".join(filter(None, (f"fields {', '.join(keys)}" if keys else "",
                                        f"{len(images)} images ({images[0]} ...)" if images else "")))
        report.warn(agent.folder, f"V2V4Real cameras: expected none (the release publishes no camera calibration), "
                                  f"got {found}; not converted")


def _first_image_size(agent: _Agent, camera: str) -> tuple[int, int]:
    """(width, height) of the camera's first whole PNG in the agent's frames, (0, 0) if none.

    The bad ones are reported when their frame is written.
    """
    for number in agent.frames:
        path = agent.file(number, f"_{camera}.png")
        try:
            return png_size(read_regular_file(path), path)
        except (OSError, InputError):
            continue
    return 0, 0


def _variant(agents: list[_Agent], folder: Source) -> str:
    kinds = {frame.is_matrix_pose for agent in agents for frame in agent.frames.values()}
    if len(kinds) != 1:
        raise InputError(f"{folder}: field lidar_pose: expected one pose format per scenario, got both 6-number "
                         "(OPV2V) and 4x4 (V2V4Real) poses")
    return "v2v4real" if kinds.pop() else "opv2v"


def _world_T_lidar(frame: AgentFrame, variant: str) -> Transform:
    if variant == "v2v4real":
        return Transform.from_matrix(frame.lidar_pose)
    return world_T_carla_pose(frame.lidar_pose)


def _lidar_T_optical(extrinsic: np.ndarray) -> Transform:
    """The optical camera frame in the right-handed lidar frame, from OPV2V's camera_T_lidar (Unreal axes)."""
    return RH_T_CARLA @ Transform.from_matrix(extrinsic).inverse() @ UE_T_OPTICAL


def _max_difference(a: Transform, b: Transform) -> float:
    return float(max(np.abs(a.rotation - b.rotation).max(), np.abs(a.translation - b.translation).max()))


def _points(cloud: np.ndarray, variant: str, path: Source) -> dict[str, np.ndarray]:
    names = cloud.dtype.names or ()
    if not {"x", "y", "z"} <= set(names):
        raise InputError(f"{path}: PCD fields: expected x, y, z, got {list(names)}")
    sign = np.float32(-1.0) if variant == "opv2v" else np.float32(1.0)
    fields = {"x": cloud["x"].astype(np.float32), "y": sign * cloud["y"].astype(np.float32),
              "z": cloud["z"].astype(np.float32)}
    if "rgb" in names:
        fields["intensity"] = intensity_from_rgb(cloud["rgb"])
    elif "intensity" in names:
        fields["intensity"] = cloud["intensity"].astype(np.float32)
    return fields


def _labels(frame: AgentFrame, agent: _Agent, variant: str, world_T_lidar: Transform) -> ObjectLabels:
    vehicles = frame.vehicles
    n = len(vehicles.ids)
    source_classes = vehicles.obj_type
    classes = np.array([CLASS_MAP.get(c.lower(), "other") for c in source_classes], dtype=str).reshape(n)
    rotation_deg = vehicles.angle_deg[:, [0, 2, 1]]  # [roll, yaw, pitch] -> (roll, pitch, yaw)
    centre = vehicles.location + vehicles.center
    if variant == "opv2v":
        ids = vehicles.ids.astype(str)
        boxes = boxes_from_carla(centre, vehicles.extent_half, rotation_deg, "world", ids=ids, classes=classes)
        speed = np.where(np.isfinite(vehicles.speed_kmh), vehicles.speed_kmh, 0.0) / 3.6
        heading = boxes.rotation_matrix()[:, :, 0] if n else np.zeros((0, 3))
        boxes = Boxes3D(center=boxes.center, size_lwh=boxes.size_lwh, quat_wxyz=boxes.quat_wxyz, frame="world",
                        ids=boxes.ids, classes=boxes.classes, velocity=heading * speed[:, None])
    else:
        ids = np.where(vehicles.ass_id >= 0, vehicles.ass_id.astype(str),
                       np.char.add(f"{agent.source_id}_", vehicles.ids.astype(str))).astype(str)
        matrices = carla_pose_matrix(np.c_[centre, vehicles.angle_deg])
        boxes_lidar = Boxes3D.from_rotation(centre, 2.0 * vehicles.extent_half, matrices[:, :3, :3], "lidar",
                                            ids=ids, classes=classes)
        boxes = boxes_lidar.transform(world_T_lidar, "world")
    return ObjectLabels(boxes=boxes, source_classes=source_classes)


def lidar_visibility(boxes: Boxes3D, annotated_ids: np.ndarray | None, points: np.ndarray) -> VisibilityLabels:
    """One lidar's view of the frame's objects.

    ``in_fov`` = the agent annotated the object, ``n_points`` = returns inside its box (both in ``boxes.frame``).

    Args:
        boxes: (N) the frame's objects.
        annotated_ids: ids this agent's own label file lists.
        points: (P, 3) the lidar's points in ``boxes.frame``.
    """
    ids = boxes.ids if boxes.ids is not None else np.zeros(0, dtype=str)
    in_fov = np.isin(ids, annotated_ids if annotated_ids is not None else np.zeros(0, dtype=str))
    return VisibilityLabels(object_ids=ids, in_fov=in_fov, n_points=boxes.count_points(points))


def _union(parts: list[ObjectLabels]) -> ObjectLabels:
    """Every object once, the first agent's box kept (the ego comes first)."""
    if not parts:
        return ObjectLabels.empty("world")
    boxes = Boxes3D.concatenate([p.boxes for p in parts])
    source = np.concatenate([p.source_classes for p in parts]) if len(boxes) else np.zeros(0, dtype=str)
    ids = boxes.ids if boxes.ids is not None else np.zeros(0, dtype=str)
    _, first = np.unique(ids, return_index=True)
    keep = np.sort(first)
    return ObjectLabels(boxes=boxes[keep], source_classes=source[keep])
