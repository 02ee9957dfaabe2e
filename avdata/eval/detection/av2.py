"""Argoverse 2 3D detection metrics (AP, ATE, ASE, AOE, CDS), equal to av2-api 0.3.6's ``evaluate``.

av2's ``av2.evaluation.detection.eval.evaluate`` step by step, and where each lives here:

1. Rows are grouped per sweep *and* category: (log_id, timestamp_ns, category) (:func:`_groups`).
2. Per group (``accumulate``), detections are ranked by score (``np.argsort(-score)``, as av2), then
   filtered: inside the region of interest (any of the 8 cuboid vertices, moved to the city frame
   with the sweep's ego pose, falls on an ROI cell of the map raster; ``avdata.sources.argoverse2.roi``),
   centre within ``max_range_m`` of the ego origin (3D norm, egovehicle frame), and at most
   ``max_num_dts_per_category`` detections per group; ground truth needs ``num_interior_pts > 0``.
3. Assignment (``assign``): each detection takes its nearest ground truth (3D centre distance);
   the first (best-scored) detection that takes a ground truth is its match, at every threshold
   whose distance it is under; later ones are false positives. Not Hungarian, not class-agnostic.
4. True-positive errors at ``tp_threshold_m``: ATE = centre distance, ASE = 1 - IoU of the sizes
   aligned at a common centre and heading, AOE = |yaw difference| wrapped into [0, pi] (yaw = the z
   angle of the extrinsic ``xyz`` Euler decomposition).
5. Summary per category: detections that passed the filters, ranked by score (stable), give the
   VOC-style AP at each threshold (precision made monotone, sampled at 101 recalls, 0 beyond the
   last recall); AP = mean over thresholds; TP errors are the means over the true positives at the
   middle threshold (the upper bounds 2 m, 1, pi when none); CDS = AP * mean(1 - ATE/2, 1 - ASE,
   1 - AOE/pi). A category without evaluated ground truth keeps (0, 2, 1, pi, 0).
6. ``AVERAGE_METRICS`` = the mean of every category row, including categories without ground truth.

av2 rounds its table to 3 decimals; :class:`Av2DetectionResult` keeps full precision (``rounded()``
gives av2's table). Ties in score rank as av2's sorts rank them (the same numpy calls on rows in
the same order: sorted by log, time, category, input order kept within a group).

Input tables are av2's own: ground truth = every ``<log>/annotations.feather`` of a split folder
(with ``log_id`` added), detections = one feather/parquet file with ``log_id, timestamp_ns,
category, tx_m, ty_m, tz_m, length_m, width_m, height_m, qw, qx, qy, qz, score`` (egovehicle frame).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
from scipy.spatial.distance import cdist

from avdata.errors import InputError
from avdata.eval.problems import check_ground_truth, warn
from avdata.frames.rotations import euler_from_matrix, matrix_from_quat_wxyz
from avdata.inputs import is_present, refuse_special_file
from avdata.schema.limits import MAX_BOX_SIZE_M, MAX_COORDINATE_M
from avdata.sources import argoverse2 as av2

#: The cuboid parameter columns, in av2's ``ORDERED_CUBOID_COL_NAMES`` order.
CUBOID_COLUMNS: tuple[str, ...] = ("tx_m", "ty_m", "tz_m", "length_m", "width_m", "height_m", "qw", "qx", "qy", "qz")
#: av2 ``MetricNames``, the columns of the summary.
METRICS: tuple[str, ...] = ("AP", "ATE", "ASE", "AOE", "CDS")
#: The name of the mean row (av2's).
AVERAGE = "AVERAGE_METRICS"
#: av2 ``utils.constants.EPS``, added to precision's denominator.
_EPS = sys.float_info.epsilon
#: av2 ``NUM_DECIMALS``: what av2's own table is rounded to.
AV2_DECIMALS = 3

_UNIT_VERTICES = np.array(
    [[1, 1, 1], [1, -1, 1], [1, -1, -1], [1, 1, -1], [-1, 1, 1], [-1, -1, 1], [-1, -1, -1], [-1, 1, -1]], dtype=np.float64
)


@dataclass(frozen=True, slots=True, kw_only=True)
class Av2DetectionConfig:
    """av2 ``DetectionCfg`` defaults (the sensor competition).

    Attributes:
        affinity_thresholds_m: centre-distance thresholds of a true positive.
        categories: the evaluated categories (rows of the summary).
        eval_only_roi_instances: keep only cuboids touching the map's region of interest.
        max_num_dts_per_category: detections kept per sweep and category (best scores first).
        max_range_m: centre distance from the ego origin beyond which cuboids are not evaluated.
        num_recall_samples: recall points of the AP integral.
        tp_threshold_m: the threshold whose true positives give ATE, ASE, AOE.
    """

    affinity_thresholds_m: tuple[float, ...] = (0.5, 1.0, 2.0, 4.0)
    categories: tuple[str, ...] = av2.COMPETITION_CATEGORIES
    eval_only_roi_instances: bool = True
    max_num_dts_per_category: int = 100
    max_range_m: float = 150.0
    num_recall_samples: int = 101
    tp_threshold_m: float = 2.0

    @property
    def tp_normalization_terms(self) -> tuple[float, float, float]:
        """(ATE, ASE, AOE) upper bounds: tp_threshold_m, 1, pi."""
        return (self.tp_threshold_m, 1.0, math.pi)


@dataclass(frozen=True, slots=True, kw_only=True)
class CuboidTable:
    """N cuboids of one or more logs, in the egovehicle frame of their sweep.

    Attributes:
        log_id: (N,) log ids.
        timestamp_ns: (N,) sweep times.
        category: (N,) AV2 categories.
        params: (N, 10) tx_m, ty_m, tz_m, length_m, width_m, height_m, qw, qx, qy, qz.
        last: (N,) score (detections) or num_interior_pts (ground truth).
    """

    log_id: np.ndarray
    timestamp_ns: np.ndarray
    category: np.ndarray
    params: np.ndarray
    last: np.ndarray

    def __len__(self) -> int:
        """Number of rows."""
        return len(self.log_id)


@dataclass(frozen=True, slots=True, kw_only=True)
class Av2DetectionResult:
    """The summary table and the per-row outcome av2 adds to its inputs.

    Attributes:
        metrics: category (and ``AVERAGE_METRICS``) -> {AP, ATE, ASE, AOE, CDS}, full precision.
        dts_outcome: (N, T + 4) per detection, in input order: is a true positive at each
            threshold (0/1), ATE, ASE, AOE, is_evaluated (av2's added columns).
        gts_outcome: (M, T + 4) the same for the ground truth.
    """

    metrics: dict[str, dict[str, float]]
    dts_outcome: np.ndarray = field(repr=False)
    gts_outcome: np.ndarray = field(repr=False)

    def rounded(self) -> dict[str, dict[str, float]]:
        """The table as av2 prints it (rounded to 3 decimals, half to even as pandas rounds)."""
        return {c: {m: float(np.round(v, AV2_DECIMALS)) for m, v in row.items()} for c, row in self.metrics.items()}


def read_detections(path: Path) -> CuboidTable:
    """An av2 detection file (feather or parquet) with log_id, timestamp_ns, category, the 10 cuboid columns, score."""
    return _cuboid_table(_read_table(path), path, "score")


def read_ground_truth(split_dir: Path, log_ids: list[str] | None = None) -> CuboidTable:
    """Every ``<log>/annotations.feather`` of a split folder (or of ``log_ids``), with ``log_id`` added."""
    split_dir = Path(split_dir)
    # is_present, not is_file: a log whose annotations are a folder, FIFO or broken link is damage to name, not
    # a log without annotations (a test log) to pass over.
    logs = log_ids if log_ids is not None else sorted(
        p.name for p in split_dir.iterdir() if is_present(p / "annotations.feather")
    ) if split_dir.is_dir() else []
    if not logs:
        raise InputError(f"{split_dir}: expected log folders holding annotations.feather, got none")
    tables = []
    for log in logs:
        path = split_dir / log / "annotations.feather"
        rows = av2.read_annotations(path)
        if rows.dropped:  # ground truth is scored as given or not at all, like av2's own loader
            raise InputError(f"{path}: {rows.dropped[0]}")
        columns = rows.columns
        n = len(columns["timestamp_ns"])
        tables.append(CuboidTable(
            log_id=np.full(n, log, dtype=object).astype(str),
            timestamp_ns=columns["timestamp_ns"],
            category=columns["category"],
            params=np.stack([columns[c] for c in CUBOID_COLUMNS], axis=1),
            last=columns["num_interior_pts"].astype(np.float64),
        ))
    return CuboidTable(**{name: np.concatenate([getattr(t, name) for t in tables]) for name in
                          ("log_id", "timestamp_ns", "category", "params", "last")})


def evaluate_av2_detection(
    dts: CuboidTable,
    gts: CuboidTable,
    config: Av2DetectionConfig | None = None,
    split_dir: Path | None = None,
    *,
    source: str | Path = "detections",
) -> Av2DetectionResult:
    """av2's ``evaluate(dts, gts, cfg)`` (see the module docstring).

    Args:
        dts: N detections.
        gts: M ground-truth cuboids.
        config: the evaluation settings (av2's defaults when None).
        split_dir: the split folder with each log's ``map/`` and ``city_SE3_egovehicle.feather``
            (needed when ``config.eval_only_roi_instances``).
        source: the detection file, named by the messages about its rows.
    """
    config = config or Av2DetectionConfig()
    if config.eval_only_roi_instances and split_dir is None:
        raise InputError("expected the split folder (maps and ego poses) for ROI filtering, got none")
    gt_logs = set(gts.log_id.tolist())
    unknown = sorted(set(dts.log_id.tolist()) - gt_logs)
    if unknown:
        raise InputError(f"{source}: log_id: expected detections of the ground-truth logs, got logs {unknown[:3]} "
                         f"without ground truth")
    sweeps = np.char.add(np.char.add(gts.log_id.astype(str), "\x1f"), gts.timestamp_ns.astype(str))
    dt_sweeps = np.char.add(np.char.add(dts.log_id.astype(str), "\x1f"), dts.timestamp_ns.astype(str))
    stray = np.flatnonzero(~np.isin(dt_sweeps, sweeps))
    if len(stray):
        # av2 would score them as false positives of a sweep nobody annotated: a wrong clock or log, not a result.
        raise InputError(f"{source}: row {int(stray[0])}: expected detections at annotated sweeps of the ground truth (the "
                         f"timestamps of {dts.log_id[stray[0]]}/annotations.feather), got timestamp_ns "
                         f"{int(dts.timestamp_ns[stray[0]])} ({len(stray)} such row(s))")
    evaluated = set(config.categories)
    names, counts = np.unique(dts.category.astype(str), return_counts=True)
    for name, count in zip(names.tolist(), counts.tolist(), strict=True):
        if name not in evaluated:
            warn(f"{source}: category: {count} row(s) of category {name!r}, which is not one of the evaluated "
                 f"categories; they are not evaluated")
    check_ground_truth("ground truth", config.categories,
                       sorted(set(config.categories) - set(gts.category.astype(str).tolist())),
                       f"their AP is 0 and counts in {AVERAGE}")
    dts_in_roi = np.ones(len(dts), dtype=bool)
    gts_in_roi = np.ones(len(gts), dtype=bool)
    if config.eval_only_roi_instances and split_dir is not None:
        for log in sorted(gt_logs):
            roi = av2.log_roi(Path(split_dir) / log)
            pose_rows = av2.read_poses(Path(split_dir) / log / "city_SE3_egovehicle.feather")
            if pose_rows.dropped:
                raise InputError(f"{Path(split_dir) / log / 'city_SE3_egovehicle.feather'}: {pose_rows.dropped[0]}")
            poses = pose_rows.columns
            for table, in_roi in ((dts, dts_in_roi), (gts, gts_in_roi)):
                rows = np.flatnonzero(table.log_id == log)
                in_roi[rows] = _in_roi(table.params[rows], table.timestamp_ns[rows], poses, roi,
                                       Path(split_dir) / log / "city_SE3_egovehicle.feather")
    # Yaw is a function of each row's quaternion alone: computed once for every row, not per group.
    dts_yaw, gts_yaw = _yaw(dts.params[:, 6:10]), _yaw(gts.params[:, 6:10])
    n_thresholds = len(config.affinity_thresholds_m)
    dts_outcome = np.zeros((len(dts), n_thresholds + 4))
    gts_outcome = np.zeros((len(gts), n_thresholds + 4))
    dt_groups, gt_groups = _groups(dts), _groups(gts)
    for key in sorted(dt_groups.keys() | gt_groups.keys()):
        dt_rows = dt_groups.get(key, np.zeros(0, dtype=np.int64))
        gt_rows = gt_groups.get(key, np.zeros(0, dtype=np.int64))
        dts_outcome[dt_rows], gts_outcome[gt_rows] = _accumulate(
            _Rows(cuboids=np.column_stack([dts.params[dt_rows], dts.last[dt_rows]]), in_roi=dts_in_roi[dt_rows],
                  yaw_rad=dts_yaw[dt_rows]),
            _Rows(cuboids=np.column_stack([gts.params[gt_rows], gts.last[gt_rows]]), in_roi=gts_in_roi[gt_rows],
                  yaw_rad=gts_yaw[gt_rows]),
            config,
        )
    metrics = _summarize(dts, gts, dts_outcome, gts_outcome, config)
    return Av2DetectionResult(metrics=metrics, dts_outcome=dts_outcome, gts_outcome=gts_outcome)


def _groups(table: CuboidTable) -> dict[tuple[str, int, str], np.ndarray]:
    """(log, time, category) -> row indices in input order."""
    order = np.lexsort((table.category, table.timestamp_ns, table.log_id))
    keys = list(zip(table.log_id[order].tolist(), table.timestamp_ns[order].tolist(), table.category[order].tolist(),
                    strict=True))
    groups: dict[tuple[str, int, str], list[int]] = {}
    for key, row in zip(keys, order.tolist(), strict=True):
        groups.setdefault(key, []).append(row)
    return {key: np.asarray(rows, dtype=np.int64) for key, rows in groups.items()}


@dataclass(frozen=True, slots=True, kw_only=True)
class _Rows:
    """The rows of one sweep and category.

    (K, 11) cuboid parameters + score / num_interior_pts, whether each touches the ROI (all True without ROI
    filtering), and each yaw (rad).
    """

    cuboids: np.ndarray
    in_roi: np.ndarray
    yaw_rad: np.ndarray

    def take(self, index: np.ndarray) -> _Rows:
        return _Rows(cuboids=self.cuboids[index], in_roi=self.in_roi[index], yaw_rad=self.yaw_rad[index])


def _accumulate(dts: _Rows, gts: _Rows, config: Av2DetectionConfig) -> tuple[np.ndarray, np.ndarray]:
    """av2 ``accumulate`` for one sweep and category: (N, T+4) and (M, T+4) outcomes, input order."""
    n_thresholds = len(config.affinity_thresholds_m)
    permutation = np.argsort(-dts.cuboids[:, -1])
    dts = dts.take(permutation)
    evaluated_dts = dts.in_roi.copy()
    evaluated_gts = gts.in_roi.copy()
    if len(dts.cuboids):
        in_range = np.linalg.norm(dts.cuboids[:, :3], axis=1) < config.max_range_m
        over = np.flatnonzero(np.cumsum(in_range) > config.max_num_dts_per_category)
        if len(over):
            in_range[over[0]:] = False
        evaluated_dts &= in_range
    if len(gts.cuboids):
        evaluated_gts &= (np.linalg.norm(gts.cuboids[:, :3], axis=1) < config.max_range_m) & (
            gts.cuboids[:, -1].astype(int) > 0)
    dts_out = np.zeros((len(dts.cuboids), n_thresholds + 4))
    gts_out = np.zeros((len(gts.cuboids), n_thresholds + 4))
    dts_out[evaluated_dts, -1] = 1.0
    gts_out[evaluated_gts, -1] = 1.0
    if evaluated_dts.any() and evaluated_gts.any():
        dts_out[evaluated_dts, :-1], gts_out[evaluated_gts, :-1] = _assign(
            dts.take(evaluated_dts), gts.take(evaluated_gts), config)
    inverse = np.empty_like(permutation)
    inverse[permutation] = np.arange(len(permutation))
    return dts_out[inverse], gts_out


def _in_roi(
    cuboids: np.ndarray, timestamp_ns: np.ndarray, poses: dict[str, np.ndarray], roi: av2.RoiRaster, poses_path: Path
) -> np.ndarray:
    """(N,) whether any vertex of each (N, 10+) egovehicle cuboid lies in the ROI (av2 ``compute_objects_in_roi_mask``).

    Each cuboid is moved to the city frame with the ego pose at its own timestamp, which must be a
    pose row (av2 looks the pose up by exact time).
    """
    if not len(cuboids):
        return np.zeros(0, dtype=bool)
    pose_times = poses["timestamp_ns"]
    index = np.minimum(np.searchsorted(pose_times, timestamp_ns), len(pose_times) - 1)
    missing = np.flatnonzero(pose_times[index] != timestamp_ns)
    if len(missing):
        raise InputError(f"{poses_path}: expected an ego pose at timestamp_ns {int(timestamp_ns[missing[0]])} "
                         "(a sweep with cuboids), got none")
    rotation_ce = matrix_from_quat_wxyz(poses["quat_wxyz"][index])
    translation_ce = poses["translation_m"][index]
    rotation_eo = matrix_from_quat_wxyz(cuboids[:, 6:10])
    # city_SE3_object = city_SE3_ego.compose(ego_SE3_object), then vertices = local @ R.T + t (av2 order).
    rotation_co = rotation_ce @ rotation_eo
    translation_co = np.einsum("nij,nj->ni", rotation_ce, cuboids[:, :3]) + translation_ce
    local = _UNIT_VERTICES[None] * (cuboids[:, None, 3:6] / 2.0)
    vertices = np.einsum("nkj,nij->nki", local, rotation_co) + translation_co[:, None, :]
    return np.asarray(roi.contains(vertices.reshape(-1, 3)).reshape(-1, 8).any(axis=1), dtype=bool)


def _assign(dts: _Rows, gts: _Rows, config: Av2DetectionConfig) -> tuple[np.ndarray, np.ndarray]:
    """av2 ``assign``: (N, T+3) and (M, T+3) true-positive flags and TP errors of score-ranked detections."""
    affinity = -cdist(dts.cuboids[:, :3], gts.cuboids[:, :3])
    nearest_gt = affinity.argmax(axis=1)
    best = affinity[np.arange(len(dts.cuboids)), nearest_gt]
    matched_gts, first_dts = np.unique(nearest_gt, return_index=True)
    n_thresholds = len(config.affinity_thresholds_m)
    defaults = config.tp_normalization_terms
    dts_out = np.zeros((len(dts.cuboids), n_thresholds + 3))
    dts_out[:, n_thresholds:] = defaults
    gts_out = np.zeros((len(gts.cuboids), n_thresholds + 3))
    gts_out[:, n_thresholds:] = defaults
    for i, threshold_m in enumerate(config.affinity_thresholds_m):
        is_tp = best[first_dts] > -threshold_m
        dts_out[first_dts[is_tp], i] = 1.0
        gts_out[matched_gts, i] = 1.0
        if threshold_m != config.tp_threshold_m or not is_tp.any():
            continue
        tp_dts, tp_gts = first_dts[is_tp], matched_gts[is_tp]
        a, b = dts.cuboids[tp_dts], gts.cuboids[tp_gts]
        translation = np.linalg.norm(a[:, :3] - b[:, :3], axis=1)
        scale = 1.0 - np.minimum(a[:, 3:6], b[:, 3:6]).prod(axis=1) / np.maximum(a[:, 3:6], b[:, 3:6]).prod(axis=1)
        orientation = _wrap_angles(dts.yaw_rad[tp_dts] - gts.yaw_rad[tp_gts])
        dts_out[tp_dts, n_thresholds:] = np.stack([translation, scale, orientation], axis=-1)
    return dts_out, gts_out


def _yaw(quat_wxyz: np.ndarray) -> np.ndarray:
    """(N,) the z angle of the extrinsic xyz Euler angles (av2 ``mat_to_xyz(quat_to_mat(q))[..., 2]``)."""
    if not len(quat_wxyz):
        return np.zeros(0)
    return euler_from_matrix(matrix_from_quat_wxyz(quat_wxyz), "xyz")[:, 2]


def _wrap_angles(angles: np.ndarray, period: float = math.pi) -> np.ndarray:
    """av2 ``wrap_angles``: |angle| folded into [0, period] (the smaller of the two headings' differences)."""
    angles = np.abs(angles)
    divs, mods = np.divmod(angles, period)
    over = np.nonzero(divs)
    angles[over] = period - mods[over]
    return angles


def _average_precision(is_tp: np.ndarray, recall_samples: np.ndarray, num_gts: float) -> float:
    """av2 ``compute_average_precision``: VOC-style AP of score-ranked detections."""
    cum_tps = np.cumsum(is_tp)
    cum_fps = np.cumsum(~is_tp)
    cum_fns = num_gts - cum_tps
    precision = cum_tps / (cum_tps + cum_fps + _EPS)
    recall = cum_tps / (cum_tps + cum_fns)
    precision = np.maximum.accumulate(precision[::-1])[::-1]
    return float(np.mean(np.interp(recall_samples, recall, precision, right=0)))


def _summarize(
    dts: CuboidTable, gts: CuboidTable, dts_outcome: np.ndarray, gts_outcome: np.ndarray, config: Av2DetectionConfig
) -> dict[str, dict[str, float]]:
    """av2 ``summarize_metrics`` plus its mean row."""
    recall_samples = np.linspace(0, 1, config.num_recall_samples, endpoint=True)
    n_thresholds = len(config.affinity_thresholds_m)
    middle = n_thresholds // 2
    normalization = np.asarray(config.tp_normalization_terms)
    # av2 ranks within the rows sorted by (log, time, category), input order kept inside a group.
    uuid_order = np.lexsort((dts.category, dts.timestamp_ns, dts.log_id))
    summary: dict[str, dict[str, float]] = {}
    for category in config.categories:
        row = dict(zip(METRICS, (0.0, config.tp_threshold_m, 1.0, math.pi, 0.0), strict=True))
        summary[category] = row
        num_gts = float(gts_outcome[gts.category == category, -1].sum())
        if num_gts == 0:
            continue
        rows = uuid_order[(dts.category[uuid_order] == category) & (dts_outcome[uuid_order, -1] != 0)]
        rows = rows[np.argsort(-dts.last[rows], kind="stable")]
        outcome = dts_outcome[rows]
        aps = [_average_precision(outcome[:, i].astype(bool), recall_samples, num_gts) if len(rows) else 0.0
               for i in range(n_thresholds)]
        mean_ap = float(np.mean(aps))
        is_tp = outcome[:, middle].astype(bool)
        errors = outcome[is_tp, n_thresholds:n_thresholds + 3].mean(axis=0) if is_tp.any() else normalization
        cds = mean_ap * float(np.mean(1 - np.divide(errors, normalization)))
        row.update(AP=mean_ap, ATE=float(errors[0]), ASE=float(errors[1]), AOE=float(errors[2]), CDS=cds)
    summary[AVERAGE] = {m: float(np.mean([summary[c][m] for c in config.categories])) for m in METRICS}
    return summary


def _read_table(path: Path) -> pa.Table:
    if path.suffix != ".parquet":
        return av2.read_table(path)
    refuse_special_file(path)  # pyarrow calls a FIFO missing
    try:
        return pq.read_table(path)
    except FileNotFoundError:
        raise InputError(f"{path}: expected a detection parquet file, got none") from None
    except (pa.ArrowException, OSError, ValueError) as error:
        raise InputError(f"{path}: unreadable detection file ({error})") from None


def _column_type(name: str) -> tuple[str, Callable[[pa.DataType], bool]]:
    """What column ``name`` of a detection table holds, and the test of its Arrow type."""
    if name in ("log_id", "category"):
        return "text", lambda t: pa.types.is_string(t) or pa.types.is_large_string(t)
    if name == "timestamp_ns":
        return "integers", pa.types.is_integer
    return "numbers", lambda t: pa.types.is_integer(t) or pa.types.is_floating(t)


def _cuboid_table(table: pa.Table, path: Path, last: str) -> CuboidTable:
    needed = ("log_id", "timestamp_ns", "category", *CUBOID_COLUMNS, last)
    missing = [c for c in needed if c not in table.column_names]
    if missing:
        raise InputError(f"{path}: expected columns {list(needed)}, missing {missing}")
    columns = {c: table.column(c) for c in needed}
    for name, column in columns.items():
        if column.null_count:
            raise InputError(f"{path}: column {name!r}: expected values, got {column.null_count} nulls")
        # Typed as av2 writes them: numbers given as text ("1.5") would be converted without a word.
        expected, fits = _column_type(name)
        if not fits(column.type.value_type if pa.types.is_dictionary(column.type) else column.type):
            raise InputError(f"{path}: column {name!r}: expected {expected}, got {column.type}")
    try:
        params = np.stack([columns[c].to_numpy().astype(np.float64) for c in CUBOID_COLUMNS], axis=1)
        scores = columns[last].to_numpy().astype(np.float64)
        times = columns["timestamp_ns"].to_numpy().astype(np.int64)
    except (pa.ArrowException, ValueError, TypeError) as error:
        raise InputError(f"{path}: expected numeric cuboid columns, got {error}") from None
    bad = np.flatnonzero(~np.isfinite(np.column_stack([params, scores])).all(axis=1))
    if len(bad):
        raise InputError(f"{path}: row {int(bad[0])}: expected finite cuboid values and score, got NaN or inf")
    absurd = np.flatnonzero((np.abs(params[:, :3]) > MAX_COORDINATE_M).any(axis=1)
                            | (params[:, 3:6] > MAX_BOX_SIZE_M).any(axis=1))
    if len(absurd):  # finite, but 1e308 m overflows the distances and IoUs
        raise InputError(f"{path}: row {int(absurd[0])}: expected a centre within {MAX_COORDINATE_M:g} m and sizes up "
                         f"to {MAX_BOX_SIZE_M:g} m, got {params[absurd[0], :6].tolist()}")
    for name in ("log_id", "category"):  # NumPy's strings drop trailing NULs: "log\x00" would be log "log"
        with_nul = pc.match_substring(columns[name].cast(pa.string()), "\x00")
        if pc.any(with_nul).as_py():
            row = int(np.flatnonzero(with_nul.to_numpy(zero_copy_only=False))[0])
            raise InputError(f"{path}: row {row}: {name}: expected text without NUL characters, got "
                             f"{columns[name][row].as_py()!r}")
    negative = np.flatnonzero((params[:, 3:6] < 0.0).any(axis=1))
    if len(negative):
        column = CUBOID_COLUMNS[3 + int(np.argmax(params[negative[0], 3:6] < 0.0))]
        raise InputError(f"{path}: row {int(negative[0])}: {column}: expected a size >= 0, got "
                         f"{params[negative[0], CUBOID_COLUMNS.index(column)]}")
    bad = np.flatnonzero(np.abs(np.linalg.norm(params[:, 6:10], axis=1) - 1.0) > 1e-3)
    if len(bad):
        raise InputError(f"{path}: row {int(bad[0])}: columns qw..qz: expected a unit quaternion, got "
                         f"{params[bad[0], 6:10].tolist()}")
    return CuboidTable(
        log_id=np.asarray(columns["log_id"].to_pylist(), dtype=str),
        timestamp_ns=times,
        category=np.asarray(columns["category"].to_pylist(), dtype=str),
        params=params,
        last=scores,
    )
