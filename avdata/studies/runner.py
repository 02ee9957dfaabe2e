"""Runs a study: one generation task per trial, one evaluation task per (case, trial); resumable.

Layout of OUT:

```
OUT/study.yaml                     the study as run (normalised)
OUT/trials/trial-<i>/              the generated unified dataset of trial i (scene seed = seed + i)
OUT/runs/<case>__trial-<i>.json    one (case, trial): {"result": the row, with the fingerprint of its inputs and
                                   its checksum; "frames": per-frame counts; "seconds": time of each stage}
OUT/results.parquet                every result, one row per (case, trial)
```

A trial dataset or a run result counts as done only when its fingerprint (the study's generator settings,
and for runs the case, the files its detector reads, the evaluation settings and the trial) matches and, for
a run, its checksum matches its content (an edited result is redone, with a warning); otherwise it is redone.
A metric that does not apply (no collaboration, nothing predicted) is stored as null, never NaN.

OUT is a local folder or a prefix in an object store (``s3://``, ``gs://``), written through one
:class:`~avdata.executors.folder.OutputFolder` under its writer lock: every file appears whole (renamed into place,
or published from a temporary key), a trial's stamp after its dataset, ``results.parquet`` after every run; so an
interrupted study resumes where it stopped. The datasets a study reads may be in a store too (ranged reads).
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import yaml
from scipy.optimize import linear_sum_assignment

from avdata.errors import AvdataError, InputError, shown
from avdata.eval.detection.image import frame_counts_2d
from avdata.eval.names import Similarity, TrackingMetric
from avdata.eval.prediction import PredictionConfig
from avdata.eval.safety import evaluate_safety
from avdata.eval.tracking import evaluate_tracking, summary
from avdata.eval.unified import prediction_metrics, tracking_sequences
from avdata.executors import Executor, TaskFailure, make_executor
from avdata.executors.folder import OutputFolder, folder_lock
from avdata.outputs import checked_name
from avdata.perception.camera import CameraView, label_boxes_2d
from avdata.perception.collaboration import boxes_by_frame
from avdata.perception.tracker import Tracker, checked_tracks
from avdata.progress import Progress
from avdata.schema import DatasetReader, scene_path
from avdata.schema.dataset import dataset_root
from avdata.storage import Location
from avdata.studies.config import CASE_AXES, METRICS, CaseConfig, EvaluationConfig, StudyConfig
from avdata.studies.pipeline import Predictor, StageTimer, detection_stage, make_predictor, make_tracker

__all__ = ["RunResult", "result_checksum", "run_case", "run_pipeline", "run_study", "trial_dataset"]

_TRACK_COLUMNS = ("scene", "frame_index", "object_id", "class", "x_world_m", "y_world_m", "z_world_m", "length_m",
                  "width_m", "height_m", "yaw_world_rad", "vx_world_mps", "vy_world_mps")


def run_case(
    root: str | Path | Location,
    scene: str,
    case: CaseConfig,
    evaluation: EvaluationConfig | None = None,
    *,
    ego: str = "ego",
    seed: int = 0,
    tracker: Tracker | None = None,
) -> dict[str, float]:
    """Detect, track, predict and evaluate one scene of a unified dataset under one case.

    Args:
        root: the unified dataset (simulated detections need visibility labels for its lidars).
        scene: the scene.
        case: the case (its detector, tracker and predictor, and collaboration axes).
        evaluation: evaluation settings (default :class:`~avdata.studies.config.EvaluationConfig`).
        ego: the receiving agent.
        seed: seed of the simulated detections.
        tracker: any ``(Detections) -> Tracks`` callable, fresh for this scene, fed detections in ``world``
            (default: the case's tracker).

    Returns:
        The per-trial metrics of :data:`avdata.studies.config.METRICS` (NaN where not applicable).
    """
    return run_pipeline(root, scene, case, evaluation, ego=ego, seed=seed, tracker=tracker).metrics


@dataclass(frozen=True, slots=True)
class RunResult:
    """One scene under one case.

    Attributes:
        metrics: per-sequence metrics (:data:`~avdata.studies.config.METRICS`).
        frames: per-frame counts: ``frame_index``, ``detections``, ``tracks``, ``tp``, ``fp``, ``fn`` (and
            ``tp_2d``, ``fp_2d``, ``fn_2d`` in the camera's image when the detections carry 2D boxes).
        seconds: wall time of each stage (detect, track, predict, evaluate).
    """

    metrics: dict[str, float]
    frames: dict[str, list[int]]
    seconds: dict[str, float]


def run_pipeline(root: str | Path | Location, scene: str, case: CaseConfig, evaluation: EvaluationConfig | None = None, *,
                 ego: str = "ego", seed: int = 0, tracker: Tracker | None = None) -> RunResult:
    """:func:`run_case` with the per-frame results and the time of each stage."""
    evaluation = evaluation or EvaluationConfig()
    ds = DatasetReader(root)
    timer = StageTimer()
    start = time.perf_counter()
    stage = detection_stage(ds, scene, case, evaluation, ego=ego, seed=seed)
    tracker = tracker if tracker is not None else make_tracker(case)
    predict = make_predictor(case)
    timer.add("detect", start)
    step_s = 1.0 / stage.frame_rate_hz
    horizon = max(1, int(round(evaluation.prediction_horizon_s / step_s)))
    start = time.perf_counter()
    gt_all, gt_eval = _ground_truth(ds, scene, stage.own_object_ids, evaluation)
    gt_frames = _by_frame(gt_all, gt_eval)
    gt_2d = _ground_truth_2d(ds, scene, stage.camera, gt_all, gt_eval) if stage.camera is not None else None
    timer.add("evaluate", start)
    track_rows: dict[str, list[Any]] = {c: [] for c in _TRACK_COLUMNS}
    pred_parts: list[dict[str, np.ndarray]] = []
    in_range, received = [], []
    counts = ("frame_index", "detections", "tracks", "tp", "fp", "fn") + (("tp_2d", "fp_2d", "fn_2d") if gt_2d else ())
    per_frame: dict[str, list[int]] = {k: [] for k in counts}
    frames = iter(stage.frames)
    while True:
        start = time.perf_counter()
        frame = next(frames, None)
        timer.add("detect", start)
        if frame is None:
            break
        start = time.perf_counter()
        tracks = checked_tracks(tracker(frame.detections), f"case {case.name}: tracker")
        timer.add("track", start)
        b = tracks.boxes
        n = len(b)
        velocity = b.velocity if b.velocity is not None else np.zeros((n, 3))
        for name, values in zip(_TRACK_COLUMNS, (
                [scene] * n, [frame.frame_index] * n, b.ids, b.classes, b.center[:, 0], b.center[:, 1], b.center[:, 2],
                b.size_lwh[:, 0], b.size_lwh[:, 1], b.size_lwh[:, 2], b.yaw(), velocity[:, 0], velocity[:, 1]), strict=True):
            track_rows[name].extend(np.asarray(values).tolist())
        in_range.append(frame.sensors_in_range)
        received.append(frame.collaborative_detections)
        start = time.perf_counter()
        if n:
            pred_parts.append(_predictions(scene, frame.frame_index, tracks, horizon, step_s, gt_eval,
                                           evaluation.match_distance_m, predict))
        timer.add("predict", start)
        start = time.perf_counter()
        tp, fp, fn = _detection_counts(frame.detections, *gt_frames.get(frame.frame_index, (_NO_XYZ, _NO_XYZ)),
                                       evaluation.match_distance_m)
        counted: tuple[int, ...] = (frame.frame_index, len(frame.detections), n, tp, fp, fn)
        if gt_2d is not None:
            box2d = frame.detections.extras.get("box2d_px", _NO_XYXY)
            counted += frame_counts_2d(box2d[np.all(np.isfinite(box2d), axis=1)],
                                      *gt_2d.get(frame.frame_index, (_NO_XYXY, _NO_XYXY)))
        for key, value in zip(per_frame, counted, strict=True):
            per_frame[key].append(int(value))
        timer.add("evaluate", start)
    start = time.perf_counter()
    tracks_table = pa.table({c: pa.array(v, pa.string() if c in ("scene", "object_id", "class") else
                                         (pa.int64() if c == "frame_index" else pa.float64()))
                             for c, v in track_rows.items()})
    metrics: dict[str, float] = {}
    collaborative = case.comm_range_m is not None
    metrics["sensors_in_range"] = float(np.mean(in_range)) if collaborative else math.nan
    metrics["collaborative_detections"] = float(np.mean(received)) if collaborative else math.nan
    metrics.update(_precision_recall(per_frame, ""))
    metrics.update(_precision_recall(per_frame, "_2d"))
    metrics.update(_tracking_metrics(gt_all, gt_eval, tracks_table))
    metrics.update(_prediction_metrics(gt_all, pred_parts))
    frames_table = ds.frames().filter(pc.equal(ds.frames()["scene"], scene))
    safety = evaluate_safety(frames_table, gt_all, tracks_table, exclude_ids=frozenset(stage.own_object_ids))
    metrics["rss_violating_frame_fraction"] = float(safety.as_dict()["violating_frame_fraction"])
    metrics["rss_missed_violations"] = float(safety.missed_violations)
    metrics["rss_invented_violations"] = float(safety.invented_violations)
    timer.add("evaluate", start)
    return RunResult(metrics, per_frame, timer.seconds)


def _precision_recall(per_frame: dict[str, list[int]], suffix: str) -> dict[str, float]:
    """Precision and recall of the counts ``tp{suffix}``, ``fp{suffix}``, ``fn{suffix}`` (NaN where undefined)."""
    tp, fp, fn = (sum(per_frame.get(k + suffix, [])) for k in ("tp", "fp", "fn"))
    return {f"precision{suffix}": tp / (tp + fp) if tp + fp else math.nan,
            f"recall{suffix}": tp / (tp + fn) if tp + fn else math.nan}


_NO_XYZ = np.zeros((0, 3))
_NO_XYXY = np.zeros((0, 4))


def _frame_object_key(table: pa.Table) -> np.ndarray:
    """(N,) frame index and object id joined by the unit separator (0x1f): one key per (frame, object) row."""
    keys: np.ndarray = np.char.add(np.char.add(table["frame_index"].to_numpy().astype(str), "\x1f"),
                                   table["object_id"].to_numpy(zero_copy_only=False).astype(str))
    return keys


def _by_frame(gt_all: pa.Table, gt_eval: pa.Table) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per frame: (evaluated centres (M, 3), other ground-truth centres (K, 3)) in world, metres."""
    def centres(table: pa.Table) -> tuple[np.ndarray, np.ndarray]:
        xyz = np.c_[table["x_world_m"].to_numpy(), table["y_world_m"].to_numpy(), table["z_world_m"].to_numpy()]
        return table["frame_index"].to_numpy().astype(np.int64), xyz.reshape(-1, 3)

    others = (gt_all.filter(pa.array(~np.isin(_frame_object_key(gt_all), _frame_object_key(gt_eval))))
              if len(gt_all) else gt_all)
    (f_eval, xyz_eval), (f_other, xyz_other) = centres(gt_eval), centres(others)
    return {int(f): (xyz_eval[f_eval == f], xyz_other[f_other == f]) for f in np.union1d(f_eval, f_other)}


def _detection_counts(detections: Any, evaluated: np.ndarray, others: np.ndarray,
                      match_distance_m: float) -> tuple[int, int, int]:
    """(TP, FP, FN) of one frame's detections in world against the evaluated ground truth.

    Detections are assigned (Hungarian on 3D centre distance, within ``match_distance_m``) to every ground
    truth; one matched to ground truth outside the evaluated set is neither a hit nor a false positive.
    """
    centres = detections.boxes.center
    gt = np.concatenate([evaluated, others])
    if not len(centres) or not len(gt):
        return 0, len(centres), len(evaluated)
    dist = np.linalg.norm(centres[:, None, :] - gt[None, :, :], axis=2)
    d_idx, g_idx = linear_sum_assignment(dist)
    ok = dist[d_idx, g_idx] <= match_distance_m
    d_idx, g_idx = d_idx[ok], g_idx[ok]
    tp = int(np.sum(g_idx < len(evaluated)))
    return tp, len(centres) - len(d_idx), len(evaluated) - tp


def _ground_truth(ds: DatasetReader, scene: str, own_object_ids: Sequence[str],
                  evaluation: EvaluationConfig) -> tuple[pa.Table, pa.Table]:
    """All objects of the scene but the agents' own, and those evaluated (near the ego, seen well enough).

    A scene without visibility labels has every object near the ego evaluated.
    """
    objects = ds.objects().filter(pc.equal(ds.objects()["scene"], scene))
    own = pa.array(sorted(own_object_ids), pa.string())
    objects = objects.filter(pc.invert(pc.is_in(objects["object_id"], own)))
    near = np.hypot(objects["x_ego_m"].to_numpy(zero_copy_only=False), objects["y_ego_m"].to_numpy(zero_copy_only=False))
    vis = ds.visibility().filter(pc.equal(ds.visibility()["scene"], scene))
    if len(vis) == 0:  # no visibility labels (Lyft, Argoverse 2): every object near the ego is evaluated
        return objects, objects.filter(pa.array(near <= evaluation.max_range_m))
    n_points = vis["n_points"].to_numpy(zero_copy_only=False)
    seen = (vis["in_fov"].to_numpy(zero_copy_only=False).astype(bool)
            & (n_points != 0)  # -1: unknown (camera labels, e.g. KITTI), in the field of view counts as seen
            & (vis["occlusion"].to_numpy(zero_copy_only=False) <= evaluation.max_occlusion))
    well_seen = np.isin(_frame_object_key(objects), _frame_object_key(vis)[seen])
    return objects, objects.filter(pa.array(well_seen & (near <= evaluation.max_range_m)))


def _ground_truth_2d(ds: DatasetReader, scene: str, camera: str, gt_all: pa.Table,
                     gt_eval: pa.Table) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per frame: (evaluated (M, 4), ignored (K, 4)) ground-truth pixel boxes ``x0, y0, x1, y1`` in ``camera``'s image.

    The boxes are the 3D boxes projected into the image (the camera detector's own definition, the same on every
    dataset); a scene without the camera's calibration (KITTI converted without images) has its labels' 2D boxes
    instead (on KITTI 0001 they agree with the projections: median IoU 0.98). Evaluated are the objects of the 3D
    evaluated set (near the ego, seen well enough); the others in the image are ignored.
    """
    view = CameraView(ds.scene(scene), camera)
    if view.calibrated:
        frames = ds.frames().filter(pc.equal(ds.frames()["scene"], scene))
        time_of = dict(zip(frames["frame_index"].to_pylist(), frames["timestamp_ns"].to_pylist(), strict=True))
        parts = []
        for f, boxes in boxes_by_frame(gt_all).items():
            box2d, in_image = view.boxes_2d(boxes, int(time_of[f]))
            ids = np.asarray(boxes.ids, dtype=str)[in_image]
            parts.append((np.full(len(ids), f, np.int64), np.char.add(f"{f}\x1f", ids), box2d[in_image]))
        frame, keys, xyxy = (np.concatenate([p[i] for p in parts]) if parts else empty
                             for i, empty in enumerate((np.zeros(0, np.int64), np.zeros(0, str), _NO_XYXY)))
    else:
        labels = label_boxes_2d(ds, scene, camera)
        if not len(labels):
            raise InputError(f"scene {scene!r}: camera {camera!r} has neither a calibration nor labelled 2D boxes to "
                             "score 2D detections against")
        frame = labels["frame_index"].to_numpy().astype(np.int64)
        keys = _frame_object_key(labels)
        xyxy = np.stack([labels[c].to_numpy(zero_copy_only=False).astype(np.float64)
                         for c in ("box2d_x0_px", "box2d_y0_px", "box2d_x1_px", "box2d_y1_px")], axis=1)
    evaluated = np.isin(keys, _frame_object_key(gt_eval))
    return {int(f): (xyxy[(frame == f) & evaluated], xyxy[(frame == f) & ~evaluated]) for f in np.unique(frame)}


def _agnostic(table: pa.Table) -> pa.Table:
    """The same rows with one class, so tracking is scored over all objects together, as the V2I study does."""
    return table.set_column(table.schema.get_field_index("class"), "class", pa.array(["object"] * len(table), pa.string()))


def _tracking_metrics(gt_all: pa.Table, gt_eval: pa.Table, tracks: pa.Table) -> dict[str, float]:
    # Ground truth outside the evaluated set is ignored, not missed: tracks matched to it are removed first
    # (tracking_sequences' visibility rule), as TrackEval removes tracks matched to distractors.
    evaluated = pa.table({"scene": gt_eval["scene"], "frame_index": gt_eval["frame_index"],
                          "object_id": gt_eval["object_id"], "in_fov": pa.array(np.ones(len(gt_eval), bool)),
                          "n_points": pa.array(np.ones(len(gt_eval), np.int64)),
                          "visible_fraction": pa.array(np.ones(len(gt_eval)))})
    sequences = tracking_sequences(_agnostic(gt_all), evaluated if len(evaluated) else _no_visibility(gt_all),
                                   _agnostic(tracks), ["object"], Similarity.EUCLIDEAN)["object"]
    result = evaluate_tracking(sequences, (TrackingMetric.HOTA, TrackingMetric.CLEAR, TrackingMetric.IDENTITY))
    flat = summary(result["COMBINED_SEQ"])
    return {name: float(flat[name]) for name in ("HOTA", "DetA", "AssA", "MOTA", "MOTP", "IDF1")}


def _no_visibility(objects: pa.Table) -> pa.Table:
    """A visibility table in which no object is seen (every ground truth is ignored)."""
    n = len(objects)
    return pa.table({"scene": objects["scene"], "frame_index": objects["frame_index"], "object_id": objects["object_id"],
                     "in_fov": pa.array(np.zeros(n, bool)), "n_points": pa.array(np.zeros(n, np.int64)),
                     "visible_fraction": pa.array(np.zeros(n))})


def _predictions(scene: str, frame: int, tracks: Any, horizon: int, step_s: float, gt_eval: pa.Table,
                 match_distance_m: float, predict: Predictor) -> dict[str, np.ndarray]:
    """Predictions of the tracks matched to evaluated ground truth, keyed by the matched object."""
    rows = gt_eval.filter(pc.equal(gt_eval["frame_index"], frame))
    empty = {k: np.zeros(0) for k in ("object_id", "step", "x", "y")}
    if len(rows) == 0:
        return {"frame": np.zeros(0, np.int64), **empty}
    gt_xy = np.c_[rows["x_world_m"].to_numpy(), rows["y_world_m"].to_numpy()]
    dist = np.linalg.norm(tracks.boxes.center[:, None, :2] - gt_xy[None, :, :], axis=2)
    t_idx, g_idx = linear_sum_assignment(dist)
    ok = dist[t_idx, g_idx] <= match_distance_m
    t_idx, g_idx = t_idx[ok], g_idx[ok]
    predicted = predict(tracks, horizon, step_s)
    try:
        future = np.asarray(predicted, dtype=np.float64)
    except (TypeError, ValueError):  # a string or ragged lists: a ValueError traceback
        raise InputError(f"predictor: expected an array of numbers, got {shown(predicted)}") from None
    if future.shape != (len(tracks.boxes), horizon, 2):
        raise InputError(f"predictor: expected an array of shape {(len(tracks.boxes), horizon, 2)}, got {future.shape}")
    if not np.all(np.isfinite(future)):  # NaN positions made ADE/FDE NaN, stored as null: "N/A" without a word
        raise InputError(f"predictor: expected finite positions, got {int(np.sum(~np.isfinite(future)))} non-finite")
    future = future[t_idx]  # (M, T, 2)
    ids = rows["object_id"].to_numpy(zero_copy_only=False).astype(str)[g_idx]
    m = len(t_idx)
    return {"frame": np.full(m * horizon, frame, np.int64), "object_id": np.repeat(ids, horizon),
            "step": np.tile(np.arange(1, horizon + 1), m), "x": future[:, :, 0].reshape(-1), "y": future[:, :, 1].reshape(-1),
            "scene": np.full(m * horizon, scene)}


def _prediction_metrics(gt_all: pa.Table, parts: list[dict[str, np.ndarray]]) -> dict[str, float]:
    parts = [p for p in parts if len(p["frame"])]
    if not parts:
        return {"ADE": math.nan, "FDE": math.nan}
    cat = {k: np.concatenate([p[k] for p in parts]) for k in ("scene", "frame", "object_id", "step", "x", "y")}
    n = len(cat["frame"])
    predictions = pa.table({"scene": pa.array(cat["scene"].astype(str)), "frame_index": pa.array(cat["frame"]),
                            "object_id": pa.array(cat["object_id"].astype(str)), "mode": pa.array(np.zeros(n, np.int64)),
                            "probability": pa.array(np.ones(n)), "step": pa.array(cat["step"].astype(np.int64)),
                            "x_world_m": pa.array(cat["x"]), "y_world_m": pa.array(cat["y"])})
    try:
        result = prediction_metrics(gt_all, predictions, PredictionConfig(ks=(1,)))
    except InputError:  # no predicted step has ground truth (the scene ended): nothing to score
        return {"ADE": math.nan, "FDE": math.nan}
    return {"ADE": float(result["ADE"]), "FDE": float(result["FDE"])}


# --------------------------------------------------------------------------- the study


#: The stamp of a generated trial, written last: the fingerprint of the generator settings it was generated with.
TRIAL_STAMP = ".study-fingerprint"


def trial_dataset(out: Path | Location, trial: int) -> Path | Location:
    """The folder of trial ``trial``'s generated dataset (a prefix when OUT is in an object store)."""
    return out / "trials" / f"trial-{trial}"


def _identity(path: Path | Location) -> list[int]:
    """[size, modification time in ns] of a file or object (an object's last-modified time)."""
    if isinstance(path, Location):
        info = path.info()
        return [info.size, info.mtime_ns]
    stat = path.stat()
    return [stat.st_size, stat.st_mtime_ns]


def _trial_source(study: StudyConfig, out: OutputFolder, trial: int) -> tuple[str, Path | Location, str, dict[str, Any]]:
    """The dataset name, folder, scene and fingerprint input of ``trial``: generated, or a scene of existing data."""
    sources = study.sources()
    if sources is not None:
        name, path, scene = sources[trial]
        root = dataset_root(path)
        return name, root, scene, {"dataset": str(root), "scene": scene, "scene_stat": _identity(scene_path(root, scene))}
    return "generated", trial_dataset(out.root, trial), "", {"generator": study.scenario(trial)}


def _generate_trial(args: tuple[StudyConfig, OutputFolder, int]) -> str:
    """Generates a trial's dataset in place, then its stamp, last.

    :func:`~avdata.generators.driver.generate_scenes` resumes scene by scene, on a disk or in a store; a trial is done
    when its stamp matches, and a trial whose stamp does not is redone (only the scenes that differ).
    """
    study, out, trial = args
    if study.sources() is not None:
        return "given"
    from avdata.generators.config import scenario_from_dict
    from avdata.generators.driver import generate_scenes

    trial_folder = OutputFolder.of(trial_dataset(out.root, trial))
    fingerprint = study.fingerprint({"generator": study.scenario(trial)}).encode()
    if trial_folder.read_bytes(TRIAL_STAMP) == fingerprint:
        return "kept"
    trial_folder.remove([TRIAL_STAMP])  # a trial being redone is not done until its new stamp is written
    config = scenario_from_dict(study.scenario(trial), f"study {study.name}, trial {trial}")
    result = generate_scenes(config, trial_folder.root, quiet=True)
    if result.failed:
        raise AvdataError(str(result.problems[0]))
    trial_folder.write(TRIAL_STAMP, fingerprint)
    return "generated"


def _run_name(case: CaseConfig, trial: int) -> str:
    return f"{checked_name(case.name, 'study case name')}__trial-{trial}"


def _component_stats(case: CaseConfig) -> dict[str, Any]:
    """Size and modification time of the files a case reads (a retrained checkpoint or new detections redo it)."""
    stats: dict[str, Any] = {}
    for key in ("path", "checkpoint"):
        value = getattr(case.detector, key)
        if value is not None:
            path = Path(value)
            if not path.exists():
                raise InputError(f"case {case.name}: detector.{key}: no such file or folder {value!r}")
            stats[key] = _identity(path) if path.is_file() else sorted((str(p.relative_to(path)), *_identity(p))
                                                                    for p in path.rglob("*") if p.is_file())
    return stats


def result_checksum(record: dict[str, Any]) -> str:
    """The checksum of a run result: SHA-256 of its canonical JSON without the ``checksum`` field."""
    body = {k: v for k, v in record.items() if k != "checksum"}
    return hashlib.sha256(json.dumps(body, sort_keys=True, allow_nan=False).encode()).hexdigest()


def _finite_or_none(value: float) -> float | None:
    """A metric as stored: None where it does not apply (NaN), so a NaN in a result is always damage."""
    return float(value) if math.isfinite(value) else None


#: The columns of ``results.parquet`` in order (any other key of a result after them, by name).
_COLUMNS = ("case", "trial", "dataset", "scene", "seed", "fingerprint", "detector", "tracker", "predictor",
            *(f"axis_{k}" for k in CASE_AXES), *METRICS, "checksum")


def _in_column_order(result: dict[str, Any]) -> dict[str, Any]:
    """The result with its keys in :data:`_COLUMNS` order, kept or redone alike.

    A kept result is read back from its JSON (keys sorted), a redone one is built in code order, and the table's
    columns follow its first row: without one order a resumed study's ``results.parquet`` had other bytes.
    """
    rank = {name: i for i, name in enumerate(_COLUMNS)}
    return dict(sorted(result.items(), key=lambda item: (rank.get(item[0], len(rank)), item[0])))


def _evaluate_run(args: tuple[StudyConfig, OutputFolder, CaseConfig, int]) -> dict[str, Any]:
    study, out, case, trial = args
    name = f"runs/{_run_name(case, trial)}.json"
    path = f"{out}/{name}"
    dataset, root, scene, source = _trial_source(study, out, trial)
    fingerprint = study.fingerprint(source, case, study.evaluation, trial, _component_stats(case))
    found = out.read_bytes(name)
    if found is not None:
        try:
            stored = json.loads(found)
        except (json.JSONDecodeError, UnicodeDecodeError):
            stored = {}
        result = stored.get("result") if isinstance(stored, dict) else None
        if isinstance(result, dict) and result.get("fingerprint") == fingerprint:
            if result.get("checksum") == result_checksum(result):
                return _in_column_order(result)
            # An edited result is redone, not trusted: its inputs match but its numbers are not what was run.
            print(f"{path}: checksum does not match the result (edited?); redoing it", file=sys.stderr)
    scene = scene or DatasetReader(root).scenes[0]
    run = run_pipeline(root, scene, case, study.evaluation, ego=study.ego, seed=study.seed + trial)
    record: dict[str, Any] = {
        "case": case.name, "trial": trial, "dataset": dataset, "scene": scene, "seed": study.seed + trial,
        "fingerprint": fingerprint,
        "detector": case.detector.label(), "tracker": case.tracker, "predictor": case.predictor,
        **{f"axis_{k}": getattr(case, k) for k in CASE_AXES},
        **{k: _finite_or_none(v) for k, v in run.metrics.items()}}
    record["checksum"] = result_checksum(record)
    stored = {"result": record, "frames": run.frames, "seconds": {k: round(v, 3) for k, v in run.seconds.items()}}
    out.write(name, json.dumps(stored, sort_keys=True, allow_nan=False).encode())
    return _in_column_order(record)


def _map(engine: Executor, fn: Callable[[Any], Any], tasks: Sequence[Any], what: Sequence[str], desc: str,
         unit: str, progress: bool) -> list[Any]:
    with Progress(len(tasks), desc, unit, quiet=not progress) as shown:
        results = engine.map(fn, tasks, on_done=lambda i, _r: shown.update(what[i]))
    for name, result in zip(what, results, strict=True):
        if isinstance(result, TaskFailure):
            raise AvdataError(f"study task {name}: {result.message}")
    return results


def run_study(study: StudyConfig, out: str | Path | Location, *, executor: str = "local", workers: int = 1,
              ray_address: str | None = None, progress: bool = True) -> pa.Table:
    """Runs every trial and case of ``study`` into ``out``; returns the results table (also ``out/results.parquet``).

    One task per trial generation, then one per (case, trial), on the executor (the same numbers on any
    executor and any number of workers: every random draw is seeded by the trial, scene, frame and sensor).

    Args:
        study: the study.
        out: the output folder (created; reused on a rerun: finished work whose inputs match is kept), or its
            prefix in an object store (``s3://...``, ``gs://...``).
        executor: "local" (``workers`` processes) or "ray" (``ray_address``, or a local Ray instance).
        workers: processes of the local executor.
        ray_address: the Ray cluster to join.
        progress: show progress on stderr: a bar on a terminal, else one line per finished trial and run.
    """
    with folder_lock(out) as folder, make_executor(executor, workers=workers, ray_address=ray_address) as engine:
        sources = study.sources()
        folders = [folder.root, *sorted({dataset_root(path) for _, path, _ in sources or []}, key=str)]
        engine.check_visible([p for p in folders if isinstance(p, Path)])  # those in a store are reached by URI
        folder.remove_temporary()
        folder.write("study.yaml", yaml.safe_dump(json.loads(json.dumps(asdict(study), default=list)),
                                                  sort_keys=False).encode())
        trials = list(range(study.trials))
        states = _map(engine, _generate_trial, [(study, folder, t) for t in trials], [f"trial {t}" for t in trials],
                      f"study {study.name}: trials", "trial", progress)
        if progress and sources is None:
            print(f"study {study.name}: {states.count('generated')} trials generated, {states.count('kept')} kept")
        runs = [(c, t) for c in study.cases for t in trials
                if not c.datasets or (sources is not None and sources[t][0] in c.datasets)]
        records = _map(engine, _evaluate_run, [(study, folder, c, t) for c, t in runs],
                       [_run_name(c, t) for c, t in runs], f"study {study.name}: runs", "run", progress)
        if progress:
            print(f"study {study.name}: {len(records)} runs ({len(study.cases)} cases, {study.trials} trials)")
        table = pa.Table.from_pylist(records)
        parquet = pa.BufferOutputStream()  # through the one atomic writer: a full disk is one line, no partial file
        pq.write_table(table, parquet)
        folder.write("results.parquet", parquet.getvalue().to_pybytes())  # last: after every trial and run
    return table
