"""Scenario configuration: frozen dataclasses, loaded from YAML with errors that name the field.

A scenario file (see ``presets/*.yaml``) has the keys ``scenes``, ``frames``, ``seed``,
``frame_rate_hz``, ``town`` (:class:`~avdata.generators.town.TownConfig`), ``traffic``
(:class:`~avdata.generators.traffic.TrafficConfig`), ``egos`` (list of agents with sensors) and
``infrastructure`` (count, placement, height, pitch, sensors). Sensor mounts are given in the agent's
body frame as ``mount_xyz_m`` and ``mount_ypr_deg`` (yaw, pitch, roll: intrinsic "ZYX"; positive
pitch turns x downwards); a camera's mount is its x-forward body, its optical frame is derived.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from avdata.errors import InputError, yaml_problem
from avdata.generators.camera import CameraConfig
from avdata.generators.lidar import LidarConfig
from avdata.generators.sizes import VEHICLE_CLASSES
from avdata.generators.town import CURB_HEIGHT_M, TownConfig
from avdata.generators.traffic import SIM_STEP_S, TrafficConfig
from avdata.inputs import UniqueKeyLoader, refuse_special_file

PRESETS_DIR = Path(__file__).parent / "presets"
PRESETS = ("v2i-intersection", "v2i-town")


@dataclass(frozen=True, slots=True, kw_only=True)
class SensorConfig:
    """One sensor on an agent.

    Attributes:
        name: sensor name; its frame is ``<agent>/<name>``.
        kind: "lidar" or "camera".
        mount_xyz_m: (3,) position in the agent's body frame.
        mount_ypr_deg: (3,) yaw, pitch, roll in degrees (intrinsic ZYX) relative to the body frame.
        lidar: LiDAR parameters (kind "lidar").
        camera: camera parameters (kind "camera").
    """

    name: str
    kind: str
    mount_xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mount_ypr_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lidar: LidarConfig | None = None
    camera: CameraConfig | None = None

    @property
    def lidar_config(self) -> LidarConfig:
        """The LiDAR parameters of a "lidar" sensor."""
        if self.lidar is None:
            raise InputError(f"sensor {self.name}: expected lidar parameters, got none")
        return self.lidar

    @property
    def camera_config(self) -> CameraConfig:
        """The camera parameters of a "camera" sensor."""
        if self.camera is None:
            raise InputError(f"sensor {self.name}: expected camera parameters, got none")
        return self.camera

    @property
    def rate_hz(self) -> float:
        """The sensor's recording rate."""
        return self.lidar_config.rate_hz if self.kind == "lidar" else self.camera_config.rate_hz

    def spec(self) -> dict[str, Any]:
        """The sensor spec written into the scene metadata."""
        return self.lidar_config.spec() if self.kind == "lidar" else self.camera_config.spec()


@dataclass(frozen=True, slots=True, kw_only=True)
class EgoConfig:
    """A moving agent: one of the traffic's cars, with sensors.

    Attributes:
        name: agent (body frame) name, e.g. "ego" or "cav_1".
        sensors: its sensors.
    """

    name: str
    sensors: tuple[SensorConfig, ...] = ()


@dataclass(frozen=True, slots=True, kw_only=True)
class InfrastructureConfig:
    """Static sensor units on poles.

    Attributes:
        count: number of units, named ``infra_00``, ``infra_01`` ...
        placement: "intersections" (corners of intersections, facing their centre) or "random"
            (along roads, facing across the road).
        height_m: sensor height above the road.
        pitch_deg: downward pitch of the sensors.
        sensors: the sensors of every unit (mounts relative to the pole top, facing forward).
    """

    count: int = 0
    placement: str = "intersections"
    height_m: float = 15.0
    pitch_deg: float = 30.0
    sensors: tuple[SensorConfig, ...] = ()


@dataclass(frozen=True, slots=True, kw_only=True)
class ScenarioConfig:
    """A complete scenario.

    Attributes:
        scenes: number of scenes, each with its own town and traffic (seed + scene index).
        frames: frames per scene.
        seed: base random seed.
        frame_rate_hz: frames per second.
        town, traffic, egos, infrastructure: see their classes.
    """

    scenes: int = 1
    frames: int = 20
    seed: int = 0
    frame_rate_hz: float = 10.0
    town: TownConfig = field(default_factory=TownConfig)
    traffic: TrafficConfig = field(default_factory=TrafficConfig)
    egos: tuple[EgoConfig, ...] = ()
    infrastructure: InfrastructureConfig = field(default_factory=InfrastructureConfig)

    def to_dict(self) -> dict[str, Any]:
        """Plain data (for YAML and the scene metadata)."""
        plain: dict[str, Any] = _plain(dataclasses.asdict(self))
        return plain


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


#: (class, field) -> inclusive (low, high) of every number in it (each element of a list field). Values
#: beyond these are typing slips (1e9 rays, -3 scenes), refused before any work instead of a MemoryError
#: or hours of work; README's tolerances section lists them.
MAX_SEED = 2**32 - 1
LIMITS: dict[tuple[str, str], tuple[float, float]] = {
    ("ScenarioConfig", "scenes"): (1, 10_000),
    ("ScenarioConfig", "frames"): (1, 100_000),
    ("ScenarioConfig", "frame_rate_hz"): (0.01, 1_000),
    ("LidarConfig", "azimuth_steps"): (1, 16_384),
    ("LidarConfig", "horizontal_fov_deg"): (0.01, 360),
    ("LidarConfig", "max_range_m"): (0.01, 10_000),
    ("LidarConfig", "min_range_m"): (0, 10_000),
    ("LidarConfig", "rate_hz"): (0.01, 1_000),
    ("LidarConfig", "range_noise_std_m"): (0, 100),
    ("LidarConfig", "dropout"): (0, 1),
    ("CameraConfig", "width"): (1, 8_192),
    ("CameraConfig", "height"): (1, 8_192),
    ("CameraConfig", "horizontal_fov_deg"): (0.01, 179),
    ("CameraConfig", "near_m"): (0.001, 10_000),
    ("CameraConfig", "far_m"): (0.001, 10_000),
    ("CameraConfig", "rate_hz"): (0.01, 1_000),
    ("TownConfig", "grid"): (2, 50),
    ("TownConfig", "block_pitch_m"): (40, 1_000),
    ("TownConfig", "lane_width_m"): (1, 10),
    ("TownConfig", "parking_width_m"): (0, 10),
    ("TownConfig", "sidewalk_width_m"): (0, 20),
    ("TownConfig", "building_height_m"): (1, 1_000),
    ("TownConfig", "parked_per_100m"): (0, 50),
    ("TownConfig", "tree_spacing_m"): (1, 1_000),
    ("TrafficConfig", "vehicles"): (0, 10_000),
    ("TrafficConfig", "pedestrians"): (0, 10_000),
    ("TrafficConfig", "crossing_pedestrians"): (0, 10_000),
    ("TrafficConfig", "parked_fraction"): (0, 1),
    ("TrafficConfig", "time_headway_s"): (0, 100),
    ("TrafficConfig", "min_gap_m"): (0, 1_000),
    ("TrafficConfig", "green_s"): (0.1, 3_600),
    ("TrafficConfig", "all_red_s"): (0, 3_600),
    ("TrafficConfig", "warmup_s"): (0, 3_600),
    ("TrafficConfig", "class_weights"): (0, 1e6),
    ("InfrastructureConfig", "count"): (0, 1_000),
    ("InfrastructureConfig", "height_m"): (0, 1_000),
    ("InfrastructureConfig", "pitch_deg"): (-90, 90),
    ("SensorConfig", "mount_xyz_m"): (-1_000, 1_000),
    ("SensorConfig", "mount_ypr_deg"): (-360, 360),
}

_NESTED = {"town": TownConfig, "traffic": TrafficConfig, "infrastructure": InfrastructureConfig,
           "lidar": LidarConfig, "camera": CameraConfig}
"""Fields whose value is itself a configuration object."""


def _build(cls: type, data: Any, where: str, source: str) -> Any:
    if not isinstance(data, dict):
        raise InputError(f"{source}: field {where}: expected a mapping, got {data!r}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise InputError(f"{source}: field {where + '.' if where else ''}{unknown[0]}: expected one of {sorted(fields)}, "
                         f"got {unknown[0]!r}")
    kwargs: dict[str, Any] = {}
    for name, value in data.items():
        path = f"{where}.{name}" if where else name
        if name in _NESTED and (value is not None or type(None) not in typing.get_args(hints[name])):  # town: null
            kwargs[name] = _build(_NESTED[name], value, path, source)
        elif name in ("egos", "sensors") and not isinstance(value, list | None):
            raise InputError(f"{source}: field {path}: expected a list, got {value!r}")
        elif name == "egos":
            kwargs[name] = tuple(_build(EgoConfig, v, f"{path}[{i}]", source) for i, v in enumerate(value or []))
        elif name == "sensors":
            kwargs[name] = tuple(_build(SensorConfig, v, f"{path}[{i}]", source) for i, v in enumerate(value or []))
        else:
            kwargs[name] = tuple(value) if isinstance(value, list) else value
            _check_type(kwargs[name], hints[name], path, source)
            _check_range(kwargs[name], LIMITS.get((cls.__name__, name)), path, source)
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as error:
        raise InputError(f"{source}: field {where or '<top>'}: {error}") from error


def _check_type(value: Any, hint: Any, path: str, source: str) -> None:
    """Raises InputError unless ``value`` is of the field's declared type (YAML ``'two'`` for an int ...)."""
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if hint is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
        expected = "an integer"
    elif hint is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
        expected = "a finite number"
    elif hint is str:
        ok, expected = isinstance(value, str), "a string"
    elif hint is bool:
        ok, expected = isinstance(value, bool), "true or false"
    elif origin is tuple:
        fixed = not (len(args) == 2 and args[1] is Ellipsis)
        ok = isinstance(value, tuple) and (not fixed or len(value) == len(args))
        expected = f"a list of {len(args)} values" if fixed else "a list"
        if ok:
            for i, item in enumerate(value):
                _check_type(item, args[i] if fixed else args[0], f"{path}[{i}]", source)
    elif origin is dict:
        ok, expected = isinstance(value, dict), "a mapping"
        if ok:
            for key, item in value.items():
                _check_type(key, args[0], f"{path} key", source)
                _check_type(item, args[1], f"{path}.{key}", source)
    else:
        return
    if not ok:
        raise InputError(f"{source}: field {path}: expected {expected}, got {value!r}")


def _check_range(value: Any, limits: tuple[float, float] | None, path: str, source: str) -> None:
    """Raises InputError unless every number of a (type-checked) field value lies within ``limits``."""
    if limits is None:
        return
    numbers = value.values() if isinstance(value, dict) else value if isinstance(value, tuple) else (value,)
    low, high = limits
    for number in numbers:
        if not low <= number <= high:
            raise InputError(f"{source}: field {path}: expected values in [{low:g}, {high:g}], got {value!r}")


def scenario_from_dict(data: dict[str, Any], source: str) -> ScenarioConfig:
    """Builds and checks a scenario from plain data; ``source`` names the file in errors."""
    config: ScenarioConfig = _build(ScenarioConfig, data, "", source)
    # Ego names beside the infrastructure units' (infra_00 ...) and the world frame: a name given twice failed only
    # once the scene was simulated, as two poses of one frame.
    taken = {"world", *(f"infra_{k:02d}" for k in range(config.infrastructure.count))}
    for i, ego in enumerate(config.egos):
        _check_name(ego.name, taken, f"egos[{i}].name", source)
        _check_sensors(ego.sensors, f"egos[{i}].sensors", source)
    _check_sensors(config.infrastructure.sensors, "infrastructure.sensors", source)
    if config.infrastructure.height_m <= CURB_HEIGHT_M:  # the poles stand on the sidewalk: 0 m was a pybullet error
        raise InputError(f"{source}: field infrastructure.height_m: expected more than the {CURB_HEIGHT_M:g} m curb the "
                         f"poles stand on, got {config.infrastructure.height_m:g}")
    if config.infrastructure.placement not in ("intersections", "random"):
        raise InputError(f"{source}: field infrastructure.placement: expected 'intersections' or 'random', "
                         f"got {config.infrastructure.placement!r}")
    weights = config.traffic.class_weights
    unknown = sorted(set(weights) - set(VEHICLE_CLASSES))
    if unknown or not weights or min(weights.values()) < 0 or sum(weights.values()) <= 0:
        raise InputError(f"{source}: field traffic.class_weights: expected non-negative weights of "
                         f"{list(VEHICLE_CLASSES)}, got {weights}")
    if min(config.town.grid) < 2:
        raise InputError(f"{source}: field town.grid: expected at least 2 x 2 intersections, got {list(config.town.grid)}")
    if config.seed < 0:
        raise InputError(f"{source}: field seed: expected an integer >= 0, got {config.seed}")
    if config.seed > MAX_SEED:
        raise InputError(f"{source}: field seed: expected an integer <= {MAX_SEED}, got {config.seed}")
    if config.frame_rate_hz <= 0:
        raise InputError(f"{source}: field frame_rate_hz: expected > 0, got {config.frame_rate_hz}")
    if _whole_steps(1.0 / config.frame_rate_hz) < 1:
        raise InputError(f"{source}: field frame_rate_hz: expected {1 / SIM_STEP_S:g} Hz divided by a whole number "
                         f"(frames are whole {SIM_STEP_S:g} s simulation steps), got {config.frame_rate_hz:g}")
    if _whole_steps(config.traffic.warmup_s) < LABEL_STEPS:
        raise InputError(f"{source}: field traffic.warmup_s: expected a multiple of {SIM_STEP_S:g} s of at least "
                         f"{LABEL_STEPS * SIM_STEP_S:g} s (the first labels difference {LABEL_STEPS} simulation steps), "
                         f"got {config.traffic.warmup_s:g}")
    if config.frames < 1 or config.scenes < 1:
        raise InputError(f"{source}: field frames/scenes: expected >= 1, got {config.frames}/{config.scenes}")
    building = config.town.building_height_m
    if building[0] > building[1]:
        raise InputError(f"{source}: field town.building_height_m: expected [lowest, highest], got {list(building)}")
    sensors = [*(s for ego in config.egos for s in ego.sensors), *config.infrastructure.sensors]
    for s in sensors:
        if s.rate_hz > config.frame_rate_hz:
            raise InputError(f"{source}: sensor {s.name}: expected rate_hz <= frame_rate_hz={config.frame_rate_hz:g} "
                             f"(a sensor records at most once per frame), got {s.rate_hz:g}")
        if s.kind == "lidar" and s.lidar is not None and not s.lidar.min_range_m < s.lidar.max_range_m:
            raise InputError(f"{source}: sensor {s.name}: expected lidar min_range_m < max_range_m, got "
                             f"{s.lidar.min_range_m} and {s.lidar.max_range_m}")
        if s.kind == "camera" and s.camera is not None and not s.camera.near_m < s.camera.far_m:
            raise InputError(f"{source}: sensor {s.name}: expected camera near_m < far_m, got {s.camera.near_m} and "
                             f"{s.camera.far_m}")
    if len(config.egos) > config.traffic.vehicles:
        raise InputError(f"{source}: field egos: expected at most traffic.vehicles={config.traffic.vehicles} egos, "
                         f"got {len(config.egos)}")
    return config


#: Poses the labels difference (velocity, acceleration): the first frame needs as many warm-up steps.
LABEL_STEPS = 3


def _whole_steps(duration_s: float) -> int:
    """``duration_s`` in simulation steps, or -1 if it is not a whole number of them.

    The simulator advances in whole steps: a frame period of 1.5 steps (30 Hz) was simulated as one step while the
    frame times said 33 ms, and a warm-up shorter than :data:`LABEL_STEPS` crashed on the first frame's labels.
    """
    steps = duration_s / SIM_STEP_S
    return round(steps) if abs(steps - round(steps)) <= 1e-6 * steps else -1


def _check_name(name: str, taken: set[str], path: str, source: str) -> None:
    """Adds ``name`` to ``taken`` unless it is empty, has a '/' (frames are ``<agent>/<sensor>``) or is taken."""
    if not name or "/" in name or name in taken:
        raise InputError(f"{source}: field {path}: expected a name without '/' that no other agent or sensor of its "
                         f"agent has, got {name!r}")
    taken.add(name)


def _check_sensors(sensors: tuple[SensorConfig, ...], where: str, source: str) -> None:
    names: set[str] = set()
    for i, s in enumerate(sensors):
        _check_name(s.name, names, f"{where}[{i}].name", source)
        if s.kind not in ("lidar", "camera"):
            raise InputError(f"{source}: field {where}[{i}].kind: expected 'lidar' or 'camera', got {s.kind!r}")
        if getattr(s, s.kind) is None:
            raise InputError(f"{source}: field {where}[{i}].{s.kind}: expected the {s.kind} parameters, got none")


def load_scenario(path: str | Path) -> ScenarioConfig:
    """Reads a scenario YAML file."""
    path = Path(path)
    refuse_special_file(path)
    try:
        data = yaml.load(path.read_text(), Loader=UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except OSError as error:
        raise InputError(f"{path}: expected a readable scenario file, got {error.strerror}") from error
    except yaml.YAMLError as error:
        raise InputError(f"{path}: expected valid YAML, got {yaml_problem(error)}") from error
    except UnicodeDecodeError as error:
        byte = error.object[error.start]
        raise InputError(f"{path}: expected UTF-8 YAML, got byte {byte:#04x} at offset {error.start}") from None
    except ValueError as error:  # a key given twice (DuplicateKeyError), an integer of 5000 digits
        raise InputError(f"{path}: {error}") from None
    return scenario_from_dict(data or {}, str(path))


def load_preset(name: str) -> ScenarioConfig:
    """A built-in scenario by name (see :data:`PRESETS`)."""
    if name not in PRESETS:
        raise InputError(f"--preset: expected one of {list(PRESETS)}, got {name!r}")
    return load_scenario(PRESETS_DIR / f"{name}.yaml")
