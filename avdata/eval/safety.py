"""Responsibility-Sensitive Safety (RSS; Shalev-Shwartz, Shammah, Shashua 2017, arXiv:1708.06374 v6).

The minimum safe distances of the paper, with response time rho and the stated accelerations:

* longitudinal, same direction (Def. 1; rear car speed v_r >= 0 behind front car v_f >= 0):
  ``d = [v_r rho + a_acc rho^2 / 2 + (v_r + rho a_acc)^2 / (2 b_min) - v_f^2 / (2 b_max)]_+``
* longitudinal, opposite directions (Def. 3; car 1 in its correct lane at v_1 >= 0, car 2 approaching at
  |v_2|): ``d = (v_1 + v_1r)/2 rho + v_1r^2 / (2 b_min_correct) + (|v_2| + v_2r)/2 rho + v_2r^2 / (2 b_min)``
  with v_ir = |v_i| + rho a_acc;
* lateral (Def. 7; car 1 left of car 2, lateral velocities along the axis from car 1 to car 2):
  ``d = mu + [(v_1 + v_1r)/2 rho + v_1r|v_1r| / (2 b_lat) - ((v_2 + v_2r)/2 rho - v_2r|v_2r| / (2 b_lat))]_+``
  with v_1r = v_1 + rho a_lat, v_2r = v_2 - rho a_lat. The paper writes the braking terms as
  +v_1r^2 and -v_2r^2, which assumes v_1r >= 0 >= v_2r (each car drifting towards the other); the signed
  form v|v| (as Intel's ad-rss-lib evaluates it) equals the paper's there and stays right when a car drifts away.

A situation is *dangerous* (a violation) when both the longitudinal and the lateral gap between the two
boxes are below their minimum safe distances (Def. 8). Gaps and velocities are taken in the ego's axes
(x forward, y left): the longitudinal gap is |dx| minus both boxes' half extents along x, the lateral gap
|dy| minus their half extents along y. The ego is the car in its correct lane in the opposite-direction case.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyarrow as pa
from scipy.optimize import linear_sum_assignment

from avdata.errors import InputError
from avdata.frames.rotations import matrix_from_quat_wxyz

__all__ = [
    "RssParameters",
    "SafetyResult",
    "evaluate_safety",
    "lateral_safe_distance",
    "longitudinal_safe_distance",
    "longitudinal_safe_distance_opposite",
    "longitudinal_safe_distance_same_direction",
    "rss_violations",
]


@dataclass(frozen=True, slots=True, kw_only=True)
class RssParameters:
    """RSS parameters (defaults: common choices for urban driving; state yours when reporting).

    Attributes:
        response_time_s: rho.
        max_accel_mps2: a_max,accel, longitudinal acceleration during the response time.
        min_brake_mps2: a_min,brake, the braking every car is guaranteed to apply.
        max_brake_mps2: a_max,brake, the hardest braking of the car in front.
        min_brake_correct_mps2: a_min,brake,correct, braking of the car in its correct lane (opposite directions).
        lat_max_accel_mps2: a^lat_max,accel.
        lat_min_brake_mps2: a^lat_min,brake.
        lat_margin_m: mu, the lateral fluctuation margin.
    """

    response_time_s: float = 0.5
    max_accel_mps2: float = 3.5
    min_brake_mps2: float = 4.0
    max_brake_mps2: float = 8.0
    min_brake_correct_mps2: float = 3.0
    lat_max_accel_mps2: float = 0.2
    lat_min_brake_mps2: float = 0.8
    lat_margin_m: float = 0.1

    def __post_init__(self) -> None:
        """Checks that every deceleration is positive."""
        for name in ("max_brake_mps2", "min_brake_mps2", "min_brake_correct_mps2", "lat_min_brake_mps2"):
            if not getattr(self, name) > 0:
                raise InputError(f"RSS: expected {name} > 0, got {getattr(self, name)!r}")
        for name in ("response_time_s", "max_accel_mps2", "lat_max_accel_mps2", "lat_margin_m"):
            if not getattr(self, name) >= 0:
                raise InputError(f"RSS: expected {name} >= 0, got {getattr(self, name)!r}")


def longitudinal_safe_distance_same_direction(v_rear_mps: np.ndarray, v_front_mps: np.ndarray,
                                              p: RssParameters = RssParameters()) -> np.ndarray:
    """(N,) RSS Def. 1 for speeds (N,) >= 0 of the rear and the front car driving the same way."""
    v_r, v_f, rho = np.asarray(v_rear_mps, float), np.asarray(v_front_mps, float), p.response_time_s
    d = (v_r * rho + 0.5 * p.max_accel_mps2 * rho**2 + (v_r + rho * p.max_accel_mps2) ** 2 / (2 * p.min_brake_mps2)
         - v_f**2 / (2 * p.max_brake_mps2))
    return np.maximum(d, 0.0)


def longitudinal_safe_distance_opposite(v_correct_mps: np.ndarray, v_other_mps: np.ndarray,
                                        p: RssParameters = RssParameters()) -> np.ndarray:
    """(N,) RSS Def. 3 for speeds (N,) (magnitudes) of the car in its correct lane and the approaching car."""
    v1, v2, rho = np.abs(np.asarray(v_correct_mps, float)), np.abs(np.asarray(v_other_mps, float)), p.response_time_s
    v1r, v2r = v1 + rho * p.max_accel_mps2, v2 + rho * p.max_accel_mps2
    result: np.ndarray = ((v1 + v1r) / 2 * rho + v1r**2 / (2 * p.min_brake_correct_mps2)
            + (v2 + v2r) / 2 * rho + v2r**2 / (2 * p.min_brake_mps2))
    return result


def lateral_safe_distance(v_left_mps: np.ndarray, v_right_mps: np.ndarray, p: RssParameters = RssParameters()) -> np.ndarray:
    """(N,) RSS Def. 7; lateral velocities (N,) of the left and the right car along the left-to-right axis."""
    v1, v2, rho, a, b = (np.asarray(v_left_mps, float), np.asarray(v_right_mps, float), p.response_time_s,
                         p.lat_max_accel_mps2, p.lat_min_brake_mps2)
    v1r, v2r = v1 + rho * a, v2 - rho * a
    left_reach = (v1 + v1r) / 2 * rho + v1r * np.abs(v1r) / (2 * b)
    right_reach = (v2 + v2r) / 2 * rho + v2r * np.abs(v2r) / (2 * b)
    return p.lat_margin_m + np.maximum(left_reach - right_reach, 0.0)


def longitudinal_safe_distance(dx_m: np.ndarray, v_ego_x_mps: np.ndarray, v_obj_x_mps: np.ndarray,
                               p: RssParameters = RssParameters()) -> np.ndarray:
    """(N,) minimum longitudinal distance between the ego and objects at ``dx_m`` (N,) ahead (negative: behind).

    Velocities are along the ego's x axis. The rear car is the one behind along x; both moving forward is
    Def. 1, approaching each other Def. 3 (the ego in its correct lane), moving apart needs no distance, and
    both moving backwards is Def. 1 with the roles of front and rear exchanged.
    """
    dx, ve, vo = (np.asarray(a, float) for a in (dx_m, v_ego_x_mps, v_obj_x_mps))
    ahead = dx >= 0
    v_rear, v_front = np.where(ahead, ve, vo), np.where(ahead, vo, ve)
    same = longitudinal_safe_distance_same_direction(np.maximum(v_rear, 0), np.maximum(v_front, 0), p)
    reversed_same = longitudinal_safe_distance_same_direction(np.maximum(-v_front, 0), np.maximum(-v_rear, 0), p)
    opposite = longitudinal_safe_distance_opposite(ve, vo, p)
    return np.select(
        [(v_rear >= 0) & (v_front >= 0), (v_rear >= 0) & (v_front < 0), (v_rear < 0) & (v_front >= 0)],
        [same, opposite, np.zeros_like(same)],
        default=reversed_same,
    )


def rss_violations(ego_size_lw: np.ndarray, ego_velocity_xy: np.ndarray, rel_xy: np.ndarray, rel_yaw_rad: np.ndarray,
                   size_lw: np.ndarray, velocity_xy: np.ndarray, p: RssParameters = RssParameters()) -> np.ndarray:
    """(N,) whether each ego-object pair is dangerous; everything in the ego's axes.

    Args:
        ego_size_lw: (N, 2) or (2,) ego length and width.
        ego_velocity_xy: (N, 2) ego velocity in its own axes.
        rel_xy: (N, 2) object centre relative to the ego centre.
        rel_yaw_rad: (N,) object heading relative to the ego's.
        size_lw: (N, 2) object length and width.
        velocity_xy: (N, 2) object velocity in the ego's axes.
        p: RSS parameters.
    """
    ego_size_lw = np.broadcast_to(np.asarray(ego_size_lw, float), np.shape(size_lw))
    c, s = np.abs(np.cos(rel_yaw_rad)), np.abs(np.sin(rel_yaw_rad))
    half_x = size_lw[:, 0] / 2 * c + size_lw[:, 1] / 2 * s
    half_y = size_lw[:, 0] / 2 * s + size_lw[:, 1] / 2 * c
    gap_lon = np.abs(rel_xy[:, 0]) - ego_size_lw[:, 0] / 2 - half_x
    gap_lat = np.abs(rel_xy[:, 1]) - ego_size_lw[:, 1] / 2 - half_y
    d_lon = longitudinal_safe_distance(rel_xy[:, 0], ego_velocity_xy[:, 0], velocity_xy[:, 0], p)
    left = rel_xy[:, 1] >= 0  # the object is the left car; the left-to-right axis is -y
    v_left = np.where(left, -velocity_xy[:, 1], -ego_velocity_xy[:, 1])
    v_right = np.where(left, -ego_velocity_xy[:, 1], -velocity_xy[:, 1])
    d_lat = lateral_safe_distance(v_left, v_right, p)
    result: np.ndarray = (gap_lon < d_lon) & (gap_lat < d_lat)
    return result


@dataclass(frozen=True, slots=True, kw_only=True)
class SafetyResult:
    """RSS over a dataset (and optionally a tracker's estimates).

    Attributes:
        frames: frames evaluated.
        pairs: ego-object pairs on ground truth.
        violating_frames: frames with at least one dangerous ground-truth pair.
        violating_pairs: dangerous ground-truth pairs.
        track_pairs: ego-track pairs (0 without tracks).
        track_violating_frames: frames with at least one dangerous ego-track pair.
        track_violating_pairs: dangerous ego-track pairs.
        missed_violations: dangerous ground-truth pairs whose object no track matches in a dangerous pair.
        invented_violations: dangerous ego-track pairs whose track matches no dangerous ground-truth pair.
    """

    frames: int
    pairs: int
    violating_frames: int
    violating_pairs: int
    track_pairs: int = 0
    track_violating_frames: int = 0
    track_violating_pairs: int = 0
    missed_violations: int = 0
    invented_violations: int = 0

    def as_dict(self) -> dict[str, float | int]:
        """Counts and fractions, as the report tables print them."""
        out: dict[str, float | int] = {name: getattr(self, name) for name in self.__slots__}
        out["violating_frame_fraction"] = self.violating_frames / self.frames if self.frames else 0.0
        out["violating_pair_fraction"] = self.violating_pairs / self.pairs if self.pairs else 0.0
        out["track_violating_frame_fraction"] = self.track_violating_frames / self.frames if self.frames else 0.0
        out["track_violating_pair_fraction"] = self.track_violating_pairs / self.track_pairs if self.track_pairs else 0.0
        return out


_MATCH_DISTANCE_M = 2.0


def evaluate_safety(frames: pa.Table, objects: pa.Table, tracks: pa.Table | None = None, *,
                    ego_size_lw: tuple[float, float] = (4.5, 1.9), exclude_ids: frozenset[str] = frozenset(),
                    params: RssParameters = RssParameters()) -> SafetyResult:
    """RSS violations of the ego against every object, on ground truth and on tracks.

    Args:
        frames: ``index/frames.parquet`` rows (scene, frame_index, timestamp_ns, world_T_ego columns); the ego's
            velocity is the central difference of its positions.
        objects: ``index/objects.parquet`` rows (world boxes and ``v*_world_mps``).
        tracks: optional tracker output with the avdata-protocol columns (scene, frame_index, object_id,
            x/y_world_m, length_m, width_m, yaw_world_rad) and ``vx_world_mps``, ``vy_world_mps``.
            Missing (NaN) velocities, of objects or tracks, are central differences of their positions.
        ego_size_lw: the ego's length and width.
        exclude_ids: object ids that are agents themselves (the ego's own box), left out of the ground truth and
            of the tracks; a track whose centre lies inside the ego's own footprint is the ego too (seen by
            another agent's sensor, under a track id of its own), never an object in violation.
        params: RSS parameters.
    """
    ego = _ego_states(frames)
    gt = _pair_table(objects, ego, exclude_ids, "objects")
    gt_bad = rss_violations(np.asarray(ego_size_lw), gt["ego_v"], gt["rel"], gt["rel_yaw"], gt["size"], gt["v"], params)
    n_frames = len(ego["key"])
    result = dict(frames=n_frames, pairs=len(gt_bad), violating_frames=int(len(np.unique(gt["frame"][gt_bad]))),
                  violating_pairs=int(gt_bad.sum()))
    if tracks is not None:
        tr = _pair_table(tracks, ego, exclude_ids, "tracks")
        not_ego = ~np.all(np.abs(tr["rel"]) < np.asarray(ego_size_lw) / 2.0, axis=1)
        tr = {name: values[not_ego] for name, values in tr.items()}
        tr_bad = rss_violations(np.asarray(ego_size_lw), tr["ego_v"], tr["rel"], tr["rel_yaw"], tr["size"], tr["v"], params)
        gt_match, tr_match = _match(gt, tr)
        # A ground-truth violation is caught when its matched track is also in violation.
        caught = np.zeros(len(gt_bad), bool)
        caught[gt_match] = tr_bad[tr_match]
        confirmed = np.zeros(len(tr_bad), bool)
        confirmed[tr_match] = gt_bad[gt_match]
        result.update(track_pairs=len(tr_bad), track_violating_frames=int(len(np.unique(tr["frame"][tr_bad]))),
                      track_violating_pairs=int(tr_bad.sum()), missed_violations=int((gt_bad & ~caught).sum()),
                      invented_violations=int((tr_bad & ~confirmed).sum()))
    return SafetyResult(**result)


def _col(table: pa.Table, name: str, where: str) -> np.ndarray:
    if name not in table.column_names:
        raise InputError(f"{where}: expected column {name!r}, got {table.column_names}")
    values = table[name].to_numpy(zero_copy_only=False)
    result: np.ndarray = values
    return result


def _where(key: str) -> str:
    scene, frame = str(key).rsplit("\x1f", 1)
    return f"scene {scene!r} frame {frame}"


def _frame_keys(table: pa.Table, where: str) -> np.ndarray:
    return np.char.add(np.char.add(_col(table, "scene", where).astype(str), "\x1f"),
                       _col(table, "frame_index", where).astype(np.int64).astype(str))


def _ego_states(frames: pa.Table) -> dict[str, np.ndarray]:
    key = _frame_keys(frames, "frames")
    scene = _col(frames, "scene", "frames").astype(str)
    t = _col(frames, "timestamp_ns", "frames").astype(np.int64)
    xyz = np.stack([_col(frames, f"world_T_ego_{a}_m", "frames").astype(float) for a in "xyz"], axis=1)
    q = np.stack([_col(frames, f"world_T_ego_q{a}", "frames").astype(float) for a in "wxyz"], axis=1)
    if not np.all(np.isfinite(xyz)) or not np.all(np.isfinite(q)):
        bad = int(np.flatnonzero(~np.isfinite(np.c_[xyz, q]).all(axis=1))[0])
        raise InputError(f"frames: expected a finite ego pose, got {np.c_[xyz, q][bad].tolist()} at {_where(key[bad])}")
    rotation = matrix_from_quat_wxyz(q)  # the one rotation core, not quaternion arithmetic of our own
    yaw = np.arctan2(rotation[:, 1, 0], rotation[:, 0, 0])
    v_world = np.zeros((len(key), 2))
    for s in np.unique(scene).tolist():
        i = np.flatnonzero(scene == s)
        i = i[np.argsort(t[i], kind="stable")]
        if len(i) > 1:
            v_world[i] = np.stack([np.gradient(xyz[i, a], t[i] * 1e-9) for a in (0, 1)], axis=1)
    c, sn = np.cos(yaw), np.sin(yaw)
    v_ego = np.stack([c * v_world[:, 0] + sn * v_world[:, 1], -sn * v_world[:, 0] + c * v_world[:, 1]], axis=1)
    order = np.argsort(key)
    return {"key": key[order], "xy": xyz[order, :2], "yaw": yaw[order], "v": v_ego[order], "t": t[order]}


def _fill_velocity(cols: dict[str, np.ndarray], scene: np.ndarray, ids: np.ndarray, t_ns: np.ndarray) -> None:
    """Fills missing velocities (NaN: KITTI labels have none) in place.

    The central difference of the object's positions over its frames; an object seen in one frame only is
    taken as standing still.
    """
    missing = ~(np.isfinite(cols["vx_world_mps"]) & np.isfinite(cols["vy_world_mps"]))
    if not missing.any():
        return
    track = np.char.add(np.char.add(scene, "\x1f"), ids)
    for key in np.unique(track[missing]).tolist():
        i = np.flatnonzero(track == key)
        i = i[np.argsort(t_ns[i], kind="stable")]
        t_s = t_ns[i] * 1e-9
        for axis, name in (("x_world_m", "vx_world_mps"), ("y_world_m", "vy_world_mps")):
            if len(i) < 2 or np.any(np.diff(t_s) <= 0):
                estimate = np.zeros(len(i))
            else:
                estimate = np.gradient(cols[axis][i], t_s)
            cols[name][i] = np.where(np.isfinite(cols[name][i]), cols[name][i], estimate)


def _pair_table(table: pa.Table, ego: dict[str, np.ndarray], exclude_ids: frozenset[str], where: str) -> dict[str, np.ndarray]:
    ids = _col(table, "object_id", where).astype(str)
    keep = ~np.isin(ids, np.array(sorted(exclude_ids), dtype=str)) if exclude_ids else np.ones(len(ids), bool)
    table = table.filter(pa.array(keep))
    key = _frame_keys(table, where)
    pos = np.clip(np.searchsorted(ego["key"], key), 0, max(len(ego["key"]) - 1, 0))
    known = ego["key"][pos] == key if len(ego["key"]) else np.zeros(len(key), bool)
    if not known.all():
        raise InputError(f"{where}: expected rows of frames in index/frames.parquet, got {_where(key[~known][0])}")
    cols = {name: _col(table, name, where).astype(float) for name in
            ("x_world_m", "y_world_m", "length_m", "width_m", "yaw_world_rad", "vx_world_mps", "vy_world_mps")}
    _fill_velocity(cols, _col(table, "scene", where).astype(str), ids[keep], ego["t"][pos])
    values = np.stack(list(cols.values()), axis=1)
    if len(values) and not np.all(np.isfinite(values)):
        bad = int(np.flatnonzero(~np.isfinite(values).all(axis=1))[0])
        row = dict(zip(cols, values[bad].tolist(), strict=True))
        raise InputError(f"{where}: expected finite values, got {row} at {_where(key[bad])}")
    yaw_e = ego["yaw"][pos]
    c, s = np.cos(yaw_e), np.sin(yaw_e)
    d = np.stack([cols["x_world_m"], cols["y_world_m"]], axis=1) - ego["xy"][pos]

    def rotate(v: np.ndarray) -> np.ndarray:
        rotated: np.ndarray = np.stack([c * v[:, 0] + s * v[:, 1], -s * v[:, 0] + c * v[:, 1]], axis=1)
        return rotated

    return {"frame": key, "ego_v": ego["v"][pos], "rel": rotate(d), "rel_yaw": cols["yaw_world_rad"] - yaw_e,
            "size": np.stack([cols["length_m"], cols["width_m"]], axis=1),
            "v": rotate(np.stack([cols["vx_world_mps"], cols["vy_world_mps"]], axis=1)),
            "xy": np.stack([cols["x_world_m"], cols["y_world_m"]], axis=1)}


def _match(gt: dict[str, np.ndarray], tr: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, Hungarian matching of ground truth and tracks on BEV centre distance (<= 2 m)."""
    g_out, t_out = [], []
    for key in np.intersect1d(gt["frame"], tr["frame"]).tolist():
        gi, ti = np.flatnonzero(gt["frame"] == key), np.flatnonzero(tr["frame"] == key)
        dist = np.linalg.norm(gt["xy"][gi, None, :] - tr["xy"][None, ti, :], axis=2)
        rows, cols = linear_sum_assignment(dist)
        ok = dist[rows, cols] <= _MATCH_DISTANCE_M
        g_out.append(gi[rows[ok]])
        t_out.append(ti[cols[ok]])
    if not g_out:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(g_out), np.concatenate(t_out)

