"""The simulated world of one scene: town, traffic, pybullet bodies and the agents that carry sensors.

One scene = one town and its traffic from ``seed + scene index``; traffic advances in 0.05 s steps and the
object poses go into pybullet. Object ids are integers shared by every agent and sensor.

Frames: ``world`` is the town centre at road level, z up. Vehicle agents' body frames are at the
centre of their box's bottom face (x forward, y left, z up), posed on ``/tf``; infrastructure units'
frames are at the foot of their pole, x towards the road, on ``/tf_static``.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from dataclasses import dataclass

import numpy as np

from avdata import portable_math
from avdata.frames import XFWD_T_OPTICAL, Boxes3D, Transform
from avdata.generators.config import ScenarioConfig, SensorConfig
from avdata.generators.sizes import CLASS_SPECS, sample_sizes
from avdata.generators.town import CURB_HEIGHT_M, Town, build_town
from avdata.generators.traffic import SIM_STEP_S, Traffic
from avdata.generators.world import SimWorld
from avdata.schema import ObjectLabels

EGO_CLASS = "car"


@dataclass(frozen=True, slots=True, kw_only=True)
class Agent:
    """An agent and its sensors.

    Attributes:
        name: body frame name.
        kind: "vehicle" or "infrastructure".
        vehicle_index: index of the carrying vehicle among the objects (-1 for infrastructure).
        world_T_agent: fixed pose of an infrastructure unit (None for vehicles).
        sensors: the sensor configs.
        agent_T_sensor: the sensors' frames in the body frame (optical frames for cameras).
    """

    name: str
    kind: str
    vehicle_index: int
    world_T_agent: Transform | None
    sensors: tuple[SensorConfig, ...]
    agent_T_sensor: tuple[Transform, ...]


def mount_transform(sensor: SensorConfig, base: Transform | None = None) -> Transform:
    """The sensor frame in its agent's body frame (the optical frame for cameras)."""
    mount = Transform.from_euler("ZYX", np.asarray(sensor.mount_ypr_deg, dtype=np.float64),
                                 translation=np.asarray(sensor.mount_xyz_m, dtype=np.float64), degrees=True)
    if base is not None:
        mount = base @ mount
    return mount @ XFWD_T_OPTICAL if sensor.kind == "camera" else mount


def captures(sensor: SensorConfig, frame_index: int, frame_rate_hz: float) -> bool:
    """Whether a sensor records at frame ``frame_index``.

    At frame 0 and whenever its own clock (``rate_hz``, at most the frame rate) ticks, e.g. every other frame
    for 5 Hz at 10 Hz frames.
    """
    rate = sensor.rate_hz
    if frame_index == 0 or rate >= frame_rate_hz:
        return True
    return int(np.floor(frame_index * rate / frame_rate_hz + 1e-9)) > int(
        np.floor((frame_index - 1) * rate / frame_rate_hz + 1e-9))


def _infrastructure_poses(config: ScenarioConfig, town: Town, rng: np.random.Generator) -> list[Transform]:
    infra = config.infrastructure
    poses = []
    if infra.placement == "intersections":
        inset = town.config.road_half_width_m + 1.5
        corners = np.array([[-1, -1], [1, 1], [1, -1], [-1, 1]], dtype=np.float64) * inset
        centre_first = np.argsort(np.linalg.norm(town.nodes, axis=1), kind="stable")
        for k in range(infra.count):
            # The four corners of the most central intersection first, then one unit per other
            # intersection, nearest first.
            rank = 0 if k < 4 else 1 + (k - 4) % (len(town.nodes) - 1)
            node = town.nodes[centre_first[rank]]
            corner = corners[k % 4]
            position = node + corner
            yaw = portable_math.arctan2(-corner[1], -corner[0])
            poses.append(Transform.from_yaw(np.asarray(yaw), translation=np.r_[position, CURB_HEIGHT_M]))
    else:
        lanes = town.lanes
        roads = np.flatnonzero(lanes.kind == 0)
        offset = town.config.road_half_width_m + 1.0 - town.config.lane_width_m / 2
        for _ in range(infra.count):
            lane = rng.choice(roads)
            s = rng.uniform(10.0, lanes.length_m[lane] - 10.0)
            xy, heading = lanes.pose(np.array([lane]), np.array([s]))
            right = np.array([np.sin(heading[0]), -np.cos(heading[0])])
            position = xy[0] + offset * right
            poses.append(Transform.from_yaw(np.asarray(heading[0] + np.pi / 2),
                                            translation=np.r_[position, CURB_HEIGHT_M]))
    return poses


class SceneSimulator:
    """Simulates one scene of a scenario.

    Args:
        config: the scenario.
        scene_index: which scene (its seed is ``config.seed + scene_index``).
    """

    def __init__(self, config: ScenarioConfig, scene_index: int):
        self.config = config
        self.seed = config.seed + scene_index
        rng = np.random.default_rng(self.seed)
        self.town = build_town(config.town, rng)
        traffic_cfg = config.traffic
        names = list(traffic_cfg.class_weights)
        weights = np.array([traffic_cfg.class_weights[n] for n in names], dtype=np.float64)
        n_egos = len(config.egos)
        classes = np.array(names)[rng.choice(len(names), size=traffic_cfg.vehicles, p=weights / weights.sum())]
        classes[:n_egos] = EGO_CLASS
        sizes = sample_sizes(classes, rng)
        sizes[:n_egos] = CLASS_SPECS[EGO_CLASS].mean_lwh_m  # fixed ego size: sensor mounts stay meaningful
        n_parked = int(round(len(self.town.parking_xy) * traffic_cfg.parked_fraction))
        parked = rng.choice(len(self.town.parking_xy), size=n_parked, replace=False)
        parked_classes = np.where(rng.random(n_parked) < 0.8, "car", "van")
        ped_sizes = sample_sizes(np.full(traffic_cfg.pedestrians, "pedestrian"), rng)
        crosser_sizes = sample_sizes(np.full(traffic_cfg.crossing_pedestrians, "pedestrian"), rng)
        self.traffic = Traffic(self.town, traffic_cfg, sizes, classes, rng, ped_sizes, crosser_sizes)
        self.parked_xy = self.town.parking_xy[parked]
        self.parked_yaw = self.town.parking_yaw[parked]
        n_peds = traffic_cfg.pedestrians + traffic_cfg.crossing_pedestrians
        self.classes = np.concatenate([classes, parked_classes, np.full(n_peds, "pedestrian")])
        self.size_lwh = np.concatenate([sizes, sample_sizes(parked_classes, rng), ped_sizes, crosser_sizes])
        # Sidewalk pedestrians stand on the curb; everyone else (crossers included) on the road.
        self.ground_z = np.concatenate([np.zeros(len(classes) + n_parked),
                                        np.full(traffic_cfg.pedestrians, CURB_HEIGHT_M),
                                        np.zeros(traffic_cfg.crossing_pedestrians)])
        self.object_ids = np.arange(len(self.classes), dtype=np.int64)
        infra_poses = _infrastructure_poses(config, self.town, rng)
        self.agents = [
            Agent(name=ego.name, kind="vehicle", vehicle_index=i, world_T_agent=None, sensors=ego.sensors,
                  agent_T_sensor=tuple(mount_transform(s) for s in ego.sensors))
            for i, ego in enumerate(config.egos)
        ]
        infra = config.infrastructure
        head = Transform.from_euler("ZYX", np.array([0.0, infra.pitch_deg, 0.0]),
                                    translation=np.array([0.5, 0.0, infra.height_m - CURB_HEIGHT_M]), degrees=True)
        for k, pose in enumerate(infra_poses):
            self.agents.append(Agent(name=f"infra_{k:02d}", kind="infrastructure", vehicle_index=-1, world_T_agent=pose,
                                     sensors=infra.sensors,
                                     agent_T_sensor=tuple(mount_transform(s, head) for s in infra.sensors)))
        scenery = self.town.scenery
        if infra_poses:
            feet = np.array([p.translation for p in infra_poses])
            height = infra.height_m - CURB_HEIGHT_M
            scenery = dataclasses.replace(
                scenery,
                cylinder_center=np.concatenate([scenery.cylinder_center, feet + [0.0, 0.0, height / 2]]),
                cylinder_radius=np.concatenate([scenery.cylinder_radius, np.full(len(feet), 0.2)]),
                cylinder_height=np.concatenate([scenery.cylinder_height, np.full(len(feet), height)]),
            )
        self.world = SimWorld(scenery, self.object_ids, self.classes, self.size_lwh)
        self._history: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=3)
        for _ in range(int(round(traffic_cfg.warmup_s / SIM_STEP_S))):
            self._step()

    def _poses(self) -> tuple[np.ndarray, np.ndarray]:
        vehicle_xy, vehicle_yaw = self.traffic.vehicle_poses()
        ped_xy, ped_yaw = self.traffic.pedestrian_poses()
        crosser_xy, crosser_yaw = self.traffic.crosser_poses()
        xy = np.concatenate([vehicle_xy, self.parked_xy, ped_xy, crosser_xy])
        yaw = np.concatenate([vehicle_yaw, self.parked_yaw, ped_yaw, crosser_yaw])
        return np.c_[xy, self.ground_z + self.size_lwh[:, 2] / 2], yaw

    def _step(self) -> None:
        self.traffic.step(SIM_STEP_S)
        self._history.append(self._poses())

    def close(self) -> None:
        """Releases pybullet."""
        self.world.close()

    def advance(self, duration_s: float) -> None:
        """Advances the world by ``duration_s`` (a whole number of simulation steps)."""
        for _ in range(max(int(round(duration_s / SIM_STEP_S)), 1)):
            self._step()

    def labels(self) -> ObjectLabels:
        """Ground truth of every object now, in the world frame."""
        (c0, y0), (c1, y1), (c2, y2) = self._history
        velocity = (c2 - c1) / SIM_STEP_S
        acceleration = (c2 - 2 * c1 + c0) / SIM_STEP_S**2
        yaw_rate = portable_math.wrap_angle(y2 - y1) / SIM_STEP_S
        unified = np.array([CLASS_SPECS[c].unified_class for c in self.classes])
        boxes = Boxes3D.from_yaw(c2, self.size_lwh, y2, frame="world", ids=self.object_ids.astype(str),
                                 classes=unified, velocity=velocity)
        return ObjectLabels(boxes=boxes, source_classes=self.classes, acceleration=acceleration,
                            angular_velocity=np.c_[np.zeros((len(yaw_rate), 2)), yaw_rate])

    def world_T_agent(self, agent: Agent) -> Transform:
        """The agent's current pose (vehicles: bottom centre of the box)."""
        if agent.world_T_agent is not None:
            return agent.world_T_agent
        center, yaw = self._history[-1]
        i = agent.vehicle_index
        return Transform.from_yaw(yaw[i], translation=center[i] - [0.0, 0.0, self.size_lwh[i, 2] / 2])
