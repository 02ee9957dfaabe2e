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
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import cast

from avdata.errors import AvdataError
from avdata.schema import UNIFIED_CLASSES

#: Per-agent values: (pattern, value) pairs, first match wins; a number or a mapping pattern -> value
#: is accepted and stored as pairs.
AgentValues = tuple[tuple[str, float], ...] | float | Mapping[str, float]

#: Fusion modes of the collaborative loader: None keeps one cloud per sensor, "early" concatenates.
FUSION_MODES = (None, "early")


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
        unknown = sorted(set(self.classes) - set(UNIFIED_CLASSES))
        if unknown or not self.classes:
            raise AvdataError(f"expected classes from the unified taxonomy {UNIFIED_CLASSES}, got {list(self.classes)}")
        if len(set(self.classes)) != len(self.classes):
            raise AvdataError(f"expected distinct classes, got {list(self.classes)}")
        if self.max_range_m is not None and not self.max_range_m > 0:
            raise AvdataError(f"expected max_range_m > 0, got {self.max_range_m}")
        if self.min_points is not None and self.min_points < 0:
            raise AvdataError(f"expected min_points >= 0, got {self.min_points}")
        if self.max_occlusion is not None and not 0 <= self.max_occlusion <= 3:
            raise AvdataError(f"expected max_occlusion in 0..3, got {self.max_occlusion}")
        if (self.min_points is not None or self.max_occlusion is not None) and not self.visible_to:
            raise AvdataError("expected visible_to (the sensor whose visibility labels to use) with min_points or "
                              f"max_occlusion, got visible_to={self.visible_to}")


@dataclass(frozen=True, slots=True, kw_only=True)
class Collaboration:
    """Which agents' data reach the ego, for V2I/V2V trade studies (range, rate, noise).

    The reference agent (the dataset's ego) always receives its own data. Another agent's data
    arrive at a frame when the agent lies within ``comm_range_m`` of the ego (3D distance between
    body-frame origins at the frame's time) and the frame opens a new transmission slot of that
    agent's rate: slots are ``1 / rate_hz`` long from the scene's first frame, and an agent sends in
    the first frame of each slot (10 Hz frames at 5 Hz send frames 0, 2, 4 ...).

    Attributes:
        agents: agent names or glob patterns ("ego", "infra_*").
        fusion: None (one cloud per sensor) or "early" (one cloud with an ``agent_index`` field).
        comm_range_m: communication range, or None for unlimited.
        rate_hz: (pattern, Hz) pairs; the first matching pattern wins; agents matching none send
            every frame. Also accepted: one number (every agent) or a mapping pattern -> Hz.
        noise_std_m: (pattern, metres) pairs: standard deviation of Gaussian noise added to each
            point's x, y, z (in its sensor frame) of matching agents, deterministic per
            (seed, scene, frame, sensor). Also accepted: one number or a mapping pattern -> metres.
        seed: seed of the noise.

    Rate and noise model the communication link, so they never apply to the ego's own sensors.
    """

    agents: tuple[str, ...]
    fusion: str | None = None
    comm_range_m: float | None = None
    rate_hz: AgentValues = ()
    noise_std_m: AgentValues = ()
    seed: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "agents", as_patterns(self.agents, "agents") or ())
        object.__setattr__(self, "rate_hz", per_agent(self.rate_hz, "rate_hz"))
        object.__setattr__(self, "noise_std_m", per_agent(self.noise_std_m, "noise_std_m"))
        if not self.agents:
            raise AvdataError("expected at least one agent pattern, got none")
        if self.fusion not in FUSION_MODES:
            raise AvdataError(f"expected fusion one of {FUSION_MODES}, got {self.fusion!r}")
        if self.comm_range_m is not None and not self.comm_range_m > 0:
            raise AvdataError(f"expected comm_range_m > 0, got {self.comm_range_m}")
        for pattern, hz in _pairs(self.rate_hz):
            if not hz > 0:
                raise AvdataError(f"expected a positive rate for agents {pattern!r}, got {hz} Hz")
        for pattern, std in _pairs(self.noise_std_m):
            if not std >= 0:
                raise AvdataError(f"expected a non-negative noise for agents {pattern!r}, got {std} m")

    def rate_of(self, agent: str) -> float | None:
        """The sending rate of ``agent`` in Hz, or None for every frame."""
        return _first_match(_pairs(self.rate_hz), agent)

    def noise_of(self, agent: str) -> float:
        """The point noise standard deviation of ``agent`` in metres (0 for none)."""
        return _first_match(_pairs(self.noise_std_m), agent) or 0.0


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
    if isinstance(value, tuple) and all(isinstance(p, tuple) and len(p) == 2 for p in value):
        return tuple((str(pattern), float(v)) for pattern, v in value)
    if isinstance(value, Mapping):
        return tuple((str(pattern), float(v)) for pattern, v in value.items())
    if isinstance(value, (int, float)):
        return (("*", float(value)),)
    raise AvdataError(f"expected {name} as a number or a mapping agent pattern -> number, got {value!r}")


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
    patterns = tuple(value)
    if not all(isinstance(p, str) and p for p in patterns):
        raise AvdataError(f"expected {name} as strings, got {value!r}")
    return patterns
