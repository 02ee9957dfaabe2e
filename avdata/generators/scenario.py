"""Generates scenes: a simulated world stepped frame by frame, each frame's sensor data written out.

The world and its agents are :mod:`~avdata.generators.simulator`'s, a frame's sensor data and labels
:mod:`~avdata.generators.sensing`'s. One scene = one town and its traffic from ``seed + scene index``; its
name and metadata are given here. Object ids are integers (``object_id`` point field; the same string in the
labels) shared by every agent and sensor.
"""

from __future__ import annotations

import sys
from typing import Any

from tqdm import tqdm

from avdata.generators.config import ScenarioConfig
from avdata.generators.sensing import LidarRays, write_frame
from avdata.generators.simulator import SceneSimulator
from avdata.schema import DatasetWriter

GENERATOR_VERSION = "0.1.0"


def scene_metadata(config: ScenarioConfig, sim: SceneSimulator, scene_index: int) -> dict[str, Any]:
    """The scene's ``avdata.scene`` metadata: generator version, scenario, seed and the simulated world's facts."""
    return {
        "generator": {"name": "avdata.generators", "version": GENERATOR_VERSION},
        "config": config.to_dict(),
        "scene_index": scene_index,
        "seed": sim.seed,
        "world_origin": "town centre at road level, z up (simulated, scene-relative)",
        "time": "scene-relative: frame k at k / frame_rate_hz seconds",
        "object_model": "every object is its labelled box (rendering, ray casting and labels agree exactly)",
        "occlusion_thresholds": "visible fraction >= 0.8: 0, >= 0.4: 1, >= 0.05: 2, else 3",
    }


def scene_name(config: ScenarioConfig, scene_index: int) -> str:
    """The name of scene ``scene_index`` of a scenario."""
    return f"scene_{config.seed:06d}_{scene_index:04d}"


def write_scene(config: ScenarioConfig, scene_index: int, writer: DatasetWriter, progress: bool = False) -> str:
    """Simulates and writes scene ``scene_index``; returns its name (skipped if already complete).

    With ``progress`` and a terminal on stderr, a bar advances per frame (a scene of a large town takes minutes).
    """
    name = scene_name(config, scene_index)
    if writer.is_complete(name):
        return name
    sim = SceneSimulator(config, scene_index)
    try:
        with writer.scene(name, scene_metadata(config, sim, scene_index)) as scene:
            for agent in sim.agents:
                origin = ("bottom centre of the vehicle box" if agent.kind == "vehicle"
                          else "foot of the sensor pole, x towards the road")
                # A vehicle agent is also a labelled object; its id lets loaders and evaluation leave the
                # agent's own box out of its targets.
                own_object = {"object_id": str(int(sim.object_ids[agent.vehicle_index]))} if agent.vehicle_index >= 0 else {}
                scene.add_agent(agent.name, kind=agent.kind, origin=origin, **own_object)
                if agent.world_T_agent is not None:
                    scene.add_static_transform("world", agent.name, agent.world_T_agent)
                for sensor, agent_T_sensor in zip(agent.sensors, agent.agent_T_sensor, strict=True):
                    frame = f"{agent.name}/{sensor.name}"
                    scene.add_sensor(frame, kind=sensor.kind, **sensor.spec())
                    scene.add_static_transform(agent.name, frame, agent_T_sensor)
            directions: dict[str, LidarRays] = {}
            bar = tqdm(range(config.frames), desc=name, unit="frame", leave=False,
                       disable=not (progress and sys.stderr.isatty()))
            for frame_index in bar:
                if frame_index:
                    sim.advance(1.0 / config.frame_rate_hz)
                time_ns = int(round(frame_index * 1e9 / config.frame_rate_hz))
                write_frame(sim, scene, frame_index, time_ns, directions)
    finally:
        sim.close()
    return name
