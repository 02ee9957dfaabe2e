"""OPV2V / V2XSet / V2V4Real files: the per-agent frame YAML, the PCD intensity, the devkit formulas.

Layout (OpenCOOD ``basedataset.py``): ``split/scenario/<agent id>/<frame>.yaml`` with ``<frame>.pcd``
and ``<frame>_camera0..3.png`` beside it; a negative agent id is a road-side unit (V2XSet).

OPV2V / V2XSet (CARLA): ``lidar_pose``, ``true_ego_pos``, ``predicted_ego_pos`` and camera ``cords``
are [x, y, z, roll, yaw, pitch] (metres, DEGREES) in CARLA's LEFT-handed map frame (x forward, y right,
z up); OpenCOOD turns them into 4x4 matrices with ``x_to_world`` (``transformation_utils.py``), which is
``carla.Transform.get_matrix()``. Camera ``extrinsic`` is ``inv(x_to_world(cords)) @
x_to_world(lidar_pose)``: it maps lidar coordinates into the camera's (checked on the real file).
Vehicles: ``location``, ``center`` (added to ``location`` in MAP axes by OpenCOOD's
``project_world_objects``, not rotated), ``extent`` (half sizes), ``angle`` [roll, yaw, pitch] degrees,
``speed`` km/h. Point clouds are left-handed too, with intensity in the red byte of the packed ``rgb``
float (OpenCOOD ``pcd_utils.pcd_to_np`` reads ``open3d``'s ``colors[:, 0]`` = red / 255).

V2V4Real (real lidars, right-handed): ``lidar_pose`` is the 4x4 lidar-to-world matrix; vehicles are in
that CAV's lidar frame with the same ``location + center`` / ``angle`` formula, an ``obj_type`` and an
``ass_id`` that links the same object across the two CAVs (-1: seen by one CAV only).
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import yaml

from avdata.errors import InputError, shown
from avdata.frames import Transform
from avdata.frames.rotations import repaired_rotation
from avdata.inputs import Source, UniqueKeyLoader, read_regular_file
from avdata.schema.limits import MAX_ANGLE_RAD, MAX_COORDINATE_M, MAX_SPEED_MPS
from avdata.sources.png import png_problem

#: File names of frames: OpenCOOD skips ``*additional*`` and ``*camera_gt*`` YAMLs beside them.
FRAME_FILE = re.compile(r"^(\d+)\.yaml$")
CAMERA_KEY = re.compile(r"^camera(\d+)$")
#: CARLA writes rotations in degrees within +-360 (its Rotation normalises them to +-180): beyond the format's two
#: turns a value is damage (an angle of 1e308 deg gave a box of arbitrary heading without a word).
MAX_ANGLE_DEG = round(float(np.degrees(MAX_ANGLE_RAD)), 9)

#: ``camera_UE_T_optical``: optical axes (x right, y down, z forward) expressed in an Unreal camera
#: frame (x forward, y right, z up): right = +y, down = -z, forward = +x. Improper (Unreal is left-handed).
UE_T_OPTICAL = Transform(rotation=np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]),
                         translation=np.zeros(3))


class _Loader(UniqueKeyLoader):
    """PyYAML's YAML 1.1 reads "1e-05" (no dot) as a string; OpenCOOD's ``load_yaml`` adds this float rule.

    A key given twice with different values (PyYAML and OpenCOOD keep the last) makes the file unreadable.
    """


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
    |\.[0-9_]+(?:[eE][-+][0-9]+)?
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789."),
)


@dataclass(frozen=True, slots=True, kw_only=True)
class Vehicles:
    """The ``vehicles`` of one agent's frame file, as arrays (N objects).

    Attributes:
        ids: (N,) int64 source ids (CARLA actor ids; V2V4Real per-CAV ids).
        location: (N, 3) actor location, in the file's frame (map, or V2V4Real's lidar).
        center: (N, 3) box-centre offset, added to ``location`` in the same axes.
        extent_half: (N, 3) half length, width, height.
        angle_deg: (N, 3) roll, yaw, pitch in degrees, as stored.
        speed_kmh: (N,) speed in km/h (NaN when absent).
        obj_type: (N,) source class strings ("Car" when absent, OpenCOOD's default).
        ass_id: (N,) int64 V2V4Real association id (-1 when absent or unassociated).
    """

    ids: np.ndarray
    location: np.ndarray
    center: np.ndarray
    extent_half: np.ndarray
    angle_deg: np.ndarray
    speed_kmh: np.ndarray
    obj_type: np.ndarray
    ass_id: np.ndarray


@dataclass(frozen=True, slots=True, kw_only=True)
class Camera:
    """One camera entry: ``cords`` (6,) pose (OPV2V), ``extrinsic`` (4, 4) camera_T_lidar, ``intrinsic`` (3, 3)."""

    cords: np.ndarray | None
    extrinsic: np.ndarray
    intrinsic: np.ndarray


@dataclass(frozen=True, slots=True, kw_only=True)
class AgentFrame:
    """One agent's frame file.

    Attributes:
        lidar_pose: (6,) [x, y, z, roll, yaw, pitch] (OPV2V) or (4, 4) lidar-to-world (V2V4Real).
        true_ego_pos: (6,) the vehicle pose, or None (RSUs, V2V4Real).
        predicted_ego_pos: (6,) the GPS-noised vehicle pose, or None.
        rsu: whether the file says ``RSU: true``.
        vehicles: the labelled objects that parse; ``bad_vehicles`` holds one error line per other entry.
        cameras: camera name -> entry.
        warnings: one line per repair or gap that does not cost the frame (a V2V4Real rotation repaired beyond
            float noise, a missing ``vehicles`` field).
    """

    lidar_pose: np.ndarray
    true_ego_pos: np.ndarray | None
    predicted_ego_pos: np.ndarray | None
    rsu: bool
    vehicles: Vehicles
    bad_vehicles: tuple[str, ...]
    cameras: dict[str, Camera]
    warnings: tuple[str, ...] = ()

    @property
    def is_matrix_pose(self) -> bool:
        """True for V2V4Real's 4x4 ``lidar_pose``."""
        return self.lidar_pose.shape == (4, 4)


def read_agent_frame(path: Source) -> AgentFrame:
    """Parses one frame YAML, a local file or an object read whole; a bad vehicle entry is listed, not raised.

    Raises:
        InputError: the file is unreadable or a pose field is missing or malformed (names file and field).
    """
    try:
        data = yaml.load(read_regular_file(path), Loader=_Loader)  # noqa: S506 - a SafeLoader subclass
    except OSError as error:
        raise InputError(f"{path}: cannot read ({error.strerror or error})") from None
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        raise InputError(f"{path}:{where}: malformed YAML ({getattr(error, 'problem', error)})") from None
    except ValueError as error:  # a key given twice (DuplicateKeyError), an integer of 5000 digits
        raise InputError(f"{path}: {error}") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a YAML mapping, got {type(data).__name__}")
    raw_pose = data.get("lidar_pose")
    pose = _floats(raw_pose, path, "lidar_pose")
    if pose.shape == (6,):
        _degrees(pose[3:], path, "lidar_pose")
    if pose.shape not in ((6,), (4, 4)):
        raise InputError(f"{path}: field lidar_pose: expected 6 numbers or a 4x4 matrix, got shape {pose.shape}")
    if pose.shape == (4, 4) and not np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0]):
        raise InputError(f"{path}: field lidar_pose: expected last row [0, 0, 0, 1], got {pose[3].tolist()}")
    warnings = []
    if pose.shape == (4, 4):  # the one rotation rule: repaired (with a warning beyond float noise) or refused
        rotation, warning = repaired_rotation(pose[:3, :3], f"{path}: field lidar_pose")
        pose = pose.copy()
        pose[:3, :3] = rotation
        if warning is not None:
            warnings.append(warning.removeprefix(f"{path}: "))
    translation = pose[:3, 3] if pose.shape == (4, 4) else pose[:3]
    if not np.all(np.abs(translation) <= MAX_COORDINATE_M):  # the scene writer's limit, which cost the scenario
        raise InputError(f"{path}: field lidar_pose: expected a position within {MAX_COORDINATE_M:g} m, got "
                         f"{translation.tolist()}")
    if "vehicles" not in data:
        warnings.append("field vehicles: expected the labelled objects (an empty mapping when none), got no such "
                        "field; this agent labels no object in this frame")
    poses = {}
    for key in ("true_ego_pos", "predicted_ego_pos"):
        poses[key] = None if data.get(key) is None else _degrees(_floats(data[key], path, key, shape=(6,)), path, key)
    cameras = {}
    for key, value in data.items():
        if isinstance(key, str) and CAMERA_KEY.match(key):
            if not isinstance(value, dict):
                raise InputError(f"{path}: field {key}: expected a mapping, got {shown(value)}")
            cameras[key] = Camera(
                cords=None if value.get("cords") is None
                else _degrees(_floats(value["cords"], path, f"{key}.cords", shape=(6,)), path, f"{key}.cords"),
                extrinsic=_floats(value.get("extrinsic"), path, f"{key}.extrinsic", shape=(4, 4)),
                intrinsic=_floats(value.get("intrinsic"), path, f"{key}.intrinsic", shape=(3, 3)),
            )
    rsu = data.get("RSU", False)
    if not isinstance(rsu, bool):  # "garbage" made the ego an RSU
        raise InputError(f"{path}: field RSU: expected true or false, got {shown(rsu)}")
    vehicles, bad = _vehicles({} if data.get("vehicles") is None else data["vehicles"], path)
    return AgentFrame(lidar_pose=pose, true_ego_pos=poses["true_ego_pos"], predicted_ego_pos=poses["predicted_ego_pos"],
                      rsu=rsu, vehicles=vehicles, bad_vehicles=bad, cameras=cameras,
                      warnings=tuple(warnings))


#: The most list items and numbers a number field holds (a 4x4 pose: 5 lists, 16 numbers), with room to spare.
_MAX_FIELD_ITEMS = 64


def _leaves(value: Any) -> list[Any] | None:
    """The numbers of a nested list field, or None when it holds more than :data:`_MAX_FIELD_ITEMS` items.

    Bounded, as YAML aliases can make a field of 10^9 numbers out of a few lines (a "billion laughs" file).
    """
    leaves, stack, visited = [], [value], 0
    while stack:
        visited += 1
        if visited > _MAX_FIELD_ITEMS:
            return None
        item = stack.pop()
        if isinstance(item, list):
            stack.extend(reversed(item))
        else:
            leaves.append(item)
    return leaves


def _degrees(pose: np.ndarray, path: Source, field: str) -> np.ndarray:
    """``pose`` after checking its last three values (angles in degrees) are within :data:`MAX_ANGLE_DEG`."""
    if not np.all(np.abs(pose[-3:]) <= MAX_ANGLE_DEG):
        raise InputError(f"{path}: field {field}: expected angles within +-{MAX_ANGLE_DEG:g} deg, got {pose[-3:].tolist()}")
    return pose


def _floats(value: Any, path: Source, field: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
    leaves = _leaves(value)
    if leaves is None:
        raise InputError(f"{path}: field {field}: expected at most {_MAX_FIELD_ITEMS} numbers and lists, got more")
    if any(isinstance(v, bool) for v in leaves):  # YAML true is not the number 1
        raise InputError(f"{path}: field {field}: expected numbers, got {shown(value)}")
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{path}: field {field}: expected numbers, got {shown(value)}") from None
    if value is None or (shape is not None and array.shape != shape):
        raise InputError(f"{path}: field {field}: expected shape {shape}, got {shown(value)}")
    if not np.all(np.isfinite(array)):
        raise InputError(f"{path}: field {field}: expected finite numbers, got {array.tolist()}")
    return array


def _vehicles(entries: Any, path: Source) -> tuple[Vehicles, tuple[str, ...]]:
    if not isinstance(entries, dict):
        raise InputError(f"{path}: field vehicles: expected a mapping id -> vehicle, got {shown(entries)}")
    rows = []
    bad = []
    for key, entry in entries.items():
        field = f"vehicles.{key}"
        try:
            object_id = _integer(key)
            if not isinstance(entry, dict):
                raise InputError(f"{path}: field {field}: expected a mapping, got {shown(entry)}")
            extent = _floats(entry.get("extent"), path, f"{field}.extent", shape=(3,))
            if np.any(extent <= 0.0):
                raise InputError(f"{path}: field {field}.extent: expected positive half sizes, got {extent.tolist()}")
            speed = entry.get("speed")
            obj_type = entry.get("obj_type", "Car")
            if not isinstance(obj_type, str):  # null was the class "None"
                raise InputError(f"{path}: field {field}.obj_type: expected a class name, got {shown(obj_type)}")
            speed_kmh = float("nan") if speed is None else float(_floats(speed, path, f"{field}.speed", shape=()))
            if not 0.0 <= speed_kmh <= MAX_SPEED_MPS * 3.6 and speed is not None:  # -1 reversed the velocity
                raise InputError(f"{path}: field {field}.speed: expected km/h in [0, {MAX_SPEED_MPS * 3.6:g}], got {speed!r}")
            rows.append((
                object_id,
                _floats(entry.get("location"), path, f"{field}.location", shape=(3,)),
                _floats(entry.get("center", [0.0, 0.0, 0.0]), path, f"{field}.center", shape=(3,)),
                extent,
                _degrees(_floats(entry.get("angle"), path, f"{field}.angle", shape=(3,)), path, f"{field}.angle"),
                speed_kmh,
                obj_type,
                _integer(entry.get("ass_id", -1)),
            ))
        except InputError as error:
            bad.append(str(error).removeprefix(f"{path}: "))
        except (TypeError, ValueError, OverflowError):  # OverflowError: int(inf)
            bad.append(f"field {field}: expected an integer id and ass_id, got {shown(key)} / {shown(entry)}")
    n = len(rows)
    columns = list(zip(*rows, strict=True)) if rows else [()] * 8
    return Vehicles(
        ids=np.asarray(columns[0], dtype=np.int64),
        location=np.asarray(columns[1], dtype=np.float64).reshape(n, 3),
        center=np.asarray(columns[2], dtype=np.float64).reshape(n, 3),
        extent_half=np.asarray(columns[3], dtype=np.float64).reshape(n, 3),
        angle_deg=np.asarray(columns[4], dtype=np.float64).reshape(n, 3),
        speed_kmh=np.asarray(columns[5], dtype=np.float64),
        obj_type=np.asarray(columns[6], dtype=str),
        ass_id=np.asarray(columns[7], dtype=np.int64),
    ), tuple(bad)


def _integer(value: Any) -> int:
    """An integer field (an id, ``ass_id``) in int64 range: an int, or a float with an integral value; ValueError otherwise."""
    if isinstance(value, bool) or not float(value).is_integer() or not -(2**63) <= int(float(value)) < 2**63:
        raise ValueError(value)
    return int(value)


def intensity_from_rgb(rgb: np.ndarray) -> np.ndarray:
    """(N,) float32 intensity in [0, 1] from OPV2V's packed ``rgb`` float: red byte / 255 (open3d's ``colors[:, 0]``)."""
    bits = np.ascontiguousarray(rgb, dtype=np.float32).view(np.uint32)
    intensity: np.ndarray = (((bits >> 16) & 0xFF).astype(np.float32) / np.float32(255.0)).astype(np.float32)
    return intensity


def frame_files(agent_dir: Source, names: Iterable[str]) -> dict[int, Source]:
    """Frame number -> YAML path of one agent folder, whose names are ``names``.

    Folders and broken links with a frame file's name are kept: reading them is an error.
    """
    out = {}
    for name in names:
        match = FRAME_FILE.match(name)
        if match:
            out[int(match.group(1))] = agent_dir / name
    return dict(sorted(out.items()))


def png_size(data: bytes, path: Source) -> tuple[int, int]:
    """(width, height) from a PNG's IHDR chunk, after checking the whole file (every chunk's CRC).

    Raises:
        InputError: not a PNG, truncated or damaged (naming the chunk).
    """
    problem, size = png_problem(data)
    if problem is not None:
        raise InputError(f"{path}: {problem}")
    return size
