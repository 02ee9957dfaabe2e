"""KITTI object detection AP (11 and 40 recall points) for 2D, BEV and 3D boxes, and AOS.

Semantics of the official devkit as its Python port computes them (``kitti-object-eval-python``, the
``eval.py`` used by SECOND / OpenPCDet / mmdetection3d):

* difficulties Easy / Moderate / Hard: a ground truth is *ignored* (not a miss, not a match target that
  counts) when its occlusion > (0, 1, 2), truncation > (0.15, 0.3, 0.5) or 2D height <= (40, 25, 25) px; a
  detection lower than the minimum height is ignored too;
* neighbouring classes: a Van is an ignored ground truth when evaluating Car, a Person_sitting when
  evaluating Pedestrian; other classes do not take part; detections of other classes do not take part;
* matching, per image and per ground truth in file order: among the free detections with overlap >
  threshold, the highest-overlap non-ignored one (else the first ignored one) — or, when collecting the score
  thresholds, the highest-scoring one; a match with an ignored ground truth or detection is neither TP nor FP;
* 2D only: unmatched detections covering a DontCare region (intersection / detection area > threshold) are
  not false positives;
* the 41 score thresholds come from the matched scores so that recall advances in steps of 1/40;
  precision at each is TP / (TP + FP), made non-increasing from the right; AP_11 averages points
  0, 4, ..., 40 and AP_40 points 1..40 (times 100). AOS replaces TP by sum((1 + cos(d_alpha)) / 2);
* overlaps: 2D IoU; BEV IoU of the (x, z) rectangles of length l and width w rotated by rotation_y
  (camera frame, y down); 3D IoU = BEV intersection x overlap of the [y - h, y] extents.

The devkit computes rotated overlaps in float32 on a GPU kernel; here they are exact float64, so a pair lying
within ~1e-6 of a threshold can decide differently.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from types import MappingProxyType

import numpy as np

from avdata.errors import InputError
from avdata.eval import geometry
from avdata.eval.problems import check_ground_truth, warn
from avdata.inputs import is_present, require_folder
from avdata.sources.kitti.labels import KittiLabels, read_labels

__all__ = [
    "KittiBoxType",
    "KittiDetectionConfig",
    "KittiDifficulty",
    "KittiObjects",
    "evaluate_kitti_detection",
    "load_kitti_objects",
]

_N_POINTS = 41
_MIN_HEIGHT_PX = (40.0, 25.0, 25.0)
#: The object types of KITTI's labels, lower-cased (the devkit compares types with strcasecmp).
_KITTI_TYPES = ("car", "van", "truck", "pedestrian", "person_sitting", "cyclist", "tram", "misc", "dontcare")
_MAX_OCCLUSION = (0, 1, 2)
_MAX_TRUNCATION = (0.15, 0.3, 0.5)
_NEIGHBOUR = MappingProxyType({"car": "van", "pedestrian": "person_sitting"})


class KittiDifficulty(str, Enum):
    """KITTI difficulty levels (limits on occlusion, truncation and 2D height)."""

    EASY = "easy"
    MODERATE = "moderate"
    HARD = "hard"


class KittiBoxType(str, Enum):
    """What is compared: image boxes, bird's-eye-view rectangles, 3D boxes; AOS rides on the 2D matches."""

    BBOX = "bbox"
    BEV = "bev"
    BOX3D = "3d"
    AOS = "aos"


@dataclass(frozen=True, slots=True, kw_only=True)
class KittiDetectionConfig:
    """Overlap thresholds (the official ones: 0.7 for Car, 0.5 for Pedestrian and Cyclist, for every box type).

    Attributes:
        min_overlap: class (KITTI spelling) -> IoU a match must exceed.
    """

    min_overlap: Mapping[str, float] = field(
        default_factory=lambda: MappingProxyType({"Car": 0.7, "Pedestrian": 0.5, "Cyclist": 0.5})
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class KittiObjects:
    """Objects of many images in KITTI's label layout (camera frame, y down), concatenated.

    Attributes:
        image: (N,) image key of each object.
        name: (N,) KITTI class name ("Car", "Van", "DontCare", ...).
        truncated: (N,) truncation in [0, 1].
        occluded: (N,) occlusion level 0..3.
        alpha_rad: (N,) observation angle (-10 when unknown).
        bbox_px: (N, 4) image box (x0, y0, x1, y1).
        dimensions_hwl_m: (N, 3) height, width, length, as in the file.
        location_m: (N, 3) bottom centre in the camera frame.
        rotation_y_rad: (N,) yaw about the camera y axis.
        score: (N,) detection score (0 for ground truth).
    """

    image: np.ndarray
    name: np.ndarray
    truncated: np.ndarray
    occluded: np.ndarray
    alpha_rad: np.ndarray
    bbox_px: np.ndarray
    dimensions_hwl_m: np.ndarray
    location_m: np.ndarray
    rotation_y_rad: np.ndarray
    score: np.ndarray

    def __len__(self) -> int:
        """Number of objects."""
        return len(self.image)


def load_kitti_objects(folder: str | Path, image_ids: Sequence[str] | None = None, *,
                       results: bool = False) -> KittiObjects:
    """Reads KITTI label or result files ``<folder>/<image>.txt`` (15 columns, 16 with a score).

    Lines are parsed by :func:`avdata.sources.kitti.labels.read_labels`; an unreadable line is an
    :class:`InputError` naming the file and line.

    Args:
        folder: the folder (``label_2`` or a results folder).
        image_ids: images to read (file stems); None reads every ``*.txt``. A missing result file reads as
            an image with no detections.
        results: the files are results: every line needs its score and a KITTI type (any case, as the devkit
            compares them); a line without a score read as score 0, a misspelt type as no detection, without a word.

    Returns:
        The objects, in file order.
    """
    folder = Path(folder)
    require_folder(folder, "folder of KITTI .txt files")
    ids = sorted(p.stem for p in folder.glob("*.txt")) if image_ids is None else list(image_ids)
    parts: list[KittiLabels] = []
    images: list[np.ndarray] = []
    missing = 0
    for image in ids:
        path = folder / f"{image}.txt"
        if not is_present(path):  # a broken link or a loop is an error, not "no detections"
            missing += 1
            continue
        labels, problems = read_labels(path, with_score=results)
        if problems:
            more = f" (and {len(problems) - 1} more line(s))" if len(problems) > 1 else ""
            raise InputError(f"{path}: {problems[0].message}{more}")
        unknown = ~np.isin(np.char.lower(labels.cls.astype(str)), _KITTI_TYPES)
        if results and np.any(unknown):
            k = int(np.argmax(unknown))
            raise InputError(f"{path}: line {labels.line[k]}: type: expected a KITTI type ({', '.join(_KITTI_TYPES)}, "
                             f"any case), got {str(labels.cls[k])!r}")
        parts.append(labels)
        images.append(np.full(len(labels), image, dtype=object))
    if image_ids is not None and ids and missing == len(ids):
        # Each missing file may be an image without detections; none at all is more likely the wrong folder.
        warn(f"{folder}: expected result files <image>.txt, got none for the {len(ids)} image(s); "
             f"all are scored as without detections")
    def column(name: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
        return np.concatenate([getattr(p, name) for p in parts]) if parts else np.zeros(shape, dtype=dtype)

    score = column("score", (0,), float)
    return KittiObjects(
        image=np.concatenate(images) if images else np.zeros(0, dtype=object),
        name=column("cls", (0,), str).astype(object),
        truncated=column("truncated", (0,), float),
        occluded=column("occluded", (0,), np.int64),
        alpha_rad=column("alpha", (0,), float),
        bbox_px=column("bbox", (0, 4), float),
        dimensions_hwl_m=column("hwl", (0, 3), float),
        location_m=column("location", (0, 3), float),
        rotation_y_rad=column("rotation_y", (0,), float),
        # A label line has no score: 0, as the devkit reads ground truth.
        score=np.where(np.isnan(score), 0.0, score),
    )


def _bev(obj: KittiObjects, idx: np.ndarray) -> np.ndarray:
    """(K, 5) BEV rectangles (x, z, l, w, -rotation_y) in avdata's counter-clockwise convention."""
    h, w, length = obj.dimensions_hwl_m[idx].T
    result: np.ndarray = np.c_[obj.location_m[idx, 0], obj.location_m[idx, 2], length, w, -obj.rotation_y_rad[idx]]
    return result


def _pair_overlap(gt: KittiObjects, dt: KittiObjects, g: np.ndarray, d: np.ndarray, box: KittiBoxType) -> np.ndarray:
    """(K,) overlap of detection d[k] with ground truth g[k] (the devkit's ``overlaps[j, i]``)."""
    if box in (KittiBoxType.BBOX, KittiBoxType.AOS):
        return _kitti_box_iou(dt.bbox_px[d], gt.bbox_px[g])
    inter = geometry.bev_intersection_area(_bev(dt, d), _bev(gt, g), paired=True)
    dh, dw, dl = dt.dimensions_hwl_m[d].T
    gh, gw, gl = gt.dimensions_hwl_m[g].T
    if box is KittiBoxType.BEV:
        union = dl * dw + gl * gw - inter
        bev_overlap: np.ndarray = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)
        return bev_overlap
    dy, gy = dt.location_m[d, 1], gt.location_m[g, 1]
    height = np.minimum(dy, gy) - np.maximum(dy - dh, gy - gh)
    inter3 = np.where(height > 0, inter * np.maximum(height, 0), 0.0)
    union = dl * dh * dw + gl * gh * gw - inter3
    overlap_3d: np.ndarray = np.divide(inter3, union, out=np.zeros_like(inter3), where=(height > 0) & (union > 0))
    return overlap_3d


def _kitti_box_iou(a: np.ndarray, b: np.ndarray, over_first_area: bool = False) -> np.ndarray:
    """The devkit's ``image_box_overlap`` for pairs: 0 unless both overlaps are positive."""
    iw = np.minimum(a[:, 2], b[:, 2]) - np.maximum(a[:, 0], b[:, 0])
    ih = np.minimum(a[:, 3], b[:, 3]) - np.maximum(a[:, 1], b[:, 1])
    inter = iw * ih
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    denom = area_a if over_first_area else area_a + area_b - inter
    ok = (iw > 0) & (ih > 0)
    result: np.ndarray = np.divide(inter, denom, out=np.zeros_like(inter), where=ok)
    return result


@dataclass(frozen=True, slots=True)
class _Prepared:
    """Padded per-image arrays for one (class, difficulty, box type)."""

    n_valid_gt: int
    ignored_gt: np.ndarray  # (I, G) -1 / 0 / 1, -2 for padding
    ignored_dt: np.ndarray  # (I, D) -1 / 0 / 1, -2 for padding
    overlap: np.ndarray  # (I, D, G)
    score: np.ndarray  # (I, D)
    delta_alpha: np.ndarray  # (I, D, G) gt alpha - dt alpha
    dontcare_overlap: np.ndarray  # (I, D, C) intersection / detection area with each DontCare box
    dontcare_present: np.ndarray  # (I, C)


def _slots(image_index: np.ndarray, n_images: int) -> tuple[np.ndarray, int]:
    """Position of each object within its image (file order) and the widest image."""
    order = np.argsort(image_index, kind="stable")
    counts = np.bincount(image_index, minlength=n_images)
    slot = np.empty(len(image_index), dtype=np.int64)
    slot[order] = np.arange(len(order)) - np.repeat(np.cumsum(counts) - counts, counts)
    return slot, int(counts.max(initial=0))


def _prepare(
    gt: KittiObjects, dt: KittiObjects, images: np.ndarray, cls: str, difficulty: int, box: KittiBoxType
) -> _Prepared:
    n_img = len(images)
    gi = np.searchsorted(images, gt.image)
    di = np.searchsorted(images, dt.image)
    g_slot, g_w = _slots(gi, n_img)
    d_slot, d_w = _slots(di, n_img)
    d_w = max(d_w, 1)  # an always-ignored padding slot keeps the per-image arg-max defined without detections
    current = cls.lower()
    g_name = np.char.lower(gt.name.astype(str))
    d_name = np.char.lower(dt.name.astype(str))
    height = gt.bbox_px[:, 3] - gt.bbox_px[:, 1]
    valid = np.where(g_name == current, 1, np.where(g_name == _NEIGHBOUR.get(current, "\0"), 0, -1))
    ignore = (
        (gt.occluded > _MAX_OCCLUSION[difficulty])
        | (gt.truncated > _MAX_TRUNCATION[difficulty])
        | (height <= _MIN_HEIGHT_PX[difficulty])
    )
    ig_gt = np.where((valid == 1) & ~ignore, 0, np.where((valid == 0) | (ignore & (valid == 1)), 1, -1))
    d_height = np.abs(dt.bbox_px[:, 3] - dt.bbox_px[:, 1])
    ig_dt = np.where(d_height < _MIN_HEIGHT_PX[difficulty], 1, np.where(d_name == current, 0, -1))
    ignored_gt = np.full((n_img, g_w), -2)
    ignored_gt[gi, g_slot] = ig_gt
    ignored_dt = np.full((n_img, d_w), -2)
    ignored_dt[di, d_slot] = ig_dt
    score = np.zeros((n_img, d_w))
    score[di, d_slot] = dt.score
    # Same-image (detection, ground truth) pairs.
    d_order = np.argsort(di, kind="stable")
    g_order = np.argsort(gi, kind="stable")
    d_counts = np.bincount(di, minlength=n_img)
    g_counts = np.bincount(gi, minlength=n_img)
    n_pairs = d_counts * g_counts
    pair_img = np.repeat(np.arange(n_img), n_pairs)
    local = np.arange(n_pairs.sum()) - np.repeat(np.cumsum(n_pairs) - n_pairs, n_pairs)
    width = np.maximum(g_counts[pair_img], 1)
    d_start = np.cumsum(d_counts) - d_counts
    g_start = np.cumsum(g_counts) - g_counts
    pd = d_order[d_start[pair_img] + local // width]
    pg = g_order[g_start[pair_img] + local % width]
    overlap = np.zeros((n_img, d_w, g_w))
    overlap[pair_img, d_slot[pd], g_slot[pg]] = _pair_overlap(gt, dt, pg, pd, box)
    delta = np.zeros((n_img, d_w, g_w))
    delta[pair_img, d_slot[pd], g_slot[pg]] = gt.alpha_rad[pg] - dt.alpha_rad[pd]
    # DontCare regions (2D only).
    is_dc = gt.name == "DontCare"
    dc_idx = np.flatnonzero(is_dc)
    c_slot, c_w = _slots(gi[dc_idx], n_img)
    dc_present = np.zeros((n_img, c_w), dtype=bool)
    dc_present[gi[dc_idx], c_slot] = True
    dc_overlap = np.zeros((n_img, d_w, c_w))
    if box is KittiBoxType.BBOX or box is KittiBoxType.AOS:
        dc_counts = np.bincount(gi[dc_idx], minlength=n_img)
        n_dc_pairs = d_counts * dc_counts
        dc_img = np.repeat(np.arange(n_img), n_dc_pairs)
        local = np.arange(n_dc_pairs.sum()) - np.repeat(np.cumsum(n_dc_pairs) - n_dc_pairs, n_dc_pairs)
        c_width = np.maximum(dc_counts[dc_img], 1)
        c_order = dc_idx[np.argsort(gi[dc_idx], kind="stable")]
        c_start = np.cumsum(dc_counts) - dc_counts
        qd = d_order[d_start[dc_img] + local // c_width]
        qc_pos = c_start[dc_img] + local % c_width
        qc = c_order[qc_pos]
        c_slot_of = np.empty(len(gt), dtype=np.int64)
        c_slot_of[dc_idx] = c_slot
        dc_overlap[dc_img, d_slot[qd], c_slot_of[qc]] = _kitti_box_iou(
            dt.bbox_px[qd], gt.bbox_px[qc], over_first_area=True
        )
    return _Prepared(
        n_valid_gt=int(np.sum(ig_gt == 0)), ignored_gt=ignored_gt, ignored_dt=ignored_dt, overlap=overlap,
        score=score, delta_alpha=delta, dontcare_overlap=dc_overlap, dontcare_present=dc_present,
    )


def _statistics(p: _Prepared, min_overlap: float, thresholds: np.ndarray | None, box: KittiBoxType) -> np.ndarray:
    """The devkit's ``compute_statistics_jit`` for every image and score threshold at once.

    Ground truths are visited in file order (round r handles the r-th ground truth of every image).
    With ``thresholds`` None this is the threshold-collection pass (``compute_fp=False``) and returns the
    scores of the true positives; otherwise it returns (T, 4) sums of tp, fp, fn, orientation similarity.
    """
    n_img, d_w, g_w = p.overlap.shape
    collect = thresholds is None
    thr = np.zeros(1) if collect else np.asarray(thresholds, dtype=np.float64)
    n_t = len(thr)
    below = (p.score[None] < thr[:, None, None]) & (not collect)  # (T, I, D)
    usable = (p.ignored_dt[None] >= 0) & ~below
    assigned = np.zeros((n_t, n_img, d_w), dtype=bool)
    tp = np.zeros((n_t, n_img))
    fn = np.zeros((n_t, n_img))
    sim = np.zeros((n_t, n_img))
    tp_scores = []
    no_det = np.int64(-1)
    for r in range(g_w):
        ig_gt = p.ignored_gt[:, r]  # (I,)
        active = (ig_gt == 0) | (ig_gt == 1)
        ov = p.overlap[:, :, r][None]  # (1, I, D)
        cand = usable & ~assigned & (ov > min_overlap) & active[None, :, None]
        if collect:
            s = np.where(cand, p.score[None], -np.inf)
            det = np.where(cand.any(axis=2), np.argmax(s, axis=2), no_det)
        else:
            valid_c = cand & (p.ignored_dt[None] == 0)
            ign_c = cand & (p.ignored_dt[None] == 1)
            best_valid = np.argmax(np.where(valid_c, ov, -np.inf), axis=2)
            first_ign = np.argmax(ign_c, axis=2)
            det = np.where(valid_c.any(axis=2), best_valid, np.where(ign_c.any(axis=2), first_ign, no_det))
        found = det >= 0
        safe = np.maximum(det, 0)
        t_idx, i_idx = np.nonzero(np.ones((n_t, n_img), dtype=bool))
        det_ignored = p.ignored_dt[i_idx, safe.ravel()].reshape(n_t, n_img) == 1
        fn += (~found) & (ig_gt == 0)[None]
        is_tp = found & ~((ig_gt == 1)[None] | det_ignored)
        tp += is_tp
        assigned[t_idx[found.ravel()], i_idx[found.ravel()], safe.ravel()[found.ravel()]] = True
        if collect:
            tp_scores.append(p.score[np.nonzero(is_tp[0])[0], safe[0][is_tp[0]]])
        else:
            d_alpha = p.delta_alpha[i_idx, safe.ravel(), r].reshape(n_t, n_img)
            sim += np.where(is_tp, (1.0 + np.cos(d_alpha)) / 2.0, 0.0)
    if collect:
        return np.concatenate(tp_scores) if tp_scores else np.zeros(0)
    fp = np.sum(usable & ~assigned & (p.ignored_dt[None] == 0), axis=2).astype(np.float64)
    if box in (KittiBoxType.BBOX, KittiBoxType.AOS):
        # DontCare regions absorb unmatched detections, region by region in file order.
        for c in range(p.dontcare_overlap.shape[2]):
            hit = (usable & ~assigned & (p.ignored_dt[None] == 0) & p.dontcare_present[None, :, c, None]
                   & (p.dontcare_overlap[None, :, :, c] > min_overlap))
            assigned |= hit
            fp -= hit.sum(axis=2)
    # Images with neither a TP nor an FP add no similarity (the devkit's -1).
    return np.stack([tp.sum(axis=1), fp.sum(axis=1), fn.sum(axis=1), sim.sum(axis=1)], axis=1)


def _thresholds(scores: np.ndarray, num_gt: int) -> np.ndarray:
    """The devkit's ``get_thresholds``: scores at which recall reaches 0, 1/40, 2/40, ..."""
    scores = np.sort(scores)[::-1]
    out = []
    current = 0.0
    n = len(scores)
    for i, score in enumerate(scores.tolist()):
        l_recall = (i + 1) / num_gt
        r_recall = (i + 2) / num_gt if i < n - 1 else l_recall
        if (r_recall - current) < (current - l_recall) and i < n - 1:
            continue
        out.append(score)
        current += 1 / (_N_POINTS - 1.0)
    return np.array(out)


def _curves(p: _Prepared, min_overlap: float, box: KittiBoxType) -> tuple[np.ndarray, np.ndarray]:
    """(41,) precision and (41,) orientation-similarity curves, non-increasing from the right."""
    precision = np.zeros(_N_POINTS)
    aos = np.zeros(_N_POINTS)
    if p.n_valid_gt == 0:
        return precision, aos
    thresholds = _thresholds(_statistics(p, min_overlap, None, box), p.n_valid_gt)
    if len(thresholds) == 0:
        return precision, aos
    pr = _statistics(p, min_overlap, thresholds, box)
    n = len(thresholds)
    with np.errstate(invalid="ignore", divide="ignore"):
        precision[:n] = pr[:, 0] / (pr[:, 0] + pr[:, 1])
        aos[:n] = pr[:, 3] / (pr[:, 0] + pr[:, 1])
    precision = np.maximum.accumulate(precision[::-1])[::-1]
    aos = np.maximum.accumulate(aos[::-1])[::-1]
    return precision, aos


@dataclass(frozen=True, slots=True, kw_only=True)
class KittiDetectionResult:
    """APs in percent: ``ap11[cls][box][difficulty]`` and ``ap40[...]``; curves for plotting."""

    ap11: Mapping[str, Mapping[str, Mapping[str, float]]]
    ap40: Mapping[str, Mapping[str, Mapping[str, float]]]
    precision: Mapping[tuple[str, str, str], np.ndarray]

    def summary(self) -> dict[str, dict[str, float]]:
        """``{class: {"<box>_<difficulty>_AP11": value, "<box>_<difficulty>_AP40": value}}``."""
        out: dict[str, dict[str, float]] = {}
        for cls in self.ap11:
            row = {}
            for box, per_diff in self.ap11[cls].items():
                for diff, v in per_diff.items():
                    row[f"{box}_{diff}_AP11"] = v
                    row[f"{box}_{diff}_AP40"] = self.ap40[cls][box][diff]
            out[cls] = row
        return out


_DEFAULT_CONFIG = KittiDetectionConfig()


def evaluate_kitti_detection(
    gt: KittiObjects,
    dt: KittiObjects,
    classes: Sequence[str] = ("Car", "Pedestrian", "Cyclist"),
    config: KittiDetectionConfig = _DEFAULT_CONFIG,
) -> KittiDetectionResult:
    """KITTI detection AP for each class, box type and difficulty.

    Args:
        gt: ground-truth objects (label_2), DontCare rows included.
        dt: detections (results with scores); images missing here have no detections.
        classes: KITTI class names to evaluate.
        config: overlap thresholds.

    Returns:
        AP_11 and AP_40 in percent; AOS is reported only when detections carry alphas (not -10).
    """
    unknown = [c for c in classes if c not in config.min_overlap]
    if unknown:
        raise InputError(f"classes: expected classes with an overlap threshold {sorted(config.min_overlap)}, got {unknown}")
    present = [c for c in classes if np.any(gt.name == c)]
    if not present:
        found = sorted(set(gt.name.tolist()) - {"DontCare"})
        raise InputError(f"ground truth: expected objects of {', '.join(classes)}, got none "
                         f"(classes in the labels: {', '.join(found[:8]) or 'none'})")
    if len(present) < len(classes):
        check_ground_truth("ground truth", classes, [c for c in classes if c not in present], "their AP is 0")
    images = np.unique(gt.image.astype(str))
    missing = set(np.unique(dt.image.astype(str)).tolist()) - set(images.tolist())
    if missing:
        raise InputError(f"detections image: expected images of the ground truth, got {sorted(missing)[:3]}")
    gt = KittiObjects(**{k: getattr(gt, k) for k in gt.__slots__} | {"image": gt.image.astype(str)})
    dt = KittiObjects(**{k: getattr(dt, k) for k in dt.__slots__} | {"image": dt.image.astype(str)})
    with_aos = len(dt) > 0 and dt.alpha_rad[0] != -10
    boxes = [KittiBoxType.BBOX, KittiBoxType.BEV, KittiBoxType.BOX3D] + ([KittiBoxType.AOS] if with_aos else [])
    ap11: dict[str, dict[str, dict[str, float]]] = {}
    ap40: dict[str, dict[str, dict[str, float]]] = {}
    curves: dict[tuple[str, str, str], np.ndarray] = {}
    for cls in classes:
        ap11[cls], ap40[cls] = {}, {}
        for box in boxes:
            ap11[cls][box.value], ap40[cls][box.value] = {}, {}
            for d_idx, diff in enumerate(KittiDifficulty):
                if box is KittiBoxType.AOS:
                    _, curve = _curves(_prepare(gt, dt, images, cls, d_idx, KittiBoxType.BBOX),
                                       config.min_overlap[cls], KittiBoxType.BBOX)
                else:
                    curve, _ = _curves(_prepare(gt, dt, images, cls, d_idx, box), config.min_overlap[cls], box)
                curves[(cls, box.value, diff.value)] = curve
                ap11[cls][box.value][diff.value] = float(np.sum(curve[0::4]) / 11 * 100)
                ap40[cls][box.value][diff.value] = float(np.sum(curve[1:]) / 40 * 100)
    return KittiDetectionResult(ap11=ap11, ap40=ap40, precision=curves)
