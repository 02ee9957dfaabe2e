"""The intermediate and late fusion layouts (OpenCOOD's): per-agent clouds and labels in each agent's own frame.

``fusion="intermediate"`` keeps one cloud per received agent, ``points[agent]``, in that agent's own
frame ``agent_frames[a]`` (its first lidar, or its body frame without one; an agent's other lidars are
moved into it), and adds ``pairwise_T`` (L, L, 4, 4) float64 with L = ``max_agents``:
``pairwise_T[i, j] = j_T_i = inv(world_T_j) @ world_T_i``, which maps points of agent i (in
``agent_frames[i]`` at its capture time) into agent j's frame, as OpenCOOD's ``pairwise_t_matrix[i, j]``
("i_to_j"); and ``agent_mask`` (L,) bool. Agents are ordered ego first, then the received ones, so the
mask is a prefix; rows and columns of unreceived or padded slots are the identity. ``fusion="late"`` adds
each received agent's own label set in its own frame, from its transmission's frame.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from avdata.loaders.communication import Link, sent
from avdata.loaders.items import ItemFrame, class_indices
from avdata.loaders.options import Collaboration, agent_of, matches
from avdata.loaders.packing import PendingCloud, SensorCloud, common_fields


def per_agent_layout(
    collaboration: Collaboration, at: ItemFrame, agents: list[str], links: Mapping[str, Link], clouds: list[SensorCloud]
) -> tuple[dict[str, PendingCloud], dict[str, Any]]:
    """The intermediate / late layout (module docstring): per-agent clouds and the keys it adds to the item."""
    transforms = at.transforms
    slots = collaboration.max_agents
    frames: list[str] = []
    frame_times: list[int] = []
    for agent in agents:
        own = [c for c in clouds if agent_of(c.sensor) == agent]
        frames.append(own[0].sensor if own else agent)
        frame_times.append(own[0].time_ns if own else links[agent].time_ns)
    points: dict[str, PendingCloud] = {}
    for agent, agent_frame, t_agent in zip(agents, frames, frame_times, strict=True):
        own = [replace(c, frame_T_sensor=transforms.between(agent_frame, t_agent, c.sensor, c.time_ns))
               for c in clouds if agent_of(c.sensor) == agent]
        if own:
            points[agent] = PendingCloud(members=own, names=common_fields(c.stored for c in own), agents=None)
    world_T_frame = np.stack([sent(links[a], transforms, "world", t, f, t).as_matrix()
                              for a, f, t in zip(agents, frames, frame_times, strict=True)])
    pairwise = np.tile(np.eye(4), (slots, slots, 1, 1))
    n = len(agents)
    # pairwise[i, j] = j_T_i = inv(world_T_j) @ world_T_i: agent i's points into agent j's frame
    pairwise[:n, :n] = np.linalg.solve(world_T_frame[None, :, :, :], world_T_frame[:, None, :, :])
    mask = np.zeros(slots, dtype=bool)
    mask[:n] = [links[a].received for a in agents]
    pairwise[~np.outer(mask, mask)] = np.eye(4)
    out: dict[str, Any] = {"agent_frames": frames, "pairwise_T": pairwise, "agent_mask": mask}
    if collaboration.fusion == "late":
        out.update(agent_labels(at, agents, frames, frame_times, links))
    return points, out


def agent_labels(
    at: ItemFrame, agents: list[str], frames: list[str], frame_times: list[int], links: Mapping[str, Link]
) -> dict[str, Any]:
    """Each received agent's label set, from its transmission's frame, in its own frame.

    The label filter applies per agent: its classes, ``max_range_m`` from that agent's frame origin,
    ``visible_to`` by the agent's own sensors.
    """
    options = at.options.labels
    boxes_out: dict[str, np.ndarray] = {}
    labels_out: dict[str, np.ndarray] = {}
    ids_out: dict[str, list[str]] = {}
    for agent, agent_frame, t_agent in zip(agents, frames, frame_times, strict=True):
        link = links[agent]
        if not link.received:
            continue
        _, labels = at.reader.labels(link.frame_index)
        boxes = labels.boxes.transform(at.transforms.between(agent_frame, t_agent, labels.boxes.frame, link.time_ns),
                                       agent_frame)
        ids = np.asarray(boxes.ids)
        class_index = class_indices(np.asarray(boxes.classes), options.classes)
        keep = class_index >= 0
        own_object = at.own_object(agent)
        if own_object is not None:
            keep &= ids != own_object
        if options.max_range_m is not None:
            keep &= np.hypot(boxes.center[:, 0], boxes.center[:, 1]) <= options.max_range_m
        if options.visible_to is not None:
            sensors = [s for s in at.visibility.sensors_of(at.scene, link.frame_index)
                       if agent_of(s) == agent and matches(s, options.visible_to)]
            keep &= at.seen(link.frame_index, sensors, ids)
        boxes_out[agent] = np.concatenate([boxes.center[keep], boxes.size_lwh[keep], boxes.yaw()[keep, None]],
                                          axis=1).astype(np.float32)
        labels_out[agent] = class_index[keep]
        ids_out[agent] = ids[keep].tolist()
    return {"agent_boxes": boxes_out, "agent_labels": labels_out, "agent_object_ids": ids_out}
