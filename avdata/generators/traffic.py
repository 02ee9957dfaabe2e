"""Traffic on the town's lanes: car-following (IDM), signalised intersections and walking pedestrians.

Vehicles (cars, vans, trucks, buses, motorcycles, cyclists) drive along lane centre lines with the
Intelligent Driver Model (Treiber, Hennecke & Helbing 2000):
``a = a_max * (1 - (v / v0)^4 - (s* / gap)^2)``, ``s* = s0 + v T + v dv / (2 sqrt(a_max b))``.
The leader of a vehicle is the nearest vehicle ahead along its planned route (current lane and the
next two), including vehicles on sibling connectors of the same approach, which share the first metres
of road. Before a turn, the free-flow speed drops to what a lateral acceleration of 2 m/s^2 allows.

Intersections are signalised with one green approach at a time (protected phases), so no two
movements cross inside an intersection: a phase gives up to ``green_s`` of green (less when nobody is
coming: actuated signals), then the intersection clears (at least ``all_red_s`` and until no vehicle
is inside it) before the next approach with waiting traffic turns green.
A vehicle that cannot stop at 4 m/s^2 when its green ends keeps going and the clearance waits for it;
a vehicle also waits at a green light while its exit lane has no room for it (no gridlock).

No interpenetration is guaranteed, not just likely: after each IDM step a vehicle's advance is clipped
so that it stays ``min_gap_m`` behind where its leader was (leaders never move backwards) and, without
right of way, behind the stop line.

Pedestrians walk around blocks on two sidewalk tracks; all pedestrians on one track share a speed
and direction, so their spacing never shrinks. Crossing pedestrians each own one walking line of a
crosswalk and cross it back and forth: they wait at the curb (at least ``MIN_WAIT_S``) and start
only in the first ``WALK_START_WINDOW_S`` of a walk phase, an exclusive pedestrian phase ("Barnes
dance") that an intersection runs once per signal cycle when someone is waiting. A walk phase starts
only when the intersection is empty, and the next green waits until every crosser has arrived, so
walkers and vehicles never share the intersection. A crosser turns around on the spot when it
arrives (its heading flips by pi within one step; the box it occupies does not change).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from avdata import portable_math
from avdata.errors import InputError
from avdata.generators.sizes import CLASS_SPECS
from avdata.generators.town import CONNECTOR, ROAD, Town

SIM_STEP_S = 0.05
"""The simulation's time step: traffic, frames and the labels' finite differences advance in whole steps."""

STOP_DECEL_MPS2 = 4.0
"""Deceleration beyond which a vehicle whose green ends is committed to the intersection."""

WALK_START_WINDOW_S = 4.0
"""Crossing pedestrians start only this early in a walk phase."""

MIN_WAIT_S = 6.0
"""A crossing pedestrian rests at least this long at the curb before crossing again."""


@dataclass(frozen=True, slots=True, kw_only=True)
class TrafficConfig:
    """Traffic mix and driver behaviour.

    Attributes:
        vehicles: number of moving vehicles (egos included).
        class_weights: relative frequency of each vehicle class.
        pedestrians: number of pedestrians walking around blocks on the sidewalks.
        crossing_pedestrians: number of pedestrians crossing roads at the crosswalks.
        parked_fraction: fraction of the town's parking spaces that hold a parked vehicle.
        time_headway_s: IDM desired time headway T.
        min_gap_m: IDM jam distance s0 (bumper to bumper, at standstill).
        green_s: green time per approach.
        all_red_s: minimum clearance time between phases.
        warmup_s: simulated time before the first recorded frame.
    """

    vehicles: int = 40
    class_weights: dict[str, float] = field(
        default_factory=lambda: {"car": 0.62, "van": 0.12, "truck": 0.06, "bus": 0.04, "motorcycle": 0.06,
                                 "cyclist": 0.10}
    )
    pedestrians: int = 30
    crossing_pedestrians: int = 8
    parked_fraction: float = 1.0
    time_headway_s: float = 1.2
    min_gap_m: float = 2.0
    green_s: float = 8.0
    all_red_s: float = 1.5
    warmup_s: float = 10.0


@dataclass(slots=True, kw_only=True)
class TrafficState:
    """Mutable state of the moving vehicles (N) at one instant.

    Attributes:
        lane, s_m, speed_mps: (N,) current lane, arc length of the vehicle's centre along it, speed.
        previous_lane: (N,) the lane driven before the current one (where the rear may still be).
        next_lanes: (N, 2) the next two lanes of each vehicle's route.
        accel_mps2: (N,) longitudinal acceleration over the last step.
    """

    lane: np.ndarray
    s_m: np.ndarray
    speed_mps: np.ndarray
    previous_lane: np.ndarray
    next_lanes: np.ndarray
    accel_mps2: np.ndarray


class Traffic:
    """Simulates the vehicles and pedestrians of a town.

    Attributes:
        classes: (N,) vehicle class names; ``size_lwh`` (N, 3); ``desired_speed`` (N,).
        state: the vehicles' current state.
        time_s: simulated time.
    """

    def __init__(self, town: Town, config: TrafficConfig, sizes: np.ndarray, classes: np.ndarray,
                 rng: np.random.Generator, pedestrian_sizes: np.ndarray, crosser_sizes: np.ndarray):
        """Places vehicles on the road lanes and pedestrians on the sidewalks.

        Args:
            town: the town.
            config: traffic configuration.
            sizes: (N, 3) vehicle sizes (length, width, height).
            classes: (N,) vehicle class names.
            rng: random generator, also used for route choices while driving.
            pedestrian_sizes: (P, 3) sizes of the sidewalk pedestrians.
            crosser_sizes: (C, 3) sizes of the crossing pedestrians.
        """
        self.town = town
        self.config = config
        self.rng = rng
        self.classes = classes
        self.size_lwh = sizes
        lanes = town.lanes
        specs = [CLASS_SPECS[c] for c in classes]
        self.desired_speed = np.array([rng.uniform(*s.desired_speed_mps) for s in specs])
        self.max_accel = np.array([s.max_accel_mps2 for s in specs])
        self.comfort_decel = np.array([s.comfortable_decel_mps2 for s in specs])
        self.time_s = 0.0
        self._place_vehicles(rng)
        # Signals: per intersection, its approaches (incoming road lanes) in a fixed order.
        roads = np.flatnonzero(lanes.kind == ROAD)
        self._approaches = [roads[lanes.node[roads] == k] for k in range(len(town.nodes))]
        self._phase = rng.integers(0, 4, size=len(town.nodes)) % np.array([len(a) for a in self._approaches])
        self._green = np.ones(len(town.nodes), dtype=bool)
        self._timer = rng.uniform(0.0, config.green_s, size=len(town.nodes))
        # Lanes sharing a start point with a connector (connectors of the same approach).
        self._sibling = (lanes.kind[:, None] == CONNECTOR) & (lanes.approach[:, None] == lanes.approach[None, :]) & (
            lanes.kind[None, :] == CONNECTOR
        )
        self._walk = np.zeros(len(town.nodes), dtype=bool)
        self._greens_since_walk = np.zeros(len(town.nodes), dtype=np.int64)
        self._place_pedestrians(pedestrian_sizes, rng)
        self._place_crossers(crosser_sizes, rng)

    # ------------------------------------------------------------------ set-up
    def _place_vehicles(self, rng: np.random.Generator) -> None:
        lanes = self.town.lanes
        roads = np.flatnonzero(lanes.kind == ROAD)
        n = len(self.classes)
        lane = np.empty(n, dtype=np.int64)
        s = np.empty(n)
        # Fill road lanes in a random order, each with vehicles spaced by their lengths plus a gap.
        order = rng.permutation(n)
        fill = dict.fromkeys(roads.tolist(), 0.0)
        capacity_left = {r: lanes.length_m[r] for r in fill}
        cursor = 0
        for road in rng.permutation(roads).tolist() * (n + 1):
            if cursor == n:
                break
            vehicle = order[cursor]
            need = self.size_lwh[vehicle, 0] + self.config.min_gap_m + 6.0
            if capacity_left[road] < need:
                continue
            lane[vehicle] = road
            s[vehicle] = fill[road] + self.size_lwh[vehicle, 0] / 2 + 1.0
            fill[road] += need
            capacity_left[road] -= need
            cursor += 1
        if cursor < n:
            total = float(lanes.length_m[roads].sum())
            raise InputError(f"field traffic.vehicles: expected at most ~{int(total / 12)} for this town, got {n}")
        next1 = self._choose(lane)
        next2 = lanes.successors[next1, 0]
        self.state = TrafficState(
            lane=lane, s_m=s, speed_mps=self.desired_speed * rng.uniform(0.3, 0.8, n), previous_lane=lane.copy(),
            next_lanes=np.stack([next1, next2], axis=-1), accel_mps2=np.zeros(n),
        )

    def _choose(self, road_lanes: np.ndarray) -> np.ndarray:
        """Random connector after each road lane (one uniform draw per vehicle, always)."""
        succ = self.town.lanes.successors[road_lanes]
        count = (succ >= 0).sum(axis=1)
        pick = np.minimum((self.rng.random(len(road_lanes)) * count).astype(np.int64), count - 1)
        connectors: np.ndarray = succ[np.arange(len(road_lanes)), pick]
        return connectors

    def _place_pedestrians(self, sizes: np.ndarray, rng: np.random.Generator) -> None:
        loops = self.town.sidewalk_loops
        self.ped_size_lwh = sizes
        n = len(sizes)
        lengths = np.array([np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)) for p in loops])
        self._loop_s = [np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]) for p in loops]
        self._loop_length = lengths
        self._loop_speed = rng.uniform(*CLASS_SPECS["pedestrian"].desired_speed_mps, size=len(loops))
        self._loop_speed *= np.where(rng.random(len(loops)) < 0.5, -1.0, 1.0)
        loop = rng.integers(0, len(loops), size=n)
        s = np.empty(n)
        for k in np.unique(loop):
            members = np.flatnonzero(loop == k)
            # Evenly spread with jitter smaller than the spacing minus the walkers' length.
            spacing = lengths[k] / len(members)
            if spacing < 1.5:
                raise InputError(
                    f"field traffic.pedestrians: expected at most ~{int(lengths.sum() / 1.5)} for this town, got {n}"
                )
            jitter = np.maximum(spacing - 1.5, 0.0) * rng.random(len(members))
            s[members] = np.arange(len(members)) * spacing + jitter
        self.ped_loop = loop
        self.ped_s = s

    def _place_crossers(self, sizes: np.ndarray, rng: np.random.Generator) -> None:
        lines = self.town.crosswalk_lines
        n = len(sizes)
        if n > len(lines):
            raise InputError(f"field traffic.crossing_pedestrians: expected at most {len(lines)} for this town, got {n}")
        self.crosser_size_lwh = sizes
        self.crosser_line = rng.choice(len(lines), size=n, replace=False)
        self.crosser_at_end = rng.random(n) < 0.5
        self.crosser_crossing = np.zeros(n, dtype=bool)
        self.crosser_progress_m = np.zeros(n)
        self.crosser_wait_s = rng.uniform(0.0, MIN_WAIT_S, n)
        self.crosser_speed = rng.uniform(*CLASS_SPECS["pedestrian"].desired_speed_mps, size=n)
        self._line_length = np.linalg.norm(lines[:, 1] - lines[:, 0], axis=-1)

    def _step_crossers(self, dt_s: float) -> None:
        node = self.town.crosswalk_node[self.crosser_line]
        start = (~self.crosser_crossing & (self.crosser_wait_s >= MIN_WAIT_S) & self._walk[node]
                 & (self._timer[node] < WALK_START_WINDOW_S))
        self.crosser_crossing |= start
        self.crosser_progress_m = np.where(self.crosser_crossing, self.crosser_progress_m + self.crosser_speed * dt_s,
                                           0.0)
        arrived = self.crosser_crossing & (self.crosser_progress_m >= self._line_length[self.crosser_line])
        self.crosser_crossing &= ~arrived
        self.crosser_at_end ^= arrived
        self.crosser_progress_m[arrived] = 0.0
        self.crosser_wait_s = np.where(self.crosser_crossing | arrived, 0.0, self.crosser_wait_s + dt_s)

    # ------------------------------------------------------------------ simulation
    def step(self, dt_s: float) -> None:
        """Advances traffic and pedestrians by ``dt_s`` seconds."""
        self._update_signals(dt_s)
        st = self.state
        lanes = self.town.lanes
        n = len(st.lane)
        length = self.size_lwh[:, 0]
        cfg = self.config

        # Path offsets: where each lane starts along each vehicle's route (inf: not on the route).
        n_lanes = len(lanes.length_m)
        offset = np.full((n, n_lanes), np.inf)
        rows = np.arange(n)
        route = [st.lane, st.next_lanes[:, 0], st.next_lanes[:, 1]]
        starts = [np.zeros(n), lanes.length_m[st.lane], lanes.length_m[st.lane] + lanes.length_m[st.next_lanes[:, 0]]]
        for lane_k, start_k in zip(route, starts, strict=True):
            offset[rows, lane_k] = np.minimum(offset[rows, lane_k], start_k)
            sib = self._sibling[lane_k]
            offset = np.where(sib, np.minimum(offset, start_k[:, None]), offset)
        position = offset[:, st.lane] + st.s_m[None, :]  # (i, j): j's position along i's route
        ahead = (position > st.s_m[:, None]) | ((position == st.s_m[:, None]) & (rows[None, :] > rows[:, None]))
        ahead &= rows[None, :] != rows[:, None]
        gap = np.where(ahead, position - st.s_m[:, None] - (length[:, None] + length[None, :]) / 2, np.inf)
        leader = np.argmin(gap, axis=1)
        leader_gap = gap[rows, leader]
        leader_speed = np.where(np.isfinite(leader_gap), st.speed_mps[leader], 0.0)

        # Stop lines: vehicles on road lanes without right of way stop at their lane's end.
        on_road = lanes.kind[st.lane] == ROAD
        front_to_line = lanes.length_m[st.lane] - st.s_m - length / 2
        right_of_way = self._right_of_way(on_road, front_to_line, length)
        stop_gap = np.where(on_road & ~right_of_way, front_to_line, np.inf)
        use_stop = stop_gap < leader_gap
        gap_m = np.minimum(leader_gap, stop_gap)
        lead_v = np.where(use_stop, 0.0, leader_speed)

        # Free-flow speed, lowered ahead of a sharp connector.
        limit_here = np.minimum(self.desired_speed, lanes.speed_limit_mps[st.lane])
        next_limit = lanes.speed_limit_mps[st.next_lanes[:, 0]]
        to_next = np.maximum(lanes.length_m[st.lane] - st.s_m, 0.0)
        v0 = np.minimum(limit_here, np.sqrt(next_limit**2 + 2.0 * self.comfort_decel * to_next))
        v = st.speed_mps
        s_star = cfg.min_gap_m + np.maximum(
            0.0, v * cfg.time_headway_s + v * (v - lead_v) / (2.0 * np.sqrt(self.max_accel * self.comfort_decel))
        )
        interaction = np.where(np.isfinite(gap_m), (s_star / np.maximum(gap_m, 0.1)) ** 2, 0.0)
        accel = self.max_accel * (1.0 - np.square(np.square(v / np.maximum(v0, 0.1))) - interaction)
        accel = np.clip(accel, -9.0, self.max_accel)
        new_v = np.maximum(v + accel * dt_s, 0.0)
        advance = np.maximum((v + new_v) / 2 * dt_s, 0.0)
        # Hard guarantee: never closer than 0.5 m to where the leader (or stop line) is now.
        allowed = np.maximum(gap_m - 0.5, 0.0)
        clipped = advance > allowed
        advance = np.minimum(advance, allowed)
        new_v = np.where(clipped, np.minimum(new_v, advance / dt_s), new_v)
        st.accel_mps2 = (new_v - v) / dt_s
        st.speed_mps = new_v
        st.s_m = st.s_m + advance

        # Lane changes at lane ends (at most one per step: every lane is longer than a step).
        over = st.s_m > lanes.length_m[st.lane]
        fresh = self._choose(st.next_lanes[:, 1])
        next2 = np.where(lanes.kind[st.next_lanes[:, 1]] == ROAD, fresh, lanes.successors[st.next_lanes[:, 1], 0])
        st.s_m = np.where(over, st.s_m - lanes.length_m[st.lane], st.s_m)
        st.previous_lane = np.where(over, st.lane, st.previous_lane)
        st.lane = np.where(over, st.next_lanes[:, 0], st.lane)
        st.next_lanes = np.where(over[:, None], np.stack([st.next_lanes[:, 1], next2], axis=-1), st.next_lanes)

        self.ped_s = (self.ped_s + self._loop_speed[self.ped_loop] * dt_s) % self._loop_length[self.ped_loop]
        self._step_crossers(dt_s)
        self.time_s += dt_s

    def _right_of_way(self, on_road: np.ndarray, front_to_line: np.ndarray, length: np.ndarray) -> np.ndarray:
        """Whether each vehicle may cross its stop line now (meaningful for vehicles on road lanes)."""
        st = self.state
        lanes = self.town.lanes
        node = lanes.node[st.lane]
        is_green_approach = self._green_lane()[node] == st.lane
        cannot_stop = self._cannot_stop(front_to_line)
        # Room on the exit lane: its last vehicle's tail must leave space for this one.
        exit_lane = st.next_lanes[:, 1]
        tail = st.s_m - length / 2
        tail = np.where(st.lane[None, :] == exit_lane[:, None], tail[None, :], np.inf)
        room = tail.min(axis=1) >= length + self.config.min_gap_m
        # A vehicle too close to stop goes even without room: it waits inside the intersection, which
        # then stays closed to the other approaches until it has left.
        # During a walk phase only a vehicle already past its line may move on.
        may_cross: np.ndarray = is_green_approach & ((self._green[node] & room) | (cannot_stop & ~self._walk[node])) | (
            front_to_line <= 0.0)
        return may_cross

    def _green_lane(self) -> np.ndarray:
        """(I,) the approach lane whose turn it is at each intersection."""
        return np.array([a[p] for a, p in zip(self._approaches, self._phase, strict=True)])

    def _cannot_stop(self, front_to_line: np.ndarray) -> np.ndarray:
        """Vehicles within 1 m of their stop line, or too close to it to stop at ``STOP_DECEL_MPS2``."""
        speed = self.state.speed_mps
        cannot_stop: np.ndarray = (front_to_line <= 1.0) | (
            speed**2 / (2.0 * np.maximum(front_to_line, 1e-3)) > STOP_DECEL_MPS2)
        return cannot_stop

    def _update_signals(self, dt_s: float) -> None:
        lanes = self.town.lanes
        st = self.state
        length = self.size_lwh[:, 0]
        self._timer += dt_s
        # An intersection is occupied while any vehicle's box may reach into it: its centre on a
        # connector, its front past a stop line, or its rear still on the connector it just left.
        occupied = np.zeros(len(self.town.nodes), dtype=bool)
        on_connector = lanes.kind[st.lane] == CONNECTOR
        occupied[lanes.node[st.lane[on_connector]]] = True
        rear_inside = (st.s_m - length / 2 < 0.0) & (lanes.kind[st.previous_lane] == CONNECTOR)
        occupied[lanes.node[st.previous_lane[rear_inside]]] = True
        # Vehicles committed to the intersection: past the line, or unable to stop before it.
        on_road = ~on_connector
        front_to_line = lanes.length_m[st.lane] - st.s_m - length / 2
        committed = on_road & self._cannot_stop(front_to_line)
        committed &= (self._green_lane()[lanes.node[st.lane]] == st.lane) | (front_to_line <= 0.0)
        occupied[lanes.node[st.lane[committed]]] = True
        crossing_node = self.town.crosswalk_node[self.crosser_line]
        occupied[crossing_node[self.crosser_crossing]] = True
        waiting = ~self.crosser_crossing & (self.crosser_wait_s >= MIN_WAIT_S)
        walk_demand = np.zeros(len(self.town.nodes), dtype=bool)
        walk_demand[crossing_node[waiting]] = True
        # A walk phase ends once its start window is over and every crosser has arrived.
        end_walk = self._walk & (self._timer >= WALK_START_WINDOW_S) & ~occupied
        self._walk &= ~end_walk
        self._timer[end_walk] = 0.0
        # Actuated signals: a green ends after green_s, or after 2 s once nobody approaches it; the
        # next green goes to the next approach (in turn) that has a vehicle within 40 m of its line.
        demand = np.bincount(st.lane[on_road & (front_to_line < 40.0)], minlength=len(lanes.length_m)) > 0
        idle = ~demand[self._green_lane()]
        end_green = self._green & ((self._timer >= self.config.green_s) | ((self._timer >= 2.0) & idle))
        self._green &= ~end_green
        self._timer[end_green] = 0.0
        start_green = ~self._green & ~self._walk & (self._timer >= self.config.all_red_s) & ~occupied
        count = np.array([len(a) for a in self._approaches])
        start_walk = start_green & walk_demand & (self._greens_since_walk >= count)
        self._walk |= start_walk
        self._greens_since_walk[start_walk] = 0
        self._timer[start_walk] = 0.0
        start_green &= ~start_walk
        self._greens_since_walk[start_green] += 1
        for node in np.flatnonzero(start_green):
            approaches = self._approaches[node]
            order = (self._phase[node] + 1 + np.arange(len(approaches))) % len(approaches)
            waiting = order[demand[approaches[order]]]
            self._phase[node] = waiting[0] if len(waiting) else order[0]
        self._green |= start_green
        self._timer[start_green] = 0.0

    # ------------------------------------------------------------------ outputs
    def vehicle_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """(N, 2) box centres and (N,) headings of the moving vehicles.

        A vehicle's front and rear (``s +- length / 2``) both sit on its route, like the axles of a
        real vehicle, and its box spans the chord between them: in a turn the box cuts the inside of
        the curve instead of sweeping its corners over the neighbouring lanes.
        """
        st = self.state
        lanes = self.town.lanes
        half = self.size_lwh[:, 0] / 2
        front_s = st.s_m + half
        front_past = front_s > lanes.length_m[st.lane]
        front_lane = np.where(front_past, st.next_lanes[:, 0], st.lane)
        front_s = np.where(front_past, front_s - lanes.length_m[st.lane], front_s)
        rear_s = st.s_m - half
        rear_before = rear_s < 0.0
        rear_lane = np.where(rear_before, st.previous_lane, st.lane)
        rear_s = np.where(rear_before, rear_s + lanes.length_m[st.previous_lane], rear_s)
        front, _ = lanes.pose(front_lane, front_s)
        rear, _ = lanes.pose(rear_lane, rear_s)
        axis = front - rear
        return (front + rear) / 2, portable_math.arctan2(axis[:, 1], axis[:, 0])

    def crosser_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """(C, 2) positions and (C,) headings of the crossing pedestrians (facing the far curb)."""
        lines = self.town.crosswalk_lines[self.crosser_line]
        origin = np.where(self.crosser_at_end[:, None], lines[:, 1], lines[:, 0])
        target = np.where(self.crosser_at_end[:, None], lines[:, 0], lines[:, 1])
        direction = (target - origin) / self._line_length[self.crosser_line][:, None]
        xy = origin + direction * self.crosser_progress_m[:, None]
        return xy, portable_math.arctan2(direction[:, 1], direction[:, 0])

    def pedestrian_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """(P, 2) positions and (P,) headings of the sidewalk pedestrians.

        The heading is the chord from 0.4 m behind to 0.4 m ahead on the track, so it turns smoothly
        through the rounded block corners instead of jumping from one polyline segment to the next.
        """
        n = len(self.ped_s)
        xy = np.empty((n, 2))
        chord = np.empty((n, 2))
        for k in np.unique(self.ped_loop):  # one pass per sidewalk track
            members = np.flatnonzero(self.ped_loop == k)
            at = self.ped_s[members]
            step = np.sign(self._loop_speed[k]) * 0.4
            # The position and both chord ends in one lookup (each point depends only on its own arc length).
            here, ahead, behind = np.split(self._loop_point(k, np.concatenate([at, at + step, at - step])), 3)
            xy[members] = here
            chord[members] = ahead - behind
        return xy, portable_math.arctan2(chord[:, 1], chord[:, 0])

    def _loop_point(self, loop: int, s_m: np.ndarray) -> np.ndarray:
        """(M, 2) points at arc lengths ``s_m`` (taken modulo the length) along a closed track."""
        pts, s = self.town.sidewalk_loops[loop], self._loop_s[loop]
        s_m = np.mod(s_m, self._loop_length[loop])
        seg = np.clip(np.searchsorted(s, s_m, side="right") - 1, 0, len(s) - 2)
        frac = ((s_m - s[seg]) / np.maximum(s[seg + 1] - s[seg], 1e-9))[:, None]
        points: np.ndarray = pts[seg] + frac * (pts[seg + 1] - pts[seg])
        return points
