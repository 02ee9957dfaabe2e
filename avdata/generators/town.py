"""A procedural town.

A grid of blocks with two-lane roads, signalised intersections, sidewalks, buildings, walls, poles, trees
and parked vehicles.

Layout, seen from above (right-hand traffic, world z up, metres):

- intersections sit on a grid ``(i * block_pitch_m, j * block_pitch_m)``, centred on the world origin;
- every road carries one lane per direction, lane centres ``lane_width_m / 2`` right of the road
  centre line, then a parking strip (parked vehicles), then a raised sidewalk (pedestrians, trees,
  poles), then the building lots;
- a lane ends at its intersection's stop line, ``road_half_width + sidewalk_width`` from the
  intersection centre; connector lanes (quarter circles for turns, straight segments otherwise) join
  every incoming lane to every outgoing lane of the intersection except the U-turn.

Lanes are polylines sampled every ~0.5 m; a vehicle's position is (lane, arc length).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avdata import portable_math

ROAD, CONNECTOR = 0, 1
"""Lane kinds."""


@dataclass(frozen=True, slots=True, kw_only=True)
class TownConfig:
    """Shape of the procedural town.

    Attributes:
        grid: (columns, rows) of intersections, each at least 2.
        block_pitch_m: distance between neighbouring intersections.
        lane_width_m: width of one traffic lane.
        parking_width_m: width of the parking strip beside the outer lane.
        sidewalk_width_m: width of the raised sidewalk.
        building_height_m: (min, max) building heights.
        parked_per_100m: mean number of parked vehicles per 100 m of parking strip.
        tree_spacing_m: mean distance between street trees along a sidewalk.
    """

    grid: tuple[int, int] = (3, 3)
    block_pitch_m: float = 80.0
    lane_width_m: float = 3.5
    parking_width_m: float = 2.5
    sidewalk_width_m: float = 4.0
    building_height_m: tuple[float, float] = (6.0, 30.0)
    parked_per_100m: float = 3.0
    tree_spacing_m: float = 20.0

    @property
    def road_half_width_m(self) -> float:
        """Distance from a road's centre line to its curb."""
        return self.lane_width_m + self.parking_width_m

    @property
    def stop_line_m(self) -> float:
        """Distance from an intersection centre to the stop lines of its approaches."""
        return self.road_half_width_m + self.sidewalk_width_m


@dataclass(frozen=True, slots=True, kw_only=True)
class StaticScenery:
    """Static shapes of the town (object id -1), batch-first per shape kind.

    Attributes:
        box_center: (B, 3) centres of boxes (ground, sidewalks, buildings, walls).
        box_size: (B, 3) box sizes along the world axes (boxes are axis aligned).
        box_kind: (B,) names ("ground", "sidewalk", "building", "wall").
        cylinder_center: (C, 3) centres of upright cylinders (poles, tree trunks).
        cylinder_radius: (C,) radii.
        cylinder_height: (C,) heights.
        sphere_center: (S, 3) centres of spheres (tree crowns).
        sphere_radius: (S,) radii.
    """

    box_center: np.ndarray
    box_size: np.ndarray
    box_kind: np.ndarray
    cylinder_center: np.ndarray
    cylinder_radius: np.ndarray
    cylinder_height: np.ndarray
    sphere_center: np.ndarray
    sphere_radius: np.ndarray


@dataclass(frozen=True, slots=True, kw_only=True)
class LaneGraph:
    """All lanes of the town as one set of concatenated polylines.

    Attributes:
        points: (P, 2) polyline vertices of every lane, lane after lane.
        point_s: (P,) arc length of each vertex from its lane's start.
        start: (L,) index into ``points`` of each lane's first vertex.
        count: (L,) number of vertices of each lane.
        length_m: (L,) lane lengths.
        kind: (L,) ROAD or CONNECTOR.
        node: (L,) intersection a lane ends at (roads) or lies in (connectors).
        approach: (L,) for roads, the lane itself; for connectors, the road lane that feeds them.
        successors: (L, 3) following lanes, -1 padded (roads: connectors; connectors: one road).
        speed_limit_mps: (L,) curvature speed limit (lateral acceleration 2 m/s^2); inf on straights.
    """

    points: np.ndarray
    point_s: np.ndarray
    start: np.ndarray
    count: np.ndarray
    length_m: np.ndarray
    kind: np.ndarray
    node: np.ndarray
    approach: np.ndarray
    successors: np.ndarray
    speed_limit_mps: np.ndarray

    def pose(self, lane: np.ndarray, s_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions and headings at arc lengths along lanes.

        Args:
            lane: (N,) lane indices.
            s_m: (N,) arc lengths, clipped to each lane.

        Returns:
            (N, 2) positions and (N,) headings (rad, counter-clockwise from world x).
        """
        s_m = np.clip(s_m, 0.0, self.length_m[lane])
        first = self.start[lane]
        last = first + self.count[lane] - 1
        # Index of the segment holding s: vertices are sorted by s within a lane.
        offset = self.point_s + self._lane_base[np.repeat(np.arange(len(self.start)), self.count)]
        key = self._lane_base[lane] + s_m
        segment = np.clip(np.searchsorted(offset, key, side="right") - 1, first, last - 1)
        p0, p1 = self.points[segment], self.points[segment + 1]
        s0, s1 = self.point_s[segment], self.point_s[segment + 1]
        fraction = ((s_m - s0) / np.maximum(s1 - s0, 1e-9))[:, None]
        direction = p1 - p0
        return p0 + fraction * direction, portable_math.arctan2(direction[:, 1], direction[:, 0])

    @property
    def _lane_base(self) -> np.ndarray:
        # Lanes laid end to end on one axis with a 1 m gap, so a single searchsorted finds segments.
        return np.concatenate([[0.0], np.cumsum(self.length_m + 1.0)[:-1]])


@dataclass(frozen=True, slots=True, kw_only=True)
class Town:
    """A generated town.

    Attributes:
        config: the configuration it was built from.
        nodes: (I, 2) intersection centres.
        lanes: the lane graph.
        scenery: static shapes.
        parking_xy: (K, 2) centres of parking spaces, ``parking_yaw`` (K,) their headings.
        sidewalk_loops: polylines (M_i, 2) of closed pedestrian tracks (one per block and track).
        crosswalk_lines: (W, 2, 2) start and end of each walking line across a road at an
            intersection: two parallel lines per crosswalk, 0.8 m apart, just inside the stop line,
            between waiting spots 1 m into each sidewalk.
        crosswalk_node: (W,) the intersection each line belongs to.
        block_extent: (Bk, 4) xmin, ymin, xmax, ymax of each block (sidewalk included).
    """

    config: TownConfig
    nodes: np.ndarray
    lanes: LaneGraph
    scenery: StaticScenery
    parking_xy: np.ndarray
    parking_yaw: np.ndarray
    sidewalk_loops: list[np.ndarray]
    crosswalk_lines: np.ndarray
    crosswalk_node: np.ndarray
    block_extent: np.ndarray


def _polyline(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    return points, s


def _straight(p: np.ndarray, q: np.ndarray, step_m: float = 2.0) -> np.ndarray:
    n = max(int(np.ceil(np.linalg.norm(q - p) / step_m)), 1)
    t = np.linspace(0.0, 1.0, n + 1)[:, None]
    points: np.ndarray = p + t * (q - p)
    return points


def _arc(p: np.ndarray, d: np.ndarray, q: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, float]:
    """Quarter circle from ``p`` heading ``d`` to ``q`` heading ``e`` (d perpendicular to e)."""
    left = np.array([-d[1], d[0]])
    t = np.dot(q - p, e) / np.dot(left, e)
    center = p + t * left
    radius = abs(t)
    a0 = portable_math.arctan2(*(p - center)[::-1])
    turn = np.sign(t)  # +1 counter-clockwise (left turn)
    angles = a0 + turn * np.linspace(0.0, np.pi / 2, 16)
    return center + radius * np.stack([np.cos(angles), np.sin(angles)], axis=-1), radius


def build_town(config: TownConfig, rng: np.random.Generator) -> Town:
    """Builds the town: lane graph, static scenery and parking spaces.

    Args:
        config: the town's shape.
        rng: random generator (buildings, trees, parking).
    """
    nx, ny = config.grid
    gx, gy = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    nodes = np.stack([gx.ravel(), gy.ravel()], axis=-1) * config.block_pitch_m
    nodes = nodes - nodes.mean(axis=0)
    node_of = {(int(i), int(j)): k for k, (i, j) in enumerate(zip(gx.ravel(), gy.ravel(), strict=True))}
    # Directed road lanes between neighbouring intersections.
    road_from, road_to = [], []
    for (i, j), a in node_of.items():
        for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            b = node_of.get((i + di, j + dj))
            if b is not None:
                road_from.append(a)
                road_to.append(b)
    lanes = _lane_graph(config, nodes, road_from, road_to)
    scenery, loops, blocks = _scenery(config, nodes, rng)
    parking_xy, parking_yaw = _parking(config, nodes, road_from, road_to, rng)
    lines, line_node = _crosswalks(config, nodes, road_from, road_to)
    return Town(
        config=config,
        nodes=nodes,
        lanes=lanes,
        scenery=scenery,
        parking_xy=parking_xy,
        parking_yaw=parking_yaw,
        sidewalk_loops=loops,
        crosswalk_lines=lines,
        crosswalk_node=line_node,
        block_extent=blocks,
    )


def _lane_graph(config: TownConfig, nodes: np.ndarray, road_from: list[int], road_to: list[int]) -> LaneGraph:
    """One road lane per directed road (lanes ``0 .. len(road_from) - 1``, in that order), then the connectors."""
    pitch = config.block_pitch_m
    half_lane = config.lane_width_m / 2
    stop = config.stop_line_m
    lane_points: list[np.ndarray] = []
    kind: list[int] = []
    node: list[int] = []
    approach: list[int] = []
    succ: list[list[int]] = []
    limit: list[float] = []
    road_entry: dict[tuple[int, int], int] = {}
    for a, b in zip(road_from, road_to, strict=True):
        d = (nodes[b] - nodes[a]) / pitch
        right = np.array([d[1], -d[0]])
        p = nodes[a] + stop * d + half_lane * right
        q = nodes[b] - stop * d + half_lane * right
        road_entry[(a, b)] = len(lane_points)
        lane_points.append(_straight(p, q))
        kind.append(ROAD)
        node.append(b)
        approach.append(len(approach))
        succ.append([])
        limit.append(np.inf)
    for (a, b), incoming in list(road_entry.items()):
        for (b2, c), outgoing in road_entry.items():
            if b2 != b or c == a:
                continue
            p, q = lane_points[incoming][-1], lane_points[outgoing][0]
            d = (nodes[b] - nodes[a]) / pitch
            e = (nodes[c] - nodes[b]) / pitch
            if np.allclose(d, e):
                pts, radius = _straight(p, q), np.inf
            else:
                pts, radius = _arc(p, d, q, e)
            connector = len(lane_points)
            lane_points.append(pts)
            kind.append(CONNECTOR)
            node.append(b)
            approach.append(incoming)
            succ.append([outgoing])
            limit.append(np.sqrt(2.0 * radius))
            succ[incoming].append(connector)
    successors = np.full((len(lane_points), 3), -1, dtype=np.int64)
    for k, s in enumerate(succ):
        successors[k, : len(s)] = s
    polylines = [_polyline(p) for p in lane_points]
    count = np.array([len(p) for p in lane_points])
    return LaneGraph(
        points=np.concatenate(lane_points),
        point_s=np.concatenate([s for _, s in polylines]),
        start=np.concatenate([[0], np.cumsum(count)[:-1]]),
        count=count,
        length_m=np.array([s[-1] for _, s in polylines]),
        kind=np.array(kind),
        node=np.array(node),
        approach=np.array(approach),
        successors=successors,
        speed_limit_mps=np.array(limit),
    )


CROSSWALK_LINE_OFFSETS_M = (-1.3, -0.5)
"""Walking lines of a crosswalk, relative to the stop line (each line belongs to one pedestrian).

They are the two lines nearest the stop line: the sidewalk corner itself is swept by long vehicles
turning right (a 12 m bus on a 8.25 m radius cuts the corner by ~1 m), so people wait beside it,
not on it."""


def _crosswalks(config: TownConfig, nodes: np.ndarray, road_from: list[int],
                road_to: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Walking lines across every road at both of its intersections."""
    lines, line_node = [], []
    curb = config.road_half_width_m + 1.0  # waiting spots 1 m into the sidewalk
    for a, b in zip(road_from, road_to, strict=True):
        along = (nodes[b] - nodes[a]) / np.linalg.norm(nodes[b] - nodes[a])
        across = np.array([-along[1], along[0]])
        for offset in CROSSWALK_LINE_OFFSETS_M:
            centre = nodes[a] + (config.stop_line_m + offset) * along
            lines.append([centre - curb * across, centre + curb * across])
            line_node.append(a)
    return np.array(lines, dtype=np.float64), np.array(line_node, dtype=np.int64)


def _rounded_rectangle(xmin: float, ymin: float, xmax: float, ymax: float, radius: float) -> np.ndarray:
    """Closed counter-clockwise polyline around a rectangle with rounded corners (first == last)."""
    corners = [(xmax - radius, ymin + radius, -np.pi / 2), (xmax - radius, ymax - radius, 0.0),
               (xmin + radius, ymax - radius, np.pi / 2), (xmin + radius, ymin + radius, np.pi)]
    pieces = []
    for cx, cy, a0 in corners:
        a = a0 + np.linspace(0.0, np.pi / 2, 6)
        pieces.append(np.stack([cx + radius * np.cos(a), cy + radius * np.sin(a)], axis=-1))
    ring = np.concatenate(pieces)
    return np.concatenate([ring, ring[:1]])


class _SceneryParts:
    """The static shapes collected while the blocks are laid out, as the lists :class:`StaticScenery` is made of."""

    def __init__(self) -> None:
        self.box_center: list[list[float]] = []
        self.box_size: list[list[float]] = []
        self.box_kind: list[str] = []
        self.cylinder_center: list[list[float]] = []
        self.cylinder_radius: list[float] = []
        self.cylinder_height: list[float] = []
        self.sphere_center: list[list[float]] = []
        self.sphere_radius: list[float] = []

    def add_box(self, center: list[float], size: list[float], kind: str) -> None:
        self.box_center.append(center)
        self.box_size.append(size)
        self.box_kind.append(kind)

    def add_trees(self, xy: np.ndarray, ground_z: float, rng: np.random.Generator) -> None:
        """Trees at (n, 2) ``xy``: a trunk (cylinder) and a crown (sphere) each, random sizes."""
        n = len(xy)
        trunk = rng.uniform(3.0, 4.0, n)
        crown = rng.uniform(1.4, 2.0, n)
        self.cylinder_center.extend(np.c_[xy, ground_z + trunk / 2].tolist())
        self.cylinder_radius.extend(np.full(n, 0.15).tolist())
        self.cylinder_height.extend(trunk.tolist())
        self.sphere_center.extend(np.c_[xy, ground_z + trunk + crown * 0.8].tolist())
        self.sphere_radius.extend(crown.tolist())

    def add_lamp_post(self, x: float, y: float, ground_z: float) -> None:
        self.cylinder_center.append([x, y, ground_z + 3.5])
        self.cylinder_radius.append(0.12)
        self.cylinder_height.append(7.0)

    def scenery(self) -> StaticScenery:
        return StaticScenery(
            box_center=np.array(self.box_center, dtype=np.float64),
            box_size=np.array(self.box_size, dtype=np.float64),
            box_kind=np.array(self.box_kind),
            cylinder_center=np.array(self.cylinder_center, dtype=np.float64).reshape(-1, 3),
            cylinder_radius=np.array(self.cylinder_radius, dtype=np.float64),
            cylinder_height=np.array(self.cylinder_height, dtype=np.float64),
            sphere_center=np.array(self.sphere_center, dtype=np.float64).reshape(-1, 3),
            sphere_radius=np.array(self.sphere_radius, dtype=np.float64),
        )


CURB_HEIGHT_M = 0.15
"""Height of the sidewalks (and so of everything standing on them) above the road."""


def _scenery(config: TownConfig, nodes: np.ndarray,
             rng: np.random.Generator) -> tuple[StaticScenery, list[np.ndarray], np.ndarray]:
    """The ground, the blocks (sidewalks, lots, street trees, lamp posts), their pedestrian tracks and extents."""
    pitch = config.block_pitch_m
    road_half = config.road_half_width_m
    walk = config.sidewalk_width_m
    lo, hi = nodes.min(axis=0), nodes.max(axis=0)
    margin = pitch
    parts = _SceneryParts()
    parts.add_box(np.r_[(lo + hi) / 2, -0.1].tolist(), np.r_[hi - lo + 2 * margin, 0.2].tolist(), "ground")
    loops: list[np.ndarray] = []
    blocks = []
    # Blocks between intersections, plus a ring of outer blocks around the grid.
    xs = np.unique(nodes[:, 0])
    ys = np.unique(nodes[:, 1])
    edges_x = np.concatenate([[xs[0] - pitch], xs, [xs[-1] + pitch]])
    edges_y = np.concatenate([[ys[0] - pitch], ys, [ys[-1] + pitch]])
    for x0, x1 in zip(edges_x[:-1], edges_x[1:], strict=True):
        for y0, y1 in zip(edges_y[:-1], edges_y[1:], strict=True):
            bx0, bx1 = x0 + road_half, x1 - road_half
            by0, by1 = y0 + road_half, y1 - road_half
            blocks.append([bx0, by0, bx1, by1])
            parts.add_box([(bx0 + bx1) / 2, (by0 + by1) / 2, CURB_HEIGHT_M / 2], [bx1 - bx0, by1 - by0, CURB_HEIGHT_M],
                          "sidewalk")
            # Pedestrian tracks: two walking lanes on the inner half of the sidewalk, 1.4 m apart (wider
            # than two walkers); the outer half holds trees, lamp posts and people waiting to cross.
            for offset in (0.5, 0.85):
                inset = walk * offset
                loops.append(_rounded_rectangle(bx0 + inset, by0 + inset, bx1 - inset, by1 - inset, 1.5))
            # Lots: 2 x 2 per block, each a building, a walled yard or trees.
            lx0, lx1, ly0, ly1 = bx0 + walk + 0.5, bx1 - walk - 0.5, by0 + walk + 0.5, by1 - walk - 0.5
            mx, my = (lx0 + lx1) / 2, (ly0 + ly1) / 2
            for ax0, ax1 in ((lx0, mx - 1.0), (mx + 1.0, lx1)):
                for ay0, ay1 in ((ly0, my - 1.0), (my + 1.0, ly1)):
                    _lot(parts, config, (ax0, ay0, ax1, ay1), rng)
            _street_trees_and_posts(parts, config, (bx0, by0, bx1, by1), rng)
    return parts.scenery(), loops, np.array(blocks)


def _lot(parts: _SceneryParts, config: TownConfig, extent: tuple[float, float, float, float],
         rng: np.random.Generator) -> None:
    """One building lot (xmin, ymin, xmax, ymax): a building (3 in 4), a walled yard or a few trees."""
    ax0, ay0, ax1, ay1 = extent
    choice = rng.random()
    if choice < 0.75:
        setback = rng.uniform(0.0, 3.0, size=4)
        h = rng.uniform(*config.building_height_m)
        cx0, cx1 = ax0 + setback[0], ax1 - setback[1]
        cy0, cy1 = ay0 + setback[2], ay1 - setback[3]
        parts.add_box([(cx0 + cx1) / 2, (cy0 + cy1) / 2, CURB_HEIGHT_M + h / 2], [cx1 - cx0, cy1 - cy0, h], "building")
    elif choice < 0.9:
        h = rng.uniform(1.2, 2.5)
        for wc, ws in (
            ([(ax0 + ax1) / 2, ay0 + 0.15], [ax1 - ax0, 0.3]),
            ([(ax0 + ax1) / 2, ay1 - 0.15], [ax1 - ax0, 0.3]),
            ([ax0 + 0.15, (ay0 + ay1) / 2], [0.3, ay1 - ay0 - 0.6]),
            ([ax1 - 0.15, (ay0 + ay1) / 2], [0.3, ay1 - ay0 - 0.6]),
        ):
            parts.add_box([wc[0], wc[1], CURB_HEIGHT_M + h / 2], [ws[0], ws[1], h], "wall")
    else:
        n = rng.integers(2, 6)
        xy = np.stack([rng.uniform(ax0 + 2, ax1 - 2, n), rng.uniform(ay0 + 2, ay1 - 2, n)], -1)
        parts.add_trees(xy, CURB_HEIGHT_M, rng)


def _street_trees_and_posts(parts: _SceneryParts, config: TownConfig, block: tuple[float, float, float, float],
                            rng: np.random.Generator) -> None:
    """Street trees along each curb of a block, and a lamp post near both ends of each side.

    The posts are kept off the corners, which long vehicles cut when they turn.
    """
    bx0, by0, bx1, by1 = block
    walk = config.sidewalk_width_m
    tree_line = 0.5
    post = walk + 0.5
    for side in range(4):
        if side < 2:
            y = by0 + tree_line if side == 0 else by1 - tree_line
            n = rng.poisson((bx1 - bx0 - 2 * walk) / config.tree_spacing_m)
            xy = np.stack([rng.uniform(bx0 + post + 2.0, bx1 - post - 2.0, n), np.full(n, y)], -1)
            posts = [[bx0 + post, y], [bx1 - post, y]]
        else:
            x = bx0 + tree_line if side == 2 else bx1 - tree_line
            n = rng.poisson((by1 - by0 - 2 * walk) / config.tree_spacing_m)
            xy = np.stack([np.full(n, x), rng.uniform(by0 + post + 2.0, by1 - post - 2.0, n)], -1)
            posts = [[x, by0 + post], [x, by1 - post]]
        parts.add_trees(xy, CURB_HEIGHT_M, rng)
        for px, py in posts:
            parts.add_lamp_post(px, py, CURB_HEIGHT_M)


def _parking(config: TownConfig, nodes: np.ndarray, road_from: list[int], road_to: list[int],
             rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(K, 2) centres and (K,) headings of the parking spaces along every road lane, clear of the intersections."""
    pitch = config.block_pitch_m
    park_xy, park_yaw = [], []
    park_offset = config.lane_width_m + config.parking_width_m / 2
    for a, b in zip(road_from, road_to, strict=True):
        d = (nodes[b] - nodes[a]) / pitch
        right = np.array([d[1], -d[0]])
        usable = pitch - 2 * config.stop_line_m - 6.0
        n_slots = int(usable // 7.0)
        n_parked = min(int(rng.poisson(usable / 100.0 * config.parked_per_100m)), n_slots)
        slots = np.sort(rng.choice(n_slots, size=n_parked, replace=False))
        s = config.stop_line_m + 3.0 + 7.0 * slots + 3.5
        park_xy.append(nodes[a] + s[:, None] * d + park_offset * right)
        park_yaw.append(np.full(len(s), portable_math.arctan2(d[1], d[0])))
    return np.concatenate(park_xy), np.concatenate(park_yaw)
