"""nuScenes detection metrics (mAP, TP errors, NDS) as nuscenes-devkit 1.2.0's ``DetectionEval`` computes them.

Definitions, following ``nuscenes.eval.detection`` (``algo.accumulate``, ``calc_ap``, ``calc_tp``,
``DetectionMetrics``):

* boxes farther than the class range from the ego vehicle (xy distance, strict ``<``) are dropped, and so are
  ground-truth boxes with no lidar or radar point;
* per class and per distance threshold, predictions are taken by descending score (ties: later index first)
  and each is matched to the nearest not-yet-taken ground truth of its sample (xy centre distance; strict
  ``<`` threshold). Matches in different samples never interact, so all samples advance together: round r
  handles the r-th prediction of every sample at once;
* precision is interpolated at 101 recall points (``right=0``); AP averages ``max(0, p - 0.1) / 0.9`` over the
  points above recall 0.1;
* TP errors (ATE, ASE = 1 - aligned IoU, AOE with period pi for barrier, AVE, AAE = 1 - attribute accuracy) are
  cumulative means over matches at the 2 m threshold, interpolated onto the recall points and averaged from
  recall 0.1 to the highest recall reached (1 if never above 0.1); traffic cones have no AOE / AVE / AAE and
  barriers no AVE / AAE;
* NDS = (5 mAP + sum over the five TP metrics of max(0, 1 - error)) / 10, the errors nan-averaged over classes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from avdata.errors import InputError, shown
from avdata.eval.matching import greedy_match
from avdata.eval.nuscenes_gt import (
    CATEGORY_TO_CLASS,
    BikeRacks,
    annotation_velocities,
    check_submission_samples,
    finite_array,
    lidar_ego_translations,
    load_tables,
    outside_bike_racks,
    read_json,
    select_samples,
)
from avdata.eval.problems import check_ground_truth
from avdata.frames.rotations import matrix_from_quat_wxyz
from avdata.schema.limits import MAX_BOX_SIZE_M, MAX_SPEED_MPS
from avdata.sources.nuscenes.categories import ATTRIBUTES, DETECTION_NAMES

__all__ = [
    "NUSCENES_CLASSES",
    "DetectionBoxes",
    "NuScenesDetectionConfig",
    "NuScenesDetectionResult",
    "NuScenesMetric",
    "evaluate_nuscenes_detection",
    "load_nuscenes_gt",
    "load_nuscenes_submission",
]

NUSCENES_CLASSES = DETECTION_NAMES
_N_RECALL = 101


class NuScenesMetric(str, Enum):
    """Metric names in the output (the devkit's TP metric names, with mAP and NDS)."""

    MAP = "mAP"
    NDS = "NDS"
    TRANS_ERR = "trans_err"
    SCALE_ERR = "scale_err"
    ORIENT_ERR = "orient_err"
    VEL_ERR = "vel_err"
    ATTR_ERR = "attr_err"


_TP_METRICS = (NuScenesMetric.TRANS_ERR, NuScenesMetric.SCALE_ERR, NuScenesMetric.ORIENT_ERR,
               NuScenesMetric.VEL_ERR, NuScenesMetric.ATTR_ERR)


@dataclass(frozen=True, slots=True, kw_only=True)
class NuScenesDetectionConfig:
    """The devkit's ``detection_cvpr_2019`` configuration.

    Attributes:
        class_range_m: class -> maximum xy distance from the ego vehicle.
        dist_thresholds_m: centre-distance thresholds AP is averaged over.
        dist_threshold_tp_m: threshold at which TP errors are measured.
        min_recall: recalls at or below this are ignored.
        min_precision: precisions below this count as zero.
        max_boxes_per_sample: more predictions in one sample is an error.
        mean_ap_weight: weight of mAP in NDS.
    """

    class_range_m: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({
        "car": 50.0, "truck": 50.0, "bus": 50.0, "trailer": 50.0, "construction_vehicle": 50.0,
        "pedestrian": 40.0, "motorcycle": 40.0, "bicycle": 40.0, "traffic_cone": 30.0, "barrier": 30.0,
    }))
    dist_thresholds_m: tuple[float, ...] = (0.5, 1.0, 2.0, 4.0)
    dist_threshold_tp_m: float = 2.0
    min_recall: float = 0.1
    min_precision: float = 0.1
    max_boxes_per_sample: int = 500
    mean_ap_weight: float = 5.0


@dataclass(frozen=True, slots=True, kw_only=True)
class DetectionBoxes:
    """N boxes in a global frame, ground truth or predictions.

    Attributes:
        sample: (N,) sample (frame) key of each box.
        translation_m: (N, 3) box centre.
        size_m: (N, 3) box size (length, width, height); nuScenes' (width, length, height) is reordered on load.
        yaw_rad: (N,) heading about z.
        velocity_mps: (N, 2) xy velocity (NaN when unknown).
        name: (N,) class name.
        score: (N,) detection score (-1 for ground truth).
        attribute: (N,) attribute name, "" when none.
        num_points: (N,) lidar + radar points in the box (-1 for predictions: never filtered).
        ego_translation_m: (N, 3) centre relative to the ego vehicle (global axes), for the class range.
    """

    sample: np.ndarray
    translation_m: np.ndarray
    size_m: np.ndarray
    yaw_rad: np.ndarray
    velocity_mps: np.ndarray
    name: np.ndarray
    score: np.ndarray
    attribute: np.ndarray
    num_points: np.ndarray
    ego_translation_m: np.ndarray

    def __len__(self) -> int:
        """Number of boxes."""
        return len(self.sample)

    def take(self, index: np.ndarray) -> DetectionBoxes:
        """The boxes at ``index`` ((K,) integer or (N,) bool)."""
        return DetectionBoxes(**{k: getattr(self, k)[index] for k in self.__slots__})


@dataclass(frozen=True, slots=True, kw_only=True)
class ClassCurves:
    """Interpolated curves of one class at one distance threshold (101 recall points)."""

    recall: np.ndarray
    precision: np.ndarray
    confidence: np.ndarray
    errors: Mapping[str, np.ndarray]


@dataclass(frozen=True, slots=True, kw_only=True)
class NuScenesDetectionResult:
    """Outcome of :func:`evaluate_nuscenes_detection`.

    Attributes:
        label_aps: class -> threshold -> AP.
        label_tp_errors: class -> TP metric name -> error (NaN where the class has no such metric).
        curves: (class, threshold) -> interpolated curves.
        mean_ap: mAP.
        tp_errors: TP metric name -> error averaged over classes (NaN-ignoring).
        nd_score: NDS.
    """

    label_aps: Mapping[str, Mapping[float, float]]
    label_tp_errors: Mapping[str, Mapping[str, float]]
    curves: Mapping[tuple[str, float], ClassCurves]
    mean_ap: float
    tp_errors: Mapping[str, float]
    nd_score: float

    def summary(self) -> dict[str, dict[str, float]]:
        """``{class: {metric: value}}`` plus ``"all"``: AP per threshold as ``AP@<t>``, mean AP, TP errors."""
        out: dict[str, dict[str, float]] = {}
        for cls, aps in self.label_aps.items():
            row = {f"AP@{t:g}": float(v) for t, v in aps.items()}
            row["AP"] = float(np.mean(list(aps.values())))
            row.update({k: float(v) for k, v in self.label_tp_errors[cls].items()})
            out[cls] = row
        out["all"] = {NuScenesMetric.MAP.value: self.mean_ap, NuScenesMetric.NDS.value: self.nd_score}
        out["all"].update({k: float(v) for k, v in self.tp_errors.items()})
        return out


def _filter(boxes: DetectionBoxes, config: NuScenesDetectionConfig, is_gt: bool) -> DetectionBoxes:
    max_dist = np.array([config.class_range_m.get(n, -np.inf) for n in boxes.name.tolist()], dtype=np.float64)
    ego_dist = np.sqrt(boxes.ego_translation_m[:, 0] ** 2 + boxes.ego_translation_m[:, 1] ** 2)
    keep = ego_dist < max_dist
    if is_gt:
        keep &= boxes.num_points != 0
    return boxes.take(keep)


def _angle_diff(x: np.ndarray, y: np.ndarray, period: float) -> np.ndarray:
    diff = (x - y + period / 2) % period - period / 2
    result: np.ndarray = np.abs(np.where(diff > np.pi, diff - 2 * np.pi, diff))
    return result


def _cummean(x: np.ndarray) -> np.ndarray:
    if np.isnan(x).all():
        return np.ones(len(x))
    sums = np.nancumsum(x.astype(float))
    counts = np.cumsum(~np.isnan(x))
    result: np.ndarray = np.divide(sums, counts, out=np.zeros_like(sums), where=counts != 0)
    return result


def _accumulate(gt: DetectionBoxes, pred: DetectionBoxes, cls: str, threshold: float) -> ClassCurves | None:
    """The devkit's ``accumulate`` for one class and threshold; None stands for ``no_predictions``."""
    gt = gt.take(gt.name == cls)
    pred = pred.take(pred.name == cls)
    if len(gt) == 0:
        return None
    # sorted((score, index))[::-1]: descending score, ties by descending index.
    order = np.lexsort((np.arange(len(pred)), pred.score))[::-1]
    match = greedy_match(gt.sample, gt.translation_m[:, :2], pred.sample, pred.translation_m[:, :2], order, threshold,
                         inclusive=False)
    matched_in_order = match[order] >= 0
    if not matched_in_order.any():
        return None
    tp = np.cumsum(matched_in_order).astype(float)
    fp = np.cumsum(~matched_in_order).astype(float)
    conf = pred.score[order]
    prec = tp / (fp + tp)
    rec = tp / float(len(gt))
    rec_interp = np.linspace(0, 1, _N_RECALL)
    prec = np.interp(rec_interp, rec, prec, right=0)
    conf = np.interp(rec_interp, rec, conf, right=0)
    p_idx = order[matched_in_order]
    g_idx = match[p_idx]
    period = np.pi if cls == "barrier" else 2 * np.pi
    gt_attr = gt.attribute[g_idx]
    attr_acc = np.where(gt_attr == "", np.nan, (gt_attr == pred.attribute[p_idx]).astype(float))
    gt_size, pred_size = gt.size_m[g_idx], pred.size_m[p_idx]
    inter = np.prod(np.minimum(gt_size, pred_size), axis=1)
    scale_iou = inter / (np.prod(gt_size, axis=1) + np.prod(pred_size, axis=1) - inter)
    raw = {
        "trans_err": np.linalg.norm(pred.translation_m[p_idx, :2] - gt.translation_m[g_idx, :2], axis=1),
        "vel_err": np.linalg.norm(pred.velocity_mps[p_idx] - gt.velocity_mps[g_idx], axis=1),
        "scale_err": 1 - scale_iou,
        "orient_err": _angle_diff(_wrap(gt.yaw_rad[g_idx]), _wrap(pred.yaw_rad[p_idx]), period),
        "attr_err": 1 - attr_acc,
    }
    match_conf = pred.score[p_idx]
    errors = {
        k: np.interp(conf[::-1], match_conf[::-1], _cummean(v)[::-1])[::-1] for k, v in raw.items()
    }
    return ClassCurves(recall=rec_interp, precision=prec, confidence=conf, errors=errors)


def _wrap(yaw: np.ndarray) -> np.ndarray:
    """Yaw as the devkit reads it back from a quaternion: atan2 of the rotated x axis, in (-pi, pi]."""
    result: np.ndarray = np.arctan2(np.sin(yaw), np.cos(yaw))
    return result


def _no_predictions() -> ClassCurves:
    ones = np.ones(_N_RECALL)
    return ClassCurves(
        recall=np.linspace(0, 1, _N_RECALL), precision=np.zeros(_N_RECALL), confidence=np.zeros(_N_RECALL),
        errors={m.value: ones for m in _TP_METRICS},
    )


def _calc_ap(curves: ClassCurves, config: NuScenesDetectionConfig) -> float:
    prec = curves.precision[round(100 * config.min_recall) + 1:] - config.min_precision
    prec[prec < 0] = 0
    return float(np.mean(prec)) / (1.0 - config.min_precision)


def _calc_tp(curves: ClassCurves, config: NuScenesDetectionConfig, metric: str) -> float:
    first = round(100 * config.min_recall) + 1
    nonzero = np.flatnonzero(curves.confidence)
    last = nonzero[-1] if len(nonzero) else 0
    if last < first:
        return 1.0
    return float(np.mean(curves.errors[metric][first:last + 1]))


def evaluate_nuscenes_detection(
    gt: DetectionBoxes,
    pred: DetectionBoxes,
    config: NuScenesDetectionConfig = NuScenesDetectionConfig(),
    bike_racks: BikeRacks | None = None,
) -> NuScenesDetectionResult:
    """NuScenes detection evaluation.

    Args:
        gt: ground-truth boxes (classes outside the nuScenes detection classes are ignored).
        pred: predictions; every sample key must also occur in ``gt`` or be absent.
        config: thresholds and ranges.
        bike_racks: the samples' bicycle racks (:func:`load_nuscenes_bike_racks`); cycles inside one are
            not evaluated, as in the devkit. None when the data has no racks.

    Returns:
        APs, TP errors, mAP and NDS, and the curves behind them.
    """
    if len(pred):
        _, per_sample = np.unique(pred.sample, return_counts=True)
        if per_sample.max() > config.max_boxes_per_sample:
            raise InputError(
                f"predictions: expected at most {config.max_boxes_per_sample} boxes per sample, "
                f"got {per_sample.max()}"
            )
    unknown = set(np.unique(pred.name).tolist()) - set(NUSCENES_CLASSES)
    if unknown:
        raise InputError(f"predictions name: expected nuScenes detection classes, got {sorted(unknown)}")
    gt = _filter(gt, config, is_gt=True)
    pred = _filter(pred, config, is_gt=False)
    if bike_racks is not None:
        gt = gt.take(outside_bike_racks(gt.name, gt.sample, gt.translation_m, bike_racks))
        pred = pred.take(outside_bike_racks(pred.name, pred.sample, pred.translation_m, bike_racks))
    gt_classes = set(np.unique(gt.name).tolist()) & set(NUSCENES_CLASSES)
    if not gt_classes:
        raise InputError("ground truth: expected boxes of the nuScenes detection classes within range and with "
                         "lidar or radar points, got none")
    check_ground_truth("ground truth", NUSCENES_CLASSES, [c for c in NUSCENES_CLASSES if c not in gt_classes],
                       "their AP is 0 (boxes count within range and with lidar or radar points)")
    label_aps: dict[str, dict[float, float]] = {}
    label_tp: dict[str, dict[str, float]] = {}
    curves: dict[tuple[str, float], ClassCurves] = {}
    for cls in NUSCENES_CLASSES:
        for th in config.dist_thresholds_m:
            curves[(cls, th)] = _accumulate(gt, pred, cls, th) or _no_predictions()
        label_aps[cls] = {th: _calc_ap(curves[(cls, th)], config) for th in config.dist_thresholds_m}
        tp_curves = curves.get((cls, config.dist_threshold_tp_m)) or (
            _accumulate(gt, pred, cls, config.dist_threshold_tp_m) or _no_predictions()
        )
        label_tp[cls] = {}
        for metric in _TP_METRICS:
            if (cls == "traffic_cone" and metric in (NuScenesMetric.ATTR_ERR, NuScenesMetric.VEL_ERR,
                                                     NuScenesMetric.ORIENT_ERR)) or (
                cls == "barrier" and metric in (NuScenesMetric.ATTR_ERR, NuScenesMetric.VEL_ERR)
            ):
                label_tp[cls][metric.value] = np.nan
            else:
                label_tp[cls][metric.value] = _calc_tp(tp_curves, config, metric.value)
    mean_ap = float(np.mean([np.mean(list(label_aps[c].values())) for c in NUSCENES_CLASSES]))
    tp_errors = {m.value: float(np.nanmean([label_tp[c][m.value] for c in NUSCENES_CLASSES])) for m in _TP_METRICS}
    tp_scores = [max(0.0, 1.0 - e) for e in tp_errors.values()]
    nds = (config.mean_ap_weight * mean_ap + float(np.sum(tp_scores))) / (config.mean_ap_weight + len(tp_scores))
    return NuScenesDetectionResult(
        label_aps=label_aps, label_tp_errors=label_tp, curves=curves, mean_ap=mean_ap, tp_errors=tp_errors,
        nd_score=float(nds),
    )


def _yaw_from_quaternion(q_wxyz: np.ndarray) -> np.ndarray:
    """(N,) yaw of the rotated x axis projected on the xy plane (the devkit's ``quaternion_yaw``)."""
    if not len(q_wxyz):
        return np.zeros(0)
    rotation = matrix_from_quat_wxyz(q_wxyz)
    result: np.ndarray = np.arctan2(rotation[:, 1, 0], rotation[:, 0, 0])
    return result


_ATTRIBUTES = frozenset(ATTRIBUTES)
#: |norm - 1| of a submitted rotation beyond float noise: the devkit normalises it, a norm of 2 is damage.
_UNIT_TOLERANCE = 1e-3


def _check_box(path: Path, where: str, wlh_m: np.ndarray, q_wxyz: np.ndarray) -> None:
    """A submitted box's size in [0, MAX_BOX_SIZE_M] (a negative one is no box) and a unit quaternion."""
    if np.any(wlh_m < 0.0) or np.any(wlh_m > MAX_BOX_SIZE_M):
        raise InputError(f"{path}: {where} size: expected sizes in [0, {MAX_BOX_SIZE_M:g}] m, got {wlh_m.tolist()}")
    if abs(float(np.linalg.norm(q_wxyz)) - 1.0) > _UNIT_TOLERANCE:
        raise InputError(f"{path}: {where} rotation: expected a unit quaternion (w, x, y, z), got {q_wxyz.tolist()}")


def load_nuscenes_submission(
    path: str | Path, ego_poses: Mapping[str, np.ndarray], samples: Mapping[str, dict[str, Any]] | None = None
) -> DetectionBoxes:
    """Reads a nuScenes detection submission JSON (``{"meta": ..., "results": {sample_token: [box, ...]}}``).

    Boxes are checked as the devkit's ``DetectionBox`` checks them: translation (3), size (3) and rotation (4)
    finite numbers, velocity (2) numbers (NaN allowed), a finite float ``detection_score``, a detection class and
    a known attribute (or ""). Each problem is an :class:`InputError` naming the sample token, box and value.

    Args:
        path: the submission file.
        ego_poses: sample token -> (3,) ego translation at that sample (for the class-range filter).
        samples: the evaluated samples; the submission must cover exactly these (the devkit's "Samples in split
            doesn't match samples in predictions"). None accepts any subset of ``ego_poses``.

    Returns:
        The predicted boxes.
    """
    path = Path(path)
    data = read_json(path, "submission")
    if not isinstance(data, dict) or not isinstance(data.get("results"), dict):
        got = sorted(data) if isinstance(data, dict) else type(data).__name__
        raise InputError(f"{path}: expected a 'results' object (sample token -> boxes), got {got}")
    results = data["results"]
    if samples is not None:
        check_submission_samples(path, results, samples)
    for token in results:
        if token not in ego_poses:
            raise InputError(f"{path}: results sample_token: expected a sample of the ground truth, got {token!r}")
    sample, translation, wlh, quat, velocity, name, score, attribute = [], [], [], [], [], [], [], []
    for token, boxes in results.items():
        if not isinstance(boxes, list):
            raise InputError(f"{path}: results[{token!r}]: expected a list of boxes, got {type(boxes).__name__}")
        for k, box in enumerate(boxes):
            where = f"results[{token!r}][{k}]"
            if not isinstance(box, dict):
                raise InputError(f"{path}: {where}: expected a box object, got {type(box).__name__}")
            try:
                translation.append(finite_array(box["translation"], 3, path, f"{where} translation"))
                wlh.append(finite_array(box["size"], 3, path, f"{where} size"))
                quat.append(finite_array(box["rotation"], 4, path, f"{where} rotation"))
                vel = box["velocity"]
                # NaN is "no velocity" (the devkit's); infinity, true or 1e308 would be a vel_err of any size.
                if not (isinstance(vel, list) and len(vel) == 2
                        and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                and (np.isnan(v) or abs(v) <= MAX_SPEED_MPS) for v in vel)):
                    raise InputError(f"{path}: {where} velocity: expected 2 numbers within {MAX_SPEED_MPS:g} m/s "
                                     f"(NaN for none), got {shown(vel)}")
                _check_box(path, where, wlh[-1], quat[-1])
                velocity.append(vel)
                cls, sc, attr = box["detection_name"], box["detection_score"], box.get("attribute_name", "")
            except KeyError as exc:
                raise InputError(f"{path}: {where}: expected field {exc.args[0]!r}, got none") from None
            if cls not in NUSCENES_CLASSES:
                raise InputError(f"{path}: {where} detection_name: expected one of {', '.join(NUSCENES_CLASSES)}, "
                                 f"got {cls!r}")
            if isinstance(sc, bool) or not isinstance(sc, (int, float)) or not np.isfinite(sc):
                raise InputError(f"{path}: {where} detection_score: expected a finite number, got {sc!r}")
            if attr != "" and attr not in _ATTRIBUTES:
                raise InputError(f"{path}: {where} attribute_name: expected a nuScenes attribute or '', got {attr!r}")
            sample.append(token)
            name.append(cls)
            score.append(float(sc))
            attribute.append(attr)
    translation_m = np.array(translation, dtype=np.float64).reshape(-1, 3)
    ego = np.array([ego_poses[t] for t in sample], dtype=np.float64).reshape(-1, 3)
    size = np.array(wlh, dtype=np.float64).reshape(-1, 3)
    return DetectionBoxes(
        sample=np.array(sample, dtype=object), translation_m=translation_m, size_m=size[:, [1, 0, 2]],
        yaw_rad=_yaw_from_quaternion(np.array(quat, dtype=np.float64).reshape(-1, 4)),
        velocity_mps=np.array(velocity, dtype=np.float64).reshape(-1, 2), name=np.array(name, dtype=object),
        score=np.array(score, dtype=np.float64), attribute=np.array(attribute, dtype=object),
        num_points=np.full(len(sample), -1), ego_translation_m=translation_m - ego,
    )


def load_nuscenes_gt(
    table_dir: str | Path, scene_names: set[str] | None = None
) -> tuple[DetectionBoxes, dict[str, np.ndarray], dict[str, dict[str, Any]]]:
    """Reads ground truth from nuScenes tables (``sample.json``, ``sample_annotation.json``, ...).

    Velocities are the devkit's ``box_velocity`` (:func:`avdata.eval.nuscenes_gt.annotation_velocities`).

    Args:
        table_dir: folder holding the tables (e.g. ``<dataroot>/v1.0-trainval``).
        scene_names: scenes to evaluate (a split); None for every scene. Unknown names are an error.

    Returns:
        The boxes of every annotated sample of those scenes; sample token -> (3,) ego translation (of the
        sample's LIDAR_TOP key frame); and the evaluated samples (token -> record), which a submission must
        cover exactly.
    """
    table_dir = Path(table_dir)
    tables = load_tables(table_dir, (
        "scene", "sample", "sample_data", "ego_pose", "sample_annotation", "instance", "category", "attribute",
        "calibrated_sensor", "sensor"))
    try:
        return _gt_boxes(table_dir, tables, scene_names)
    except KeyError as exc:
        raise InputError(f"{table_dir}: expected nuScenes tables with field or token {exc.args[0]!r}, got none") from None
    except TypeError as exc:
        raise InputError(f"{table_dir}: expected nuScenes tables with fields of the schema's types, got {exc}") from None


def _gt_boxes(table_dir: Path, tables: Mapping[str, list[dict[str, Any]]], scene_names: set[str] | None
              ) -> tuple[DetectionBoxes, dict[str, np.ndarray], dict[str, dict[str, Any]]]:
    samples = select_samples(table_dir, tables, scene_names)
    ego = lidar_ego_translations(table_dir, tables, samples)
    category = {c["token"]: c["name"] for c in tables["category"]}
    instance_class = {i["token"]: CATEGORY_TO_CLASS.get(category[i["category_token"]]) for i in tables["instance"]}
    attribute = {a["token"]: a["name"] for a in tables["attribute"]}
    anns = {a["token"]: a for a in tables["sample_annotation"]}
    timestamp = {s["token"]: s["timestamp"] for s in tables["sample"]}
    in_samples = [a for a in tables["sample_annotation"] if a["sample_token"] in samples]
    rows = [a for a in in_samples if instance_class[a["instance_token"]] is not None]
    if in_samples and not rows:
        names = sorted({category[i["category_token"]] for i in tables["instance"]})
        raise InputError(f"{table_dir / 'category.json'}: expected nuScenes category names that map to the detection "
                         f"classes, got none that do ({', '.join(names[:6])}{' ...' if len(names) > 6 else ''})")
    for a in rows:
        if len(a["attribute_tokens"]) > 1:
            raise InputError(f"{table_dir / 'sample_annotation.json'}: {a['token']} attribute_tokens: expected at most "
                             f"one, got {len(a['attribute_tokens'])}")
    path = table_dir / "sample_annotation.json"
    translation = np.array([finite_array(a["translation"], 3, path, f"{a['token']} translation") for a in rows]
                           ).reshape(-1, 3)
    wlh = np.array([finite_array(a["size"], 3, path, f"{a['token']} size") for a in rows]).reshape(-1, 3)
    quat = np.array([finite_array(a["rotation"], 4, path, f"{a['token']} rotation") for a in rows]).reshape(-1, 4)
    for a, wlh_m, q_wxyz in zip(rows, wlh, quat, strict=True):
        _check_box(path, a["token"], wlh_m, q_wxyz)
    sample = np.array([a["sample_token"] for a in rows], dtype=object)
    boxes = DetectionBoxes(
        sample=sample,
        translation_m=translation,
        size_m=wlh[:, [1, 0, 2]],
        yaw_rad=_yaw_from_quaternion(quat),
        velocity_mps=annotation_velocities(table_dir, rows, anns, timestamp),
        name=np.array([instance_class[a["instance_token"]] for a in rows], dtype=object),
        score=np.full(len(rows), -1.0),
        attribute=np.array([attribute[a["attribute_tokens"][0]] if a["attribute_tokens"] else "" for a in rows],
                           dtype=object),
        num_points=np.array([a["num_lidar_pts"] + a["num_radar_pts"] for a in rows], dtype=np.int64),
        ego_translation_m=translation - np.array([ego[t] for t in sample.tolist()]).reshape(-1, 3),
    )
    return boxes, ego, samples
