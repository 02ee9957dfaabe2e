"""Communication between agents: what the ego holds of each agent at a frame (range, rate, latency, pose error).

Each imperfection is deterministic per (seed, scene, frame, agent), and the ego's own data never change.
With ``latency_ms`` an agent's messages (and its pose) come from its last transmission at or before
``t - latency``; with ``pose_noise`` or ``pose_source="predicted"`` everything of another agent placed
through its pose uses the transmitted pose (:func:`sent`).
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from avdata.errors import AvdataError
from avdata.frames import Transform
from avdata.loaders.frame_index import SceneFrames
from avdata.loaders.items import ItemFrame
from avdata.loaders.options import Collaboration
from avdata.loaders.transforms import SceneTransforms


@dataclass(frozen=True, slots=True, kw_only=True)
class Link:
    """What the ego holds of one agent at a frame.

    Attributes:
        agent: the agent.
        received: whether its data arrive at this frame.
        distance_m: its distance from the ego at the frame's time.
        frame_index: the frame of the transmission held (the current frame for the ego and without latency).
        time_ns: that frame's time.
        sensor_times: that frame's sensor message times.
        world_T_recorded: ``world_sent_T_world`` (see :func:`pose_error`), None when the
            transmitted pose is the recorded one.
    """

    agent: str
    received: bool
    distance_m: float
    frame_index: int
    time_ns: int
    sensor_times: Mapping[str, int]
    world_T_recorded: Transform | None


def links(collaboration: Collaboration, at: ItemFrame, agents: list[str], frames: SceneFrames) -> list[Link]:
    """What the ego holds of each of ``agents`` (the ego first) at a frame, the ego first.

    In the intermediate and late layouts the received agents come next, so that the agent mask is a
    prefix (as OpenCOOD's ``record_len`` assumes).
    """
    transforms, t_ref = at.transforms, at.time_ns
    times = frames.times_ns
    here = int(np.searchsorted(times, t_ref))
    out = []
    for agent in agents:
        distance_m = float(np.linalg.norm(transforms.lookup(at.ego, agent, t_ref).translation))
        if agent == at.ego:
            out.append(Link(agent=agent, received=True, distance_m=distance_m, frame_index=int(frames.frame_indices[here]),
                            time_ns=t_ref, sensor_times=frames.sensor_times[here], world_T_recorded=None))
            continue
        latency_ns = collaboration.latency_ns_of(agent)
        sent_at = last_transmission(times, t_ref - latency_ns, collaboration.rate_of(agent))
        received = sent_at is not None and (at.prev_time_ns < 0 or int(times[sent_at]) > at.prev_time_ns - latency_ns)
        if collaboration.comm_range_m is not None and distance_m > collaboration.comm_range_m:
            received = False
        k = here if sent_at is None else sent_at
        link = Link(agent=agent, received=received, distance_m=distance_m, frame_index=int(frames.frame_indices[k]),
                    time_ns=int(times[k]), sensor_times=frames.sensor_times[k], world_T_recorded=None)
        if collaboration.moves_poses:
            link = replace(link, world_T_recorded=pose_error(collaboration, at.scene, link, transforms))
        out.append(link)
    if collaboration.fusion in ("intermediate", "late"):
        if len(out) > collaboration.max_agents:
            raise AvdataError(f"scene {at.scene!r} frame {at.frame_index}: expected at most "
                              f"max_agents={collaboration.max_agents} agents, got {[x.agent for x in out]}")
        out = out[:1] + sorted(out[1:], key=lambda x: not x.received)
    return out


def pose_error(collaboration: Collaboration, scene: str, link: Link, transforms: SceneTransforms) -> Transform:
    """``world_sent_T_world`` at the link's time, the agent's pose error as transmitted.

    It moves what the recorded pose places into where the transmitted one (``pose_source``, then
    ``pose_noise``) places it.
    """
    agent, t_ns = link.agent, link.time_ns
    world_T_agent = transforms.lookup("world", agent, t_ns)
    world_T_sent = world_T_agent
    if collaboration.pose_source == "predicted":
        predicted = f"{agent}/vehicle_predicted"
        if transforms.graph.can_lookup("world", predicted, t_ns):
            world_T_sent = (transforms.lookup("world", predicted, t_ns)
                            @ transforms.lookup(f"{agent}/vehicle", agent, t_ns))
        elif not transforms.graph.can_lookup("world", agent, None):  # only a surveyed (static) pose may lack it
            raise AvdataError(f"scene {scene!r} agent {agent!r}: pose_source='predicted' needs frame "
                              f"{predicted!r} at {t_ns} ns, got none")
    if collaboration.pose_noise is not None:
        rng = np.random.default_rng([collaboration.seed, zlib.crc32(f"{scene}/{link.frame_index}/{agent}/pose".encode())])
        delta = rng.normal(0.0, 1.0, 4) * np.array(collaboration.pose_noise[:3] + (np.deg2rad(collaboration.pose_noise[3]),))
        world_T_sent = Transform(rotation=Transform.from_yaw(delta[3]).rotation @ world_T_sent.rotation,
                                 translation=world_T_sent.translation + delta[:3])
    return world_T_sent @ world_T_agent.inverse()


def sent(link: Link | None, transforms: SceneTransforms, frame: str, t_frame: int, source: str, t_source: int) -> Transform:
    """``frame(t_frame)_T_source(t_source)`` as the ego knows it.

    Through the transmitted pose of the source's agent when that differs from the recorded one.
    """
    if link is None or link.world_T_recorded is None:
        return transforms.between(frame, t_frame, source, t_source)
    return transforms.lookup(frame, "world", t_frame) @ link.world_T_recorded @ transforms.lookup("world", source, t_source)


def last_transmission(times_ns: np.ndarray, latest_ns: int, rate_hz: float | None) -> int | None:
    """Index of the last sending frame in ``times_ns`` (sorted) at or before ``latest_ns``, or None.

    An agent of rate ``rate_hz`` sends in the first frame of each slot; None sends every frame.
    """
    k = int(np.searchsorted(times_ns, latest_ns, side="right")) - 1
    if rate_hz is not None:
        while k >= 0 and not opens_slot(int(times_ns[0]), int(times_ns[k - 1]) if k else -1, int(times_ns[k]), rate_hz):
            k -= 1
    return k if k >= 0 else None


def opens_slot(start_ns: int, prev_ns: int, time_ns: int, rate_hz: float) -> bool:
    """Whether the frame at ``time_ns`` is the first of a new 1/rate slot counted from ``start_ns``."""
    if prev_ns < 0:
        return True
    period_ns = 1e9 / rate_hz
    return int((time_ns - start_ns) // period_ns) > int((prev_ns - start_ns) // period_ns)
