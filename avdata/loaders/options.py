"""Frozen, keyword-only options of the loaders, validated once when they are made.

:class:`FrameOptions` is everything that shapes an item of :class:`~avdata.loaders.FrameDataset`; it
holds a :class:`LabelFilter` (which objects) and, for collaborative items, a :class:`Collaboration`
(which agents' data arrive). Options are plain values (strings, numbers, tuples), so a dataset pickles
into DataLoader worker processes without dragging open files or readers along.

Example::

    options = FrameOptions(
        sensors=("*/lidar*",),
        frame="ego",
        labels=LabelFilter(classes=("car", "pedestrian"), max_range_m=50.0),
        collaboration=Collaboration(agents=("ego", "infra_*"), fusion="early", rate_hz={"infra_*": 5.0}),
    )
"""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import cast

import numpy as np

from avdata.errors import AvdataError, shown
from avdata.schema import UNIFIED_CLASSES

#: Per-agent values: (pattern, value) pairs, first match wins; a number or a mapping pattern -> value
#: is accepted and stored as pairs.
AgentValues = tuple[tuple[str, float], ...] | float | Mapping[str, float]

#: Fusion modes of the collaborative loader: None keeps one cloud per sensor, "early" concatenates them in
#: the item's frame, "intermediate" keeps one cloud per agent in that agent's own frame with pairwise
#: transforms (OpenCOOD's layout), "late" adds each agent's own label set in its frame.
FUSION_MODES = (None, "early", "intermediate", "late")
#: Where a collaborator's transmitted pose comes from: the recorded pose, or the GPS-noised
#: ``<agent>/vehicle_predicted`` frame OPV2V's converter keeps (``predicted_ego_pos``).
POSE_SOURCES = ("true", "predicted")


@dataclass(frozen=True, slots=True, kw_only=True)
class LabelFilter:
    """Which annotated objects an item keeps.

    An object is kept when its class is in ``classes``, its centre lies within ``max_range_m`` of
    the ego origin (horizontal distance, ego body frame at the item's time), and, when
    ``visible_to`` is set, at least one matching sensor saw it: ``in_fov`` and ``n_points >=
    min_points`` (unknown counts, -1, never pass a ``min_points``) and ``occlusion <=
    max_occlusion``, all on that same sensor.

    Attributes:
        classes: unified class names; an object's class index is its position here.
        max_range_m: horizontal range from the ego origin, or None for no limit.
        min_points: least lidar returns on the object, or None.
        max_occlusion: largest occlusion level (0 none .. 3 fully/unknown), or None.
        visible_to: sensor frames or glob patterns ("ego/lidar_top", "infra_*/lidar"), or None.
    """

    classes: tuple[str, ...] = UNIFIED_CLASSES
    max_range_m: float | None = None
    min_points: int | None = None
    max_occlusion: int | None = None
    visible_to: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "classes", as_patterns(self.classes, "classes") or ())
        object.__setattr__(self, "visible_to", as_patterns(self.visible_to, "visible_to"))
        for name in ("max_range_m", "min_points", "max_occlusion"):
            _check_number(getattr(self, name), name)
        unknown = sorted(set(self.classes) - set(UNIFIED_CLASSES))
        if unknown or not self.classes:
            raise AvdataError(f"expected classes from the unified taxonomy {UNIFIED_CLASSES}, got {list(self.classes)}")
        if len(set(self.classes)) != len(self.classes):
            raise AvdataError(f"expected distinct classes, got {list(self.classes)}")
        if self.max_range_m is not None and not self.max_range_m > 0:
            raise AvdataError(f"expected max_range_m > 0, got {self.max_range_m}")
        if self.min_points is not None and not self.min_points >= 0:
            raise AvdataError(f"expected min_points >= 0, got {self.min_points}")
        if self.max_occlusion is not None and not 0 <= self.max_occlusion <= 3:
            raise AvdataError(f"expected max_occlusion in 0..3, got {self.max_occlusion}")
        if (self.min_points is not None or self.max_occlusion is not None) and not self.visible_to:
            raise AvdataError("expected visible_to (the sensor whose visibility labels to use) with min_points or "
                              f"max_occlusion, got visible_to={self.visible_to}")


@dataclass(frozen=True, slots=True, kw_only=True)
class Collaboration:
    """Which agents' data reach the ego, for V2I/V2V trade studies (range, rate, noise).

    The reference agent (the dataset's ego) always receives its own data, unchanged by every option
    below. Another agent sends in the first frame of each transmission slot of its rate (slots are
    ``1 / rate_hz`` long from the scene's first frame: 10 Hz frames at 5 Hz send frames 0, 2, 4 ...).
    At a frame of time t, the ego holds that agent's last transmission sent at or before
    ``t - latency``; the agent is received when it lies within ``comm_range_m`` of the ego (3D
    distance between body-frame origins at t) and that transmission is new (sent after the previous
    frame's ``t_prev - latency``). A transmission carries the agent's sensor messages of its frame,
    taken at their own capture times, and the agent's pose as transmitted (``pose_source``, then
    ``pose_noise``): clouds are moved with the poses of their own capture time, so latency is honest
    asynchrony (the ego has moved since), not a relabelled timestamp.

    Attributes:
        agents: agent names or glob patterns ("ego", "infra_*").
        fusion: None (one cloud per sensor), "early" (one cloud with an ``agent_index`` field),
            "intermediate" (one cloud per agent in its own frame, pairwise transforms, agent mask) or
            "late" (intermediate plus each agent's label set in its own frame); see FrameDataset.
        comm_range_m: communication range, or None for unlimited.
        rate_hz: (pattern, Hz) pairs; the first matching pattern wins; agents matching none send
            every frame. Also accepted: one number (every agent) or a mapping pattern -> Hz.
        noise_std_m: (pattern, metres) pairs: standard deviation of Gaussian noise added to each
            point's x, y, z (in its sensor frame) of matching agents, deterministic per
            (seed, scene, frame, sensor). Also accepted: one number or a mapping pattern -> metres.
        seed: seed of the noise.
        max_agents: slots of the intermediate / late layouts (OpenCOOD's ``max_cav``); a frame with more
            matching agents is an error.
        latency_ms: (pattern, ms) pairs: transmission delay of matching agents (V2X-ViT's time delay);
            also one number or a mapping pattern -> ms.
        pose_noise: (sigma_x_m, sigma_y_m, sigma_z_m, sigma_yaw_deg) of Gaussian noise added to each
            transmitted agent pose in ``world`` (x, y, z and yaw), deterministic per (seed, scene, frame
            of the transmission, agent), as V2X-ViT's localisation-error study; None for none.
        pose_source: "true" (the recorded pose) or "predicted" (OPV2V's GPS-noised
            ``predicted_ego_pos``, frame ``<agent>/vehicle_predicted``; agents without it, e.g. road-side
            units whose pose is surveyed, send their true pose).

    Rate, latency and noise model the communication link, so they never apply to the ego's own data.
    """

    agents: tuple[str, ...]
    fusion: str | None = None
    comm_range_m: float | None = None
    rate_hz: AgentValues = ()
    noise_std_m: AgentValues = ()
    seed: int = 0
    max_agents: int = 5
    latency_ms: AgentValues = ()
    pose_noise: tuple[float, float, float, float] | None = None
    pose_source: str = "true"

    def __post_init__(self) -> None:
        object.__setattr__(self, "agents", as_patterns(self.agents, "agents") or ())
        object.__setattr__(self, "latency_ms", per_agent(self.latency_ms, "latency_ms"))
        _check_number(self.comm_range_m, "comm_range_m")
        # numpy's generators take a non-negative integer seed; anything else failed at the first item.
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise AvdataError(f"expected seed as an integer >= 0, got {self.seed!r}")
        if self.pose_noise is not None:
            sigmas = _floats(self.pose_noise)
            if len(sigmas) != 4 or not all(0 <= v < math.inf for v in sigmas):
                raise AvdataError("expected pose_noise as four finite non-negative sigmas (x_m, y_m, z_m, yaw_deg), "
                                  f"got {self.pose_noise!r}")
            object.__setattr__(self, "pose_noise", sigmas)
        if self.pose_source not in POSE_SOURCES:
            raise AvdataError(f"expected pose_source one of {POSE_SOURCES}, got {self.pose_source!r}")
        if isinstance(self.max_agents, bool) or not (isinstance(self.max_agents, int) and self.max_agents >= 1):
            raise AvdataError(f"expected max_agents >= 1, got {self.max_agents!r}")
        for pattern, ms in _pairs(self.latency_ms):
            if not 0 <= ms < math.inf:
                raise AvdataError(f"expected a finite non-negative latency for agents {pattern!r}, got {ms} ms")
        object.__setattr__(self, "rate_hz", per_agent(self.rate_hz, "rate_hz"))
        object.__setattr__(self, "noise_std_m", per_agent(self.noise_std_m, "noise_std_m"))
        if not self.agents:
            raise AvdataError("expected at least one agent pattern, got none")
        if self.fusion not in FUSION_MODES:
            raise AvdataError(f"expected fusion one of {FUSION_MODES}, got {self.fusion!r}")
        if self.comm_range_m is not None and not self.comm_range_m > 0:
            raise AvdataError(f"expected comm_range_m > 0, got {self.comm_range_m}")
        for pattern, hz in _pairs(self.rate_hz):
            if not 0 < hz < math.inf:
                raise AvdataError(f"expected a finite positive rate for agents {pattern!r}, got {hz} Hz")
        for pattern, std in _pairs(self.noise_std_m):
            if not 0 <= std < math.inf:
                raise AvdataError(f"expected a finite non-negative noise for agents {pattern!r}, got {std} m")

    def rate_of(self, agent: str) -> float | None:
        """The sending rate of ``agent`` in Hz, or None for every frame."""
        return _first_match(_pairs(self.rate_hz), agent)

    def noise_of(self, agent: str) -> float:
        """The point noise standard deviation of ``agent`` in metres (0 for none)."""
        return _first_match(_pairs(self.noise_std_m), agent) or 0.0

    def latency_ns_of(self, agent: str) -> int:
        """The transmission delay of ``agent`` in ns (0 for none)."""
        return int(round((_first_match(_pairs(self.latency_ms), agent) or 0.0) * 1e6))

    @property
    def moves_poses(self) -> bool:
        """Whether transmitted poses differ from the recorded ones (noise or a predicted source)."""
        return self.pose_source != "true" or (self.pose_noise is not None and any(self.pose_noise))


#: Sensor kinds whose messages are point clouds (the default sensors of a :class:`FrameOptions`).
POINT_CLOUD_KINDS = ("lidar", "radar")


@dataclass(frozen=True, slots=True, kw_only=True)
class FrameOptions:
    """Everything that shapes an item of :class:`~avdata.loaders.FrameDataset`.

    Attributes:
        sensors: sensor frames or glob patterns ("ego/lidar_top", "ego/cam_*", "*/lidar"); lidars
            and radars give points, cameras give images and calibrations; ``()`` gives labels only.
            None (the default) takes the point clouds (lidar and radar sensors) of the ego, or in
            collaborative items of every agent, that each frame has (none: an item without points).
        frame: the frame every point, box, pose and projection is expressed in.
        labels: which objects an item keeps.
        with_velocity: boxes (N, 9) with vx, vy instead of (N, 7).
        with_quaternions: add ``boxes_quat_wxyz`` (N, 4), the full orientations (for frames in which
            boxes are not upright, e.g. camera frames, where yaw alone loses the tilt).
        collaboration: collaborative items (several agents' data in ``frame``), or None.
    """

    sensors: tuple[str, ...] | None = None
    frame: str = "ego"
    labels: LabelFilter = field(default_factory=LabelFilter)
    with_velocity: bool = False
    with_quaternions: bool = False
    collaboration: Collaboration | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "sensors", as_patterns(self.sensors, "sensors"))
        if not isinstance(self.frame, str) or not self.frame:
            raise AvdataError(f"expected a frame name such as 'ego' or 'world', got {self.frame!r}")
        if not isinstance(self.labels, LabelFilter):
            raise AvdataError(f"expected labels as a LabelFilter, got {type(self.labels).__name__}")
        if self.collaboration is not None and not isinstance(self.collaboration, Collaboration):
            raise AvdataError(f"expected collaboration as a Collaboration or None, got {type(self.collaboration).__name__}")


def per_agent(value: AgentValues | None, name: str) -> tuple[tuple[str, float], ...]:
    """(pattern, value) pairs from pairs, one number (every agent) or a mapping agent pattern -> number."""
    if value is None:
        return ()
    pairs: list[tuple[object, object]] | None = None
    if isinstance(value, tuple) and all(isinstance(p, tuple) and len(p) == 2 for p in value):
        pairs = list(value)
    elif isinstance(value, Mapping):
        pairs = list(value.items())
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        pairs = [("*", value)]
    if pairs is None or not all(_is_number(v) for _, v in pairs):
        raise AvdataError(f"expected {name} as a number or a mapping agent pattern -> number, got {shown(value)}")
    return tuple((str(pattern), float(cast(float, v))) for pattern, v in pairs)


def _is_number(value: object) -> bool:
    """A real number (numpy's included), not a bool or a numeric string: ``float("5")`` would accept those."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def _check_number(value: object, name: str) -> None:
    """None or a real number; a string or a bool fails here, not as a TypeError in a comparison."""
    if value is not None and not _is_number(value):
        raise AvdataError(f"expected {name} as a number or None, got {shown(value)}")


def _floats(value: object) -> tuple[float, ...]:
    """The sigmas of ``pose_noise`` as floats (wrong types: an empty tuple, which the caller refuses)."""
    try:
        values = tuple(cast(Sequence[object], value))
    except TypeError:
        return ()
    return tuple(float(cast(float, v)) for v in values) if all(_is_number(v) for v in values) else ()


def _pairs(value: AgentValues) -> tuple[tuple[str, float], ...]:
    """The pairs a validated :class:`Collaboration` stores (its ``__post_init__`` made them pairs)."""
    return cast(tuple[tuple[str, float], ...], value)


def _first_match(pairs: tuple[tuple[str, float], ...], agent: str) -> float | None:
    for pattern, value in pairs:
        if fnmatch.fnmatchcase(agent, pattern):
            return value
    return None


def as_patterns(value: str | Sequence[str] | None, name: str) -> tuple[str, ...] | None:
    """A tuple of names / glob patterns from one string or a sequence of them."""
    if value is None:
        return None
    if isinstance(value, str):
        return (value,)
    try:
        patterns = tuple(value)
    except TypeError:
        raise AvdataError(f"expected {name} as a string or a sequence of strings, got {shown(value)}") from None
    if not all(isinstance(p, str) and p for p in patterns):
        raise AvdataError(f"expected {name} as strings, got {value!r}")
    return patterns


def agent_of(sensor: str) -> str:
    """The agent of a sensor frame ``<agent>/<sensor>`` (an agent's own frame is its own agent)."""
    return sensor.split("/", 1)[0]


def matches(name: str, patterns: tuple[str, ...]) -> bool:
    """Whether ``name`` matches any of the glob ``patterns``."""
    return any(fnmatch.fnmatchcase(name, p) for p in patterns)
