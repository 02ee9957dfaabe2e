"""One frame's sensor data: every LiDAR casts its rays, every camera renders, each sensor gets its visibility labels.

The ray-casting scene is rebuilt from the pybullet bodies at the frame time, and all sensors sample the world at
that time (no motion distortion within a sweep). The carrying vehicle of a sensor is not a label of that sensor
(``in_fov`` False) and its returns are removed, as real drivers filter their own body.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from avdata.frames import Transform
from avdata.generators.camera import CameraConfig
from avdata.generators.lidar import LidarConfig, RayReturns, assemble_points, ray_returns
from avdata.generators.mesh import box_corners
from avdata.generators.raycast import RaycastWorld, RayHits, StaticHits, rotated_rays
from avdata.generators.render import encode_png, render_camera
from avdata.generators.simulator import Agent, SceneSimulator, captures
from avdata.generators.visibility import (
    BoxSurface,
    SampleVisibility,
    box_surface,
    camera_in_view,
    camera_labels,
    lidar_in_view,
    occlusion_level,
    sample_visibility,
)
from avdata.schema import SceneWriter, VisibilityLabels


@dataclass(frozen=True, slots=True, kw_only=True)
class LidarRays:
    """A LiDAR's rays, computed once per scene.

    Attributes:
        config: the LiDAR.
        directions_sensor: (R, 3) float32 unit directions in the sensor frame (see ``LidarConfig.directions``).
        directions_columns: (3, R) float32, the same directions one contiguous row per axis (rotated per frame by
            :func:`~avdata.generators.raycast.rotated_rays`).
        ring: (R,) uint16 beam index per ray.
        rays_world: (R, 6) float32 rays in the world frame of a sensor that never moves, else None.
        static_hits: the fixed sensor's hits in the static town (which never moves either), else None.
        static_returns: the fixed sensor's returns of its static hits, else None.
        carrier_rays: (R,) bool, the rays that may meet the box of the vehicle carrying the sensor (fixed in the
            sensor frame, 5 cm margin), else None.
        carrier_core_m: (R,) float64 distance along each ray to the carrying vehicle's box shrunk by 1 cm (inf for
            rays that miss it), an upper bound of where such a ray surely meets the box itself, else None.
    """

    config: LidarConfig
    directions_sensor: np.ndarray
    directions_columns: np.ndarray
    ring: np.ndarray
    rays_world: np.ndarray | None
    static_hits: StaticHits | None
    static_returns: RayReturns | None
    carrier_rays: np.ndarray | None
    carrier_core_m: np.ndarray | None


def lidar_rays(config: LidarConfig, raycast: RaycastWorld, world_T_fixed_sensor: Transform | None,
               carrier: tuple[Transform, np.ndarray] | None = None) -> LidarRays:
    """A LiDAR's rays, and what stays the same for the whole scene.

    Args:
        config: the LiDAR.
        raycast: the scene's geometry (its static part is used).
        world_T_fixed_sensor: the pose of a sensor that never moves (its world directions and static hits are
            kept), else None.
        carrier: ``sensor_T_box`` and (3,) size of the box of the vehicle carrying the sensor, else None.
    """
    directions_sensor, ring = config.directions()
    directions_columns = np.ascontiguousarray(directions_sensor.T)
    carrier_rays = carrier_core_m = None
    if carrier is not None:
        sensor_T_box, size_lwh = carrier
        carrier_rays = _rays_meet_box(np.zeros(3), directions_sensor, sensor_T_box.translation, sensor_T_box.rotation,
                                      np.asarray(size_lwh) / 2 + 0.05)
        carrier_core_m = _box_entry_m(np.zeros(3), directions_sensor, sensor_T_box.translation, sensor_T_box.rotation,
                                      np.asarray(size_lwh) / 2 - 0.01)
    if world_T_fixed_sensor is None:
        return LidarRays(config=config, directions_sensor=directions_sensor, directions_columns=directions_columns,
                         ring=ring, rays_world=None, static_hits=None, static_returns=None, carrier_rays=carrier_rays,
                         carrier_core_m=carrier_core_m)
    rays_world = rotated_rays(world_T_fixed_sensor.translation, world_T_fixed_sensor.rotation, directions_columns)
    static_hits = raycast.static.cast(rays_world)
    static_returns = ray_returns(config, directions_sensor, static_hits.t_hit, static_hits.reflectivity,
                                 static_hits.cos_incidence)
    return LidarRays(config=config, directions_sensor=directions_sensor, directions_columns=directions_columns,
                     ring=ring, rays_world=rays_world, static_hits=static_hits, static_returns=static_returns,
                     carrier_rays=carrier_rays, carrier_core_m=carrier_core_m)


def carrier_box(sim: SceneSimulator, agent: Agent, sensor_index: int) -> tuple[Transform, np.ndarray] | None:
    """``sensor_T_box`` and (3,) size of the box of the vehicle carrying a sensor (None for infrastructure).

    The body frame is the bottom centre of the box, so the box is the body frame raised by half its height.
    """
    if agent.vehicle_index < 0:
        return None
    size_lwh = sim.size_lwh[agent.vehicle_index]
    agent_T_box = Transform.from_yaw(np.asarray(0.0), translation=np.array([0.0, 0.0, size_lwh[2] / 2]))
    return agent.agent_T_sensor[sensor_index].inverse() @ agent_T_box, size_lwh


def object_bounding_radius(size_lwh: np.ndarray) -> np.ndarray:
    """(N,) radius of a sphere around each (N, 3) box, 5 cm larger than its half diagonal for float32 vertices."""
    radius: np.ndarray = 0.5 * np.linalg.norm(size_lwh, axis=-1) + 0.05
    return radius


def lidar_hits(raycast: RaycastWorld, rays: LidarRays, world_T_sensor: Transform, object_center_world: np.ndarray,
               object_rotation_world: np.ndarray, size_lwh: np.ndarray, carrier_index: int = -1) -> RayHits:
    """First hits of every ray of a LiDAR; rays that cannot reach an object skip the objects' scene.

    Objects are culled by a sphere around their box (:meth:`LidarConfig.rays_near`); a sphere around the
    sensor itself (its carrying vehicle) would keep every ray, so those boxes are tested exactly instead
    (the carrying vehicle's test is done once per scene, in ``rays.carrier_rays``). Which rays are culled
    does not change any hit: a culled ray meets no object.

    The carrying vehicle's own returns are removed (range inf, object id the carrier's), as real drivers
    filter their own body. Rays that surely hit it first are not cast at all: they meet its box shrunk by
    1 cm (``rays.carrier_core_m``) before any other object could be hit (no other object's cull keeps them, or
    every other object's bounding sphere is farther from the sensor than that hit), and every static surface is
    farther from the sensor than that hit (by 1 cm, far above float32 error).

    Args:
        raycast: this frame's geometry.
        rays: the LiDAR's rays.
        world_T_sensor: the sensor's pose now.
        object_center_world: (N, 3) the objects' box centres.
        object_rotation_world: (N, 3, 3) the objects' box-to-world rotations.
        size_lwh: (N, 3) the objects' box sizes.
        carrier_index: index of the vehicle carrying the sensor among the objects (-1: none); object ids are
            the objects' indices (``SceneSimulator.object_ids``), so it is also the carrier's object id.
    """
    rays_world = (rays.rays_world if rays.rays_world is not None
                  else rotated_rays(world_T_sensor.translation, world_T_sensor.rotation, rays.directions_columns))
    directions_world = rays_world[:, 3:]
    sensor_T_world = world_T_sensor.inverse()
    center_sensor = sensor_T_world.apply(object_center_world)
    radius_m = object_bounding_radius(size_lwh)
    distance_m = np.linalg.norm(center_sensor, axis=-1)
    enclosing = distance_m <= radius_m
    near = rays.config.rays_near(center_sensor[~enclosing], radius_m[~enclosing])
    carrier_rays = None
    for k in np.flatnonzero(enclosing):  # the carrying vehicle: one box, rarely more
        if k == carrier_index and rays.carrier_rays is not None:
            carrier_rays = rays.carrier_rays
            continue
        near |= _rays_meet_box(world_T_sensor.translation, directions_world, object_center_world[k],
                               object_rotation_world[k], size_lwh[k] / 2 + 0.05)
    surely_own = None
    if carrier_rays is not None and rays.carrier_core_m is not None:
        clearance_m = raycast.static.distance_m(world_T_sensor.translation) - 0.01
        # An object is hit no nearer than its bounding sphere: the ego's roof rays meet its core within about 2 m,
        # usually before the nearest other car's sphere, even where that car's cull keeps them.
        nearest_other_m = np.min(np.delete(distance_m - radius_m, carrier_index), initial=np.inf)
        surely_own = (~near | (rays.carrier_core_m < nearest_other_m)) & (rays.carrier_core_m < clearance_m)
        near = (near | carrier_rays) & ~surely_own
    hits = raycast.cast(rays_world, static_hits=rays.static_hits, may_hit_objects=near, skip=surely_own)
    if carrier_index >= 0:
        own = hits.object_id == carrier_index
        if surely_own is not None:
            own |= surely_own
            hits.object_id[surely_own] = carrier_index
        hits.range_m[own] = np.inf
    return hits


def _box_entry_m(origin_world: np.ndarray, directions_world: np.ndarray, center_world: np.ndarray,
                 rotation_world: np.ndarray, half_size_m: np.ndarray) -> np.ndarray:
    """(R,) float64 distance at which rays from one origin enter a box (0 from inside, inf if they miss it)."""
    t_enter, t_exit = _slab(origin_world, directions_world, center_world, rotation_world, half_size_m)
    return np.where((t_enter <= t_exit) & (t_exit >= 0.0), np.maximum(t_enter, 0.0), np.inf)


def _rays_meet_box(origin_world: np.ndarray, directions_world: np.ndarray, center_world: np.ndarray,
                   rotation_world: np.ndarray, half_size_m: np.ndarray) -> np.ndarray:
    """(R,) bool: rays from one origin that meet a box (slab test in the box frame), for (R, 3) directions."""
    t_enter, t_exit = _slab(origin_world, directions_world, center_world, rotation_world, half_size_m)
    return (t_enter <= t_exit) & (t_exit >= 0.0)


def _slab(origin_world: np.ndarray, directions_world: np.ndarray, center_world: np.ndarray,
          rotation_world: np.ndarray, half_size_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R,) distances along rays from one origin at which they enter and leave a box's slabs (box frame)."""
    origin = (origin_world - center_world) @ rotation_world
    # Row vectors times the rotation as three multiply-adds: a BLAS product with a 3-wide inner dimension
    # spins its threads on shared cores (see ``avdata.frames.transform._rotate``).
    d = directions_world.astype(np.float64)
    direction = d[:, 0:1] * rotation_world[0] + d[:, 1:2] * rotation_world[1] + d[:, 2:3] * rotation_world[2]
    direction = np.where(np.abs(direction) < 1e-12, np.copysign(1e-12, direction), direction)
    t_a = (-half_size_m - origin) / direction
    t_b = (half_size_m - origin) / direction
    return np.minimum(t_a, t_b).max(axis=1), np.maximum(t_a, t_b).min(axis=1)


@dataclass(frozen=True, slots=True, kw_only=True)
class _SensorOutput:
    """One sensor's data and labels of one frame, computed before anything of the frame is written.

    Attributes:
        frame: the sensor frame name.
        points: a LiDAR's point fields, else None.
        png: a camera's PNG-encoded image, else None.
        camera: a camera's config, else None.
        visibility: the sensor's visibility labels.
    """

    frame: str
    points: dict[str, np.ndarray] | None
    png: bytes | None
    camera: CameraConfig | None
    visibility: VisibilityLabels


def _visibility_labels(sim: SceneSimulator, agent: Agent, vis: SampleVisibility, extra: dict[str, Any]) -> VisibilityLabels:
    in_fov = vis.in_fov.copy()
    fraction = vis.visible_fraction.copy()
    if agent.vehicle_index >= 0:
        in_fov[agent.vehicle_index] = False
        fraction[agent.vehicle_index] = 0.0
    return VisibilityLabels(object_ids=sim.object_ids.astype(str), in_fov=in_fov, visible_fraction=fraction,
                            occlusion=occlusion_level(np.where(in_fov, fraction, 0.0)), **extra)


def _camera_output(sim: SceneSimulator, raycast: RaycastWorld, agent_index: int, sensor_index: int,
                   world_T_camera: Transform, object_corners_world: np.ndarray, surface: BoxSurface) -> _SensorOutput:
    """One camera's PNG image and visibility labels of this frame (objects' (N, 8, 3) box corners)."""
    agent = sim.agents[agent_index]
    sensor = agent.sensors[sensor_index]
    cam = sensor.camera_config
    image = render_camera(raycast, world_T_camera, cam, object_corners_world)
    png = encode_png(image.rgba)
    vis = sample_visibility(raycast, world_T_camera, sim.object_ids, surface, camera_in_view(cam))
    labels = camera_labels(cam, world_T_camera.inverse(), vis, sim.object_ids, image.object_id)
    extra = {"truncation": labels.truncation, "box2d_xyxy": labels.box2d_xyxy,
             "visible_pixel_fraction": labels.visible_pixel_fraction}
    return _SensorOutput(frame=f"{agent.name}/{sensor.name}", points=None, png=png, camera=cam,
                         visibility=_visibility_labels(sim, agent, vis, extra))


def _lidar_output(sim: SceneSimulator, raycast: RaycastWorld, agent_index: int, sensor_index: int,
                  world_T_sensor: Transform, frame_index: int, object_rotation_world: np.ndarray,
                  surface: BoxSurface, directions: dict[str, LidarRays]) -> _SensorOutput:
    """One LiDAR's points and visibility labels of this frame (objects' (N, 3, 3) box-to-world rotations)."""
    agent = sim.agents[agent_index]
    sensor = agent.sensors[sensor_index]
    frame = f"{agent.name}/{sensor.name}"
    lidar = sensor.lidar_config
    if frame not in directions:
        directions[frame] = lidar_rays(lidar, raycast, world_T_sensor if agent.world_T_agent is not None else None,
                                       carrier_box(sim, agent, sensor_index))
    rays = directions[frame]
    hits = lidar_hits(raycast, rays, world_T_sensor, surface.center_world, object_rotation_world, sim.size_lwh,
                      agent.vehicle_index)
    rng = np.random.default_rng([sim.seed, frame_index, agent_index, sensor_index])
    fields = assemble_points(lidar, rays.directions_sensor, rays.ring, hits.range_m, hits.object_id, hits.reflectivity,
                             hits.cos_incidence, rng, rays.static_returns)
    vis = sample_visibility(raycast, world_T_sensor, sim.object_ids, surface, lidar_in_view(lidar))
    ids = fields["object_id"]
    extra = {"n_points": np.bincount(ids[ids >= 0], minlength=len(sim.object_ids))}
    return _SensorOutput(frame=frame, points=fields, png=None, camera=None,
                         visibility=_visibility_labels(sim, agent, vis, extra))


def write_frame(sim: SceneSimulator, scene: SceneWriter, frame_index: int, time_ns: int,
                directions: dict[str, LidarRays]) -> None:
    """Poses the objects, runs every sensor due at this frame, and writes data and labels.

    The sensors run in two threads; everything is written in agent and sensor order (each output once it and those
    before it are done), so the file does not depend on which finished first.

    Args:
        sim: the scene, already advanced to this frame.
        scene: the scene writer.
        frame_index: 0, 1, 2 ...
        time_ns: the frame's (scene-relative) time.
        directions: cache of each LiDAR's rays (see :func:`lidar_rays`) by sensor frame, filled on first use.
    """
    center, yaw = sim._history[-1]
    sim.world.set_object_poses(center, yaw)
    world_T_agents = [sim.world_T_agent(agent) for agent in sim.agents]
    due = [(agent_index, sensor_index, world_T_agents[agent_index] @ agent_T_sensor)
           for agent_index, agent in enumerate(sim.agents)
           for sensor_index, (sensor, agent_T_sensor) in enumerate(zip(agent.sensors, agent.agent_T_sensor,
                                                                       strict=True))
           if captures(sensor, frame_index, sim.config.frame_rate_hz)]
    raycast = sim.world.raycast_world()
    obj_center, obj_rotation = sim.world.object_poses()
    surface = box_surface(obj_center, sim.size_lwh, obj_rotation)
    # Every sensor's data and labels in two threads, cameras first (the longest jobs): OpenCV and numpy's array loops
    # release the GIL (Open3D's casts hold it, see ``raycast._cast``). Each output depends only on this frame's
    # geometry and its own sensor (random streams are seeded per sensor), so the bytes do not depend on the timing.
    # This thread writes every output in agent and sensor order as soon as it and those before it are done, while
    # the pool computes the rest.
    with ThreadPoolExecutor(max_workers=2) as pool:
        corners = box_corners(obj_center, sim.size_lwh, obj_rotation)
        jobs = {(a, s): pool.submit(_camera_output, sim, raycast, a, s, world_T_sensor, corners, surface)
                for a, s, world_T_sensor in due if sim.agents[a].sensors[s].kind == "camera"}
        jobs.update({(a, s): pool.submit(_lidar_output, sim, raycast, a, s, world_T_sensor, frame_index, obj_rotation,
                                         surface, directions)
                     for a, s, world_T_sensor in due if sim.agents[a].sensors[s].kind == "lidar"})
        sensor_times = {}
        for agent_index, agent in enumerate(sim.agents):
            if agent.kind == "vehicle":
                scene.add_transform("world", agent.name, time_ns, world_T_agents[agent_index])
            for sensor_index in range(len(agent.sensors)):
                job = jobs.get((agent_index, sensor_index))
                if job is None:  # not due at this frame
                    continue
                output = job.result()
                if output.points is not None:
                    scene.add_point_cloud(output.frame, time_ns, output.points)
                if output.png is not None and output.camera is not None:
                    cam = output.camera
                    scene.add_image(output.frame, time_ns, output.png, "png")
                    scene.add_camera_calibration(output.frame, time_ns, K=cam.K, width=cam.width, height=cam.height,
                                                 D=np.zeros(5))
                scene.add_visibility(output.frame, frame_index, time_ns, output.visibility)
                sensor_times[output.frame] = time_ns
    scene.add_frame(frame_index, time_ns, sim.labels(), sensor_timestamps_ns=sensor_times)
