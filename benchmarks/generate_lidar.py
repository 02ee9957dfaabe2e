"""LiDAR ray throughput and V2I frame time of ``avdata.generators``.

Prints one line per figure (docs/performance.md):

- ``lidar rays/s``: the whole per-frame LiDAR pipeline (objects' ray-casting scene rebuilt from the
  pybullet bodies, casting, point assembly; static town, fixed sensors' static hits and returns and the
  carrying vehicle's ray cull prepared once per scene, the LiDARs in two threads, as in ``write_frame``)
  over every LiDAR of a V2I frame, against pybullet's ``rayTestBatch`` (2 threads) casting the same rays
  in the same pybullet world.
- ``v2i frame``: one V2I frame simulated, labelled and written (MCAP), wall time per frame: an ego
  with a 64 x 2048 LiDAR and a 1242 x 375 camera (the sensors in two threads, written from this one
  as they finish, as in ``write_frame``), 8 infrastructure LiDARs of 64 x 1024 rays and 100 moving
  objects (60 vehicles, 40 pedestrians, plus parked cars); the baseline is the issue's budget of 1 s.

Open3D holds the GIL while it casts (each cast uses every core), so on a machine shared with other jobs
the wall times follow the CPU share this process gets; the CPU lines move less. About half of a frame's CPU is
Open3D's ray casting (its cost per ray, 39 ns even for a miss), the rest numpy passes over the frame's arrays and
the writer: docs/performance.md ("V2I frame: where the time goes") has the per-stage costs. Under heavy load
(load average above 4 on 2 cores) even the CPU lines move by a third from run to run; compare code by
instruction counts (callgrind, as that section does).

Usage: ``python benchmarks/generate_lidar.py [--quick]``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pybullet

from avdata.generators.config import load_preset, scenario_from_dict
from avdata.generators.lidar import assemble_points
from avdata.generators.scenario import scene_metadata
from avdata.generators.sensing import carrier_box, lidar_hits, lidar_rays, write_frame
from avdata.generators.simulator import SceneSimulator
from avdata.schema import DatasetWriter


def v2i_config(frames: int):
    base = load_preset("v2i-intersection").to_dict()
    base["frames"] = frames
    base["traffic"]["vehicles"] = 60
    base["traffic"]["pedestrians"] = 40
    return scenario_from_dict(base, "benchmark")


def lidar_rays_per_second(sim: SceneSimulator, repeats: int) -> tuple[float, float, int]:
    """Rays per wall and per CPU second (all threads) of one frame's LiDAR work, best of ``repeats``, and the rays.

    The work: objects' scene from the pybullet bodies, cast, point assembly; the LiDARs in a pool of two threads,
    as ``write_frame`` runs them.

    Each LiDAR's rays (and a fixed sensor's static hits) are prepared once per scene, as ``write_frame`` does.
    """
    center, yaw = sim._history[-1]
    sim.world.set_object_poses(center, yaw)
    world = sim.world.raycast_world()
    lidars = []
    for agent in sim.agents:
        world_T_agent = sim.world_T_agent(agent)
        for k, (sensor, agent_T_sensor) in enumerate(zip(agent.sensors, agent.agent_T_sensor, strict=True)):
            if sensor.kind == "lidar":
                world_T_sensor = world_T_agent @ agent_T_sensor
                fixed = world_T_sensor if agent.world_T_agent is not None else None
                rays = lidar_rays(sensor.lidar_config, world, fixed, carrier_box(sim, agent, k))
                lidars.append((rays, world_T_sensor, agent.vehicle_index))
    n_rays = sum(len(rays.ring) for rays, _, _ in lidars)

    def points(world, rays, world_T_sensor, carrier_index, object_center, object_rotation):
        hits = lidar_hits(world, rays, world_T_sensor, object_center, object_rotation, sim.size_lwh, carrier_index)
        return assemble_points(rays.config, rays.directions_sensor, rays.ring, hits.range_m, hits.object_id,
                               hits.reflectivity, hits.cos_incidence, np.random.default_rng(0), rays.static_returns)

    best = best_cpu = np.inf
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        world = sim.world.raycast_world()
        object_center, object_rotation = sim.world.object_poses()
        with ThreadPoolExecutor(max_workers=2) as pool:  # as write_frame runs its sensors
            jobs = [pool.submit(points, world, rays, world_T_sensor, carrier_index, object_center, object_rotation)
                    for rays, world_T_sensor, carrier_index in lidars]
            for job in jobs:
                job.result()
        best = min(best, time.perf_counter() - start)
        best_cpu = min(best_cpu, time.process_time() - start_cpu)
    return n_rays / best, n_rays / best_cpu, n_rays


def pybullet_rays_per_second(sim: SceneSimulator, n_rays: int) -> float:
    """rayTestBatch on the same world and sensors (first ``n_rays`` rays of the LiDARs, in batches)."""
    origins, targets = [], []
    for agent in sim.agents:
        world_T_agent = sim.world_T_agent(agent)
        for sensor, agent_T_sensor in zip(agent.sensors, agent.agent_T_sensor, strict=True):
            if sensor.kind == "lidar":
                world_T_sensor = world_T_agent @ agent_T_sensor
                dirs, _ = sensor.lidar.directions()
                origins.append(np.broadcast_to(world_T_sensor.translation, dirs.shape))
                targets.append(world_T_sensor.translation + world_T_sensor.apply_vector(dirs) * sensor.lidar.max_range_m)
    origins = np.concatenate(origins)[:n_rays]
    targets = np.concatenate(targets)[:n_rays]
    batch = pybullet.MAX_RAY_INTERSECTION_BATCH_SIZE
    start = time.perf_counter()
    for k in range(0, n_rays, batch):
        pybullet.rayTestBatch(origins[k:k + batch].tolist(), targets[k:k + batch].tolist(), numThreads=2,
                              physicsClientId=sim.world.bodies.client)
    return n_rays / (time.perf_counter() - start)


def frame_seconds(config, frames: int) -> tuple[float, float]:
    """Median wall and CPU time (all threads) per frame of advance + sensors + labels + MCAP writing."""
    with tempfile.TemporaryDirectory() as tmp:
        writer = DatasetWriter(Path(tmp), source="avdata-generator")
        sim = SceneSimulator(config, 0)
        times, cpu_times = [], []
        try:
            with writer.scene("bench", scene_metadata(config, sim, 0)) as scene:
                directions: dict = {}
                for frame_index in range(frames):
                    start, start_cpu = time.perf_counter(), time.process_time()
                    if frame_index:
                        sim.advance(1.0 / config.frame_rate_hz)
                    write_frame(sim, scene, frame_index, int(frame_index * 1e8), directions)
                    times.append(time.perf_counter() - start)
                    cpu_times.append(time.process_time() - start_cpu)
        finally:
            sim.close()
    steady = slice(1, None) if frames > 1 else slice(None)
    return float(np.median(times[steady])), float(np.median(cpu_times[steady]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repetitions and frames")
    args = parser.parse_args()
    frames = 3 if args.quick else 10
    config = v2i_config(frames)
    sim = SceneSimulator(config, 0)
    try:
        rate, rate_cpu, n_rays = lidar_rays_per_second(sim, 2 if args.quick else 5)
        baseline = pybullet_rays_per_second(sim, 50_000 if args.quick else 200_000)
    finally:
        sim.close()
    print(f"lidar rays/s ({n_rays} rays, 9 lidars): avdata {rate / 1e6:.2f} M rays/s, "
          f"baseline pybullet-rayTestBatch {baseline / 1e6:.2f} M rays/s, ratio {rate / baseline:.1f}")
    print(f"lidar rays per CPU second (all threads; moves less with other jobs on the machine): {rate_cpu / 1e6:.2f} M")
    seconds, cpu_seconds = frame_seconds(config, frames)
    print(f"v2i frame (ego 64x2048 lidar + 1242x375 camera, 8 infra 64x1024 lidars, 100 moving objects, written): "
          f"avdata {seconds:.3f} s/frame, baseline issue-budget 1.000 s/frame, ratio {seconds / 1.0:.2f}")
    print(f"v2i frame CPU (all threads; moves less with other jobs on the machine): {cpu_seconds:.3f} s/frame (median)")


if __name__ == "__main__":
    main()
