"""nuScenes tracking AMOTA / AMOTP as nuscenes-devkit 1.2.0's ``TrackingEval`` computes them.

Per class (bicycle, bus, car, motorcycle, pedestrian, trailer, truck):

* ground truth outside the class range or with no lidar/radar point is dropped, and so are predictions outside
  the range; every predicted box takes its track's mean score; then every track, ground truth and predicted,
  is filled in at the samples between its first and last box (the devkit's ``interpolate_tracks``, including
  its weighting: a box at time t between boxes at t_l < t < t_r takes ``(1 - r) * left + r * right`` with
  ``r = (t_r - t) / (t_r - t_l)``);
* frames are matched as py-motmetrics 1.4.0's ``MOTAccumulator`` does, per scene: an object keeps the
  hypothesis it was last matched to if that is present within 2 m (xy centre distance); the rest are assigned
  by a minimum-cost maximum-cardinality assignment; a match to a different hypothesis than the object's last
  one is a switch;
* the score thresholds are the scores reaching recall 0.1 ... 1 (40 values) by interpolating the scores of
  the predictions matched in an unthresholded run; at each threshold MOTAR = max(0, 1 - (FN + IDS + FP -
  (1 - R) P) / (R P)) with R = matches / P, and MOTP = mean distance of matches and switches;
* AMOTA (AMOTP) averages MOTAR (MOTP) over the 40 thresholds, unreached ones counting as 0 (2 m); a class
  with no match at all gets NaN; the overall value is the mean over classes, NaNs ignored.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from avdata.errors import InputError, shown
from avdata.eval.nuscenes_gt import (
    CATEGORY_TO_CLASS,
    BikeRacks,
    check_submission_samples,
    finite_array,
    lidar_ego_translations,
    load_tables,
    outside_bike_racks,
    read_json,
    select_samples,
)
from avdata.eval.problems import check_ground_truth
from avdata.eval.tracking.motmetrics import MotmetricsAccumulator

__all__ = ["NUSCENES_TRACKING_CLASSES", "TrackBoxes", "evaluate_nuscenes_tracking", "load_nuscenes_tracking"]

NUSCENES_TRACKING_CLASSES = ("bicycle", "bus", "car", "motorcycle", "pedestrian", "trailer", "truck")
_CLASS_RANGE_M = {"car": 50.0, "truck": 50.0, "bus": 50.0, "trailer": 50.0, "pedestrian": 40.0,
                  "motorcycle": 40.0, "bicycle": 40.0}
_DIST_TH_M = 2.0
_MIN_RECALL = 0.1
_N_THRESHOLDS = 40
_WORST = {"amota": 0.0, "amotp": 2.0}


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackBoxes:
    """Boxes with track ids, grouped by scene and sample.

    Attributes:
        sample: (N,) sample key.
        scene: (N,) scene key.
        timestamp: (N,) sample timestamp (any monotonic unit).
        track_id: (N,) track id (instance token for ground truth).
        name: (N,) tracking class.
        score: (N,) tracking score (-1 for ground truth).
        xy_m: (N, 2) global xy centre.
        z_m: (N,) global centre height (for the bike-rack filter).
        ego_dist_m: (N,) xy distance from the ego vehicle.
        num_points: (N,) lidar + radar points (-1 for predictions).
    """

    sample: np.ndarray
    scene: np.ndarray
    timestamp: np.ndarray
    track_id: np.ndarray
    name: np.ndarray
    score: np.ndarray
    xy_m: np.ndarray
    z_m: np.ndarray
    ego_dist_m: np.ndarray
    num_points: np.ndarray


def load_nuscenes_tracking(
    table_dir: str | Path, submission: str | Path, scene_names: set[str] | None = None
) -> tuple[TrackBoxes, TrackBoxes, dict[str, list[int]]]:
    """Reads ground truth from nuScenes tables and a tracking submission JSON.

    Args:
        table_dir: folder holding the tables.
        submission: ``{"meta": ..., "results": {sample_token: [{translation, tracking_id, tracking_name,
            tracking_score, ...}]}}``.
        scene_names: scenes to evaluate; None for all.

    Returns:
        Ground truth, predictions, and scene -> its sample timestamps in order.
    """
    table_dir = Path(table_dir)
    t = load_tables(table_dir, ("scene", "sample", "sample_data", "ego_pose", "sample_annotation", "instance",
                                "category", "calibrated_sensor", "sensor"))
    try:
        samples = select_samples(table_dir, t, scene_names)
        ego = lidar_ego_translations(table_dir, t, samples)
        category = {c["token"]: c["name"] for c in t["category"]}
        inst_class = {i["token"]: CATEGORY_TO_CLASS.get(category[i["category_token"]]) for i in t["instance"]}
        gt_rows = [a for a in t["sample_annotation"] if a["sample_token"] in samples
                   and inst_class[a["instance_token"]] in NUSCENES_TRACKING_CLASSES]
        path = table_dir / "sample_annotation.json"
        gt = _boxes(
            [(a["sample_token"], a["instance_token"], inst_class[a["instance_token"]], -1.0,
              finite_array(a["translation"], 3, path, f"{a['token']} translation"),
              a["num_lidar_pts"] + a["num_radar_pts"]) for a in gt_rows], samples, ego)
    except KeyError as exc:
        raise InputError(f"{table_dir}: expected nuScenes tables with field or token {exc.args[0]!r}, got none") from None
    if not gt_rows:
        raise InputError(f"{table_dir}: expected annotations of the nuScenes tracking classes in the evaluated scenes, "
                         f"got none")
    order: dict[str, list[int]] = defaultdict(list)
    for tok in sorted(samples, key=lambda k: samples[k]["timestamp"]):
        order[samples[tok]["scene_token"]].append(samples[tok]["timestamp"])
    submission = Path(submission)
    data = read_json(submission, "tracking submission")
    if not isinstance(data, dict) or not isinstance(data.get("results"), dict):
        raise InputError(f"{submission}: expected a 'results' object (sample token -> boxes)")
    check_submission_samples(submission, data["results"], samples)
    rows: list[tuple[str, str, str, float, np.ndarray, int]] = []
    for token, boxes in data["results"].items():
        if not isinstance(boxes, list):
            raise InputError(f"{submission}: results[{token!r}]: expected a list of boxes, got {type(boxes).__name__}")
        seen: dict[tuple[str, str], int] = {}  # (class, track id) -> box: the devkit evaluates class by class
        for k, b in enumerate(boxes):
            where = f"results[{token!r}][{k}]"
            if not isinstance(b, dict) or not {"translation", "tracking_id", "tracking_name", "tracking_score"} <= set(b):
                raise InputError(f"{submission}: {where}: expected a box with translation, tracking_id, tracking_name, "
                                 f"tracking_score, got {b!r:.120}")
            if b["tracking_name"] not in NUSCENES_TRACKING_CLASSES:
                raise InputError(f"{submission}: {where} tracking_name: expected one of {NUSCENES_TRACKING_CLASSES}, "
                                 f"got {b['tracking_name']!r}")
            score = b["tracking_score"]
            if isinstance(score, bool) or not isinstance(score, (int, float)) or not np.isfinite(score):
                raise InputError(f"{submission}: {where} tracking_score: expected a finite number, got {score!r}")
            track_id = b["tracking_id"]
            # str() would make null, true or [1] an id, and two boxes of one track in one sample are not a track.
            if isinstance(track_id, bool) or not isinstance(track_id, (str, int)):
                raise InputError(f"{submission}: {where} tracking_id: expected a string or an integer, got "
                                 f"{shown(track_id)}")
            if (first := seen.setdefault((b["tracking_name"], str(track_id)), k)) != k:
                raise InputError(f"{submission}: {where} tracking_id: expected each track once per sample, got "
                                 f"{track_id!r} also at [{first}]")
            rows.append((token, str(track_id), b["tracking_name"], float(score),
                         finite_array(b["translation"], 3, submission, f"{where} translation"), -1))
    return gt, _boxes(rows, samples, ego), dict(order)


def _boxes(rows: Sequence[tuple[str, str, str | None, float, np.ndarray, int]], samples: Mapping[str, dict[str, Any]],
           ego: Mapping[str, np.ndarray]) -> TrackBoxes:
    xyz = np.array([r[4] for r in rows], dtype=np.float64).reshape(-1, 3)
    ego_xyz = np.array([ego[r[0]] for r in rows], dtype=np.float64).reshape(-1, 3)
    return TrackBoxes(
        sample=np.array([r[0] for r in rows], dtype=object),
        scene=np.array([samples[r[0]]["scene_token"] for r in rows], dtype=object),
        timestamp=np.array([samples[r[0]]["timestamp"] for r in rows], dtype=np.int64),
        track_id=np.array([r[1] for r in rows], dtype=object),
        name=np.array([r[2] for r in rows], dtype=object),
        score=np.array([r[3] for r in rows], dtype=np.float64),
        xy_m=xyz[:, :2],
        z_m=xyz[:, 2],
        ego_dist_m=np.hypot(xyz[:, 0] - ego_xyz[:, 0], xyz[:, 1] - ego_xyz[:, 1]),
        num_points=np.array([r[5] for r in rows], dtype=np.int64),
    )


_Frame = list[tuple[str, str, float, np.ndarray]]  # (track id, class, score, xy)


def _frames(boxes: TrackBoxes, keep: np.ndarray, order: dict[str, list[int]]) -> dict[str, dict[int, _Frame]]:
    out: dict[str, dict[int, _Frame]] = {s: {ts: [] for ts in stamps} for s, stamps in order.items()}
    for i in np.flatnonzero(keep):
        out[boxes.scene[i]][int(boxes.timestamp[i])].append(
            (boxes.track_id[i], boxes.name[i], float(boxes.score[i]), boxes.xy_m[i]))
    return out


def _average_track_scores(frames: dict[int, _Frame]) -> None:
    """Every predicted box takes its track's mean score (over the scene), as the devkit's ``create_tracks``."""
    scores: dict[str, list[float]] = defaultdict(list)
    for boxes in frames.values():
        for box in boxes:
            scores[box[0]].append(box[2])
    mean = {tid: float(np.mean(v)) for tid, v in scores.items()}
    for ts, boxes in frames.items():
        frames[ts] = [(b[0], b[1], mean[b[0]], b[3]) for b in boxes]


def _interpolate(frames: dict[int, _Frame]) -> None:
    """The devkit's ``interpolate_tracks`` on one scene, in place."""
    by_id: dict[str, list[tuple[str, str, float, np.ndarray]]] = defaultdict(list)
    stamps_by_id: dict[str, list[int]] = defaultdict(list)
    for ts, boxes in frames.items():
        for box in boxes:
            by_id[box[0]].append(box)
            stamps_by_id[box[0]].append(ts)
    for ts in list(frames):
        for tid, track in by_id.items():
            stamps = stamps_by_id[tid]
            if stamps[0] <= ts <= stamps[-1] and ts not in stamps:
                right = int(np.searchsorted(stamps, ts, side="right"))
                left = right - 1
                ratio = float(stamps[right] - ts) / (stamps[right] - stamps[left])
                xy = (1.0 - ratio) * np.asarray(track[left][3]) + ratio * np.asarray(track[right][3])
                score = (1.0 - ratio) * track[left][2] + ratio * track[right][2]
                frames[ts].append((tid, track[right][1], score, xy))


def _accumulate(gt: dict[str, dict[int, _Frame]], pred: dict[str, dict[int, _Frame]], cls: str,
                threshold: float | None) -> tuple[list[MotmetricsAccumulator], list[float]]:
    """One motmetrics accumulator per scene, and the scores of matched predictions (threshold None)."""
    accumulators = []
    scores: list[float] = []
    for scene, frames in gt.items():
        acc = MotmetricsAccumulator()
        for ts, frame_gt in frames.items():
            g = [b for b in frame_gt if b[1] == cls]
            p = [b for b in pred[scene][ts] if b[1] == cls and (threshold is None or b[2] >= threshold)]
            if not g and not p:
                continue
            dist = np.full((len(g), len(p)), np.nan)
            if g and p:
                gxy, pxy = np.array([b[3] for b in g]), np.array([b[3] for b in p])
                # scikit-learn's euclidean_distances, which the devkit calls, in its operation order.
                d = -2 * (gxy @ pxy.T)
                d += np.einsum("ij,ij->i", gxy, gxy)[:, None]
                d += np.einsum("ij,ij->i", pxy, pxy)[None, :]
                dist = np.sqrt(np.maximum(d, 0))
                dist[dist >= _DIST_TH_M] = np.nan
            matched = set(acc.update([b[0] for b in g], [b[0] for b in p], dist))
            if threshold is None:
                scores.extend(b[2] for b in p if b[0] in matched)
        accumulators.append(acc)
    return accumulators, scores


def _thresholds(scores: list[float], gt_count: int) -> np.ndarray:
    if not scores:
        return np.full(_N_THRESHOLDS, np.nan)
    s = np.sort(np.array(scores))[::-1]
    rec = np.arange(1, len(s) + 1) / gt_count
    rec_interp = np.linspace(_MIN_RECALL, 1, _N_THRESHOLDS).round(12)
    th = np.interp(rec_interp, rec, s, right=0)
    th[rec_interp > rec.max()] = np.nan
    result: np.ndarray = th[::-1]
    return result


def evaluate_nuscenes_tracking(
    gt: TrackBoxes, pred: TrackBoxes, sample_order: dict[str, list[int]], bike_racks: BikeRacks | None = None
) -> dict[str, dict[str, float]]:
    """AMOTA and AMOTP per class and overall.

    Args:
        gt: ground-truth boxes.
        pred: predicted track boxes.
        sample_order: scene -> its sample timestamps in order (every sample is a frame).
        bike_racks: bicycle racks; cycles centred in one are not evaluated, as in the devkit.

    Returns:
        ``{class: {"AMOTA", "AMOTP"}}`` plus ``"all"`` (NaN-ignoring mean over classes).
    """
    gt_range = np.array([_CLASS_RANGE_M.get(n, -np.inf) for n in gt.name.tolist()])
    pred_range = np.array([_CLASS_RANGE_M.get(n, -np.inf) for n in pred.name.tolist()])
    gt_keep = (gt.ego_dist_m < gt_range) & (gt.num_points != 0)
    pred_keep = pred.ego_dist_m < pred_range
    if bike_racks is not None:
        gt_keep &= outside_bike_racks(gt.name, gt.sample, np.c_[gt.xy_m, gt.z_m], bike_racks)
        pred_keep &= outside_bike_racks(pred.name, pred.sample, np.c_[pred.xy_m, pred.z_m], bike_racks)
    gt_frames = _frames(gt, gt_keep, sample_order)
    for frames in gt_frames.values():
        _interpolate(frames)
    pred_frames = _frames(pred, pred_keep, sample_order)
    for frames in pred_frames.values():
        _average_track_scores(frames)
        _interpolate(frames)
    out: dict[str, dict[str, float]] = {}
    gt_counts = {cls: sum(1 for frames in gt_frames.values() for boxes in frames.values() for b in boxes if b[1] == cls)
                 for cls in NUSCENES_TRACKING_CLASSES}
    check_ground_truth("ground truth", NUSCENES_TRACKING_CLASSES, [c for c, n in gt_counts.items() if n == 0],
                       "their AMOTA and AMOTP are NaN, left out of 'all' (boxes count within range and with points)")
    for cls in NUSCENES_TRACKING_CLASSES:
        gt_count = gt_counts[cls]
        if gt_count == 0:
            out[cls] = {"AMOTA": float("nan"), "AMOTP": float("nan")}
            continue
        _, scores = _accumulate(gt_frames, pred_frames, cls, None)
        thresholds = _thresholds(scores, gt_count)
        motar = np.full(_N_THRESHOLDS, np.nan)
        motp = np.full(_N_THRESHOLDS, np.nan)
        cache: dict[float, tuple[float, float]] = {}
        for k, th in enumerate(thresholds):
            if np.isnan(th):
                continue
            if th not in cache:
                accs, _ = _accumulate(gt_frames, pred_frames, cls, float(th))
                matches, switches = sum(a.matches for a in accs), sum(a.switches for a in accs)
                objects = sum(a.objects for a in accs)
                errors = sum(a.misses + a.switches + a.false_positives for a in accs)
                recall = matches / objects
                denominator = recall * objects
                m = np.nan if denominator == 0 else max(0.0, 1 - (errors - (1 - recall) * objects) / denominator)
                detections = matches + switches
                distance = sum(a.distance_sum for a in accs)
                cache[th] = (m, np.nan if detections == 0 else distance / detections)
            motar[k], motp[k] = cache[th]
        out[cls] = {"AMOTA": _average(motar, _WORST["amota"]), "AMOTP": _average(motp, _WORST["amotp"])}
    out["all"] = {k: float(np.nanmean([out[c][k] for c in NUSCENES_TRACKING_CLASSES]))
                  if not all(np.isnan(out[c][k]) for c in NUSCENES_TRACKING_CLASSES) else float("nan")
                  for k in ("AMOTA", "AMOTP")}
    return out


def _average(values: np.ndarray, worst: float) -> float:
    if np.all(np.isnan(values)):
        return float("nan")
    return float(np.nanmean(np.where(np.isnan(values), worst, values)))
