"""AB3DMOT's KITTI 3D MOT protocol (``scripts/KITTI/evaluate.py`` of xinshuoweng/AB3DMOT), from its formulas.

Per class (``car``: GT ``Car``, ``Van`` ignored; ``pedestrian``: GT ``Pedestrian``, KITTI tracking's
``Person`` (a sitting person; ``Person_sitting`` in KITTI object) ignored, where the script's substring test
``"person_sitting" in "person"`` ignores nothing; ``cyclist``: GT ``Cyclist``) and sequence, frame by frame:
tracker boxes of the class with ``score >= threshold`` are matched to ground truth by Hungarian assignment on
``1 - similarity`` where the similarity (2D IoU of the image boxes, or 3D IoU of the boxes) is at least
``min_similarity``. As in the KITTI devkit, ground truth occluded > 2, truncated > 0, of a neighbour class or
lower than 25 px is ignored (a tracker box matched to it is neither TP nor FP; unmatched, it is no FN), and an
unmatched tracker box lower than 25 px or covering a DontCare region by more than half its area is no FP.

CLEAR MOT over all sequences: ``MOTA = 1 - (FN + FP + IDS) / n_gt``, ``MOTP`` the mean similarity of the TPs;
IDS counts a ground-truth track matched in two consecutive frames to different tracker ids; FRAG counts the
times its tracking resumes after an interruption. AB3DMOT's recall-integrated metrics, with L = 40:

    sMOTA_r = clip(1 - (FN + FP + IDS - (1 - r) n_gt) / (r n_gt), 0, 1)     at threshold t_r
    sAMOTA = sum_r sMOTA_r / L,  AMOTA = sum_r MOTA_r / L,  AMOTP = sum_r MOTP_r / L

for r = 1/L .. L/L, with t_r the lowest TP score (of the run without threshold) that reaches recall r; a
recall the tracker never reaches contributes 0 (the sum is still divided by L, as the script does).
MOTA, MOTP, IDS, FRAG, FP and FN are then reported at the best single threshold as the definition says: the
tracker score, among all of the class's scores, with the highest MOTA (the highest such score on a tie, as the
script's strict comparison does). The
script instead takes the best of its 40 sampled t_r; that MOTA and threshold are given too (``script_MOTA``,
``script_threshold``) and can only be lower or equal. A class without scored ground truth in the sequences
(e.g. Cyclist in KITTI val 0001, 0006, 0008) is a warning, and its metrics are NaN.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from avdata.errors import InputError
from avdata.eval.geometry import box2d_iou, box3d_iou
from avdata.eval.problems import warn
from avdata.frames import Boxes3D
from avdata.perception.detection_files import FLU_T_CAM0, UPRIGHT_FRAME
from avdata.sources.kitti.labels import KittiLabels, read_labels

__all__ = ["CLASSES", "Kitti3dmotResult", "evaluate_kitti_3dmot"]

#: class -> (KITTI class evaluated, neighbour classes ignored)
CLASSES = {"car": ("Car", ("Van",)), "pedestrian": ("Pedestrian", ("Person", "Person_sitting")), "cyclist": ("Cyclist", ())}
_L = 40
_MIN_HEIGHT_PX = 25.0


@dataclass(frozen=True, slots=True)
class _Counts:
    tp: int
    fp: int
    fn: int
    ids: int
    frag: int
    similarity_sum: float
    tp_scores: np.ndarray

    def metrics(self) -> dict[str, float]:
        n_gt = self.tp + self.fn
        return {"MOTA": 1.0 - (self.fn + self.fp + self.ids) / n_gt if n_gt else float("nan"),
                "MOTP": self.similarity_sum / self.tp if self.tp else 0.0, "IDS": self.ids, "FRAG": self.frag,
                "FP": self.fp, "FN": self.fn, "TP": self.tp}


@dataclass(frozen=True, slots=True, kw_only=True)
class Kitti3dmotResult:
    """Per class: sAMOTA, AMOTA, AMOTP and, at the best threshold, MOTA, MOTP, IDS, FRAG, FP, FN, TP, threshold."""

    table: dict[str, dict[str, float]]


def evaluate_kitti_3dmot(gt_folder: Path, tracker_folder: Path, sequences: list[str],
                         classes: tuple[str, ...] = ("car", "pedestrian", "cyclist"), similarity: str = "2d",
                         min_similarity: float = 0.5) -> Kitti3dmotResult:
    """AB3DMOT's KITTI evaluation of ``tracker_folder/<seq>.txt`` against ``gt_folder/label_02/<seq>.txt``.

    Args:
        gt_folder: folder with ``label_02/<seq>.txt``.
        tracker_folder: KITTI tracking results with a score column.
        sequences: the sequences to evaluate (each must have both files).
        classes: subset of ``car``, ``pedestrian``, ``cyclist``.
        similarity: ``2d`` (image boxes) or ``3d`` (3D IoU).
        min_similarity: least similarity of a match (AB3DMOT: 0.5 in 2D; 0.25, 0.5 or 0.7 in 3D).
    """
    if similarity not in ("2d", "3d") or not 0.0 < min_similarity <= 1.0:
        raise InputError(f"kitti-3dmot: expected similarity 2d or 3d and a threshold in (0, 1], got {similarity!r}, "
                         f"{min_similarity}")
    if bad := [c for c in classes if c not in CLASSES]:
        raise InputError(f"kitti-3dmot: expected classes among {sorted(CLASSES)}, got {bad}")
    data = {seq: (_read(Path(gt_folder) / "label_02" / f"{seq}.txt", False),
                  _read(Path(tracker_folder) / f"{seq}.txt", True)) for seq in sequences}
    table = {}
    for cls in classes:
        frames = [f for seq, (gt, tr) in data.items() for f in _frames(seq, gt, tr, cls, similarity, min_similarity)]
        everything = _count(frames, -np.inf)
        n_gt = everything.tp + everything.fn
        if n_gt == 0:
            warn(f"kitti-3dmot: class {cls} has no scored ground truth in these sequences; its metrics are not defined")
            table[cls] = dict.fromkeys(("sAMOTA", "AMOTA", "AMOTP", "MOTA", "MOTP", "threshold"), float("nan")) | {
                "IDS": everything.ids, "FRAG": everything.frag, "FP": everything.fp, "FN": 0, "TP": 0, "GT": 0}
            continue
        scores = np.sort(everything.tp_scores)[::-1]
        rows = {"sAMOTA": 0.0, "AMOTA": 0.0, "AMOTP": 0.0}
        best: tuple[float, dict[str, float]] | None = None
        for k in range(1, _L + 1):
            r = k / _L
            rank = int(np.ceil(r * n_gt - 1e-9))
            if rank > len(scores):
                break
            threshold = float(scores[rank - 1])
            m = _count(frames, threshold).metrics()
            rows["sAMOTA"] += min(1.0, max(0.0, 1 - (m["FN"] + m["FP"] + m["IDS"] - (1 - r) * n_gt) / (r * n_gt))) / _L
            rows["AMOTA"] += m["MOTA"] / _L
            rows["AMOTP"] += m["MOTP"] / _L
            if best is None or m["MOTA"] > best[1]["MOTA"]:
                best = (threshold, m)
        if best is None:  # not even recall 1/40: no threshold is sampled, report the run without one
            best = (float(scores[-1]) if len(scores) else float("nan"), everything.metrics())
        candidates = np.unique(np.concatenate([f.tr_scores for f in frames]))
        mota = _mota_by_threshold(frames, candidates, n_gt)
        at = len(mota) - 1 - int(np.argmax(mota[::-1])) if len(mota) else -1  # a tie goes to the highest score
        best_any = (float(candidates[at]), _count(frames, float(candidates[at])).metrics()) if at >= 0 else best
        table[cls] = rows | best_any[1] | {"threshold": best_any[0], "GT": n_gt, "script_MOTA": best[1]["MOTA"],
                                           "script_threshold": best[0]}
    return Kitti3dmotResult(table=table)


def _read(path: Path, with_score: bool) -> KittiLabels:
    if not path.is_file():
        raise InputError(f"{path}: expected a KITTI tracking {'result' if with_score else 'label'} file, got none")
    labels, problems = read_labels(path, tracking=True, with_score=with_score)
    if problems:
        raise InputError(f"{path}: {problems[0]}")
    return labels


@dataclass(frozen=True, slots=True)
class _Frame:
    gt_ids: np.ndarray          # (G,) ground-truth track ids (ignored ones included)
    gt_ignored: np.ndarray      # (G,)
    tr_ids: np.ndarray          # (T,)
    tr_scores: np.ndarray       # (T,)
    tr_no_fp: np.ndarray        # (T,) unmatched, still no FP (too low, or in a DontCare region)
    similarity: np.ndarray      # (G, T)
    seq: str


def _frames(seq: str, gt: KittiLabels, tr: KittiLabels, cls: str, similarity: str, min_similarity: float) -> list[_Frame]:
    name, neighbours = CLASSES[cls]
    gt_keep = np.isin(gt.cls, (name, *neighbours))
    dontcare = gt.cls == "DontCare"
    tr_keep = tr.cls == name
    out = []
    last = int(max(gt.frame.max(initial=-1), tr.frame.max(initial=-1)))
    for f in range(last + 1):
        g = np.flatnonzero(gt_keep & (gt.frame == f))
        t = np.flatnonzero(tr_keep & (tr.frame == f))
        height = gt.bbox[g, 3] - gt.bbox[g, 1]
        ignored = (gt.cls[g] != name) | (gt.occluded[g] > 2) | (gt.truncated[g] > 0) | (height < _MIN_HEIGHT_PX)
        if similarity == "2d":
            sim = box2d_iou(gt.bbox[g], tr.bbox[t])
        else:
            sim = box3d_iou(_rows3d(gt, g), _rows3d(tr, t))
        dc = gt.bbox[dontcare & (gt.frame == f)]
        tr_box = tr.bbox[t]
        area = np.clip(tr_box[:, 2] - tr_box[:, 0], 0, None) * np.clip(tr_box[:, 3] - tr_box[:, 1], 0, None)
        inter = _intersection(tr_box, dc)
        in_dontcare = np.any(inter > 0.5 * area[:, None], axis=1) if len(dc) else np.zeros(len(t), bool)
        low = (tr_box[:, 3] - tr_box[:, 1]) < _MIN_HEIGHT_PX
        out.append(_Frame(gt.track_id[g], ignored, tr.track_id[t], tr.score[t], low | in_dontcare,
                          np.where(sim >= min_similarity, sim, 0.0), seq))
    return out


def _rows3d(labels: KittiLabels, index: np.ndarray) -> np.ndarray:
    boxes = Boxes3D.from_kitti_camera(labels.hwl[index], labels.location[index], labels.rotation_y[index], "ego/cam0")
    flu = boxes.transform(FLU_T_CAM0, UPRIGHT_FRAME)
    rows: np.ndarray = np.c_[flu.center, flu.size_lwh, flu.yaw()]
    return rows


def _intersection(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0])
    h = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1])
    area: np.ndarray = np.clip(w, 0, None) * np.clip(h, 0, None)
    return area


def _match_frame(fr: _Frame, threshold: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One frame's optimal matching of ground truth to the tracks scored >= threshold.

    Returns the tracks used, the matched track of each ground-truth box (-1: none; an index among the used
    tracks) and which used tracks matched.
    """
    use = fr.tr_scores >= threshold
    sim = fr.similarity[:, use]
    matched_gt = np.full(len(fr.gt_ids), -1)
    tr_matched = np.zeros(int(use.sum()), bool)
    if sim.size and sim.max() > 0:
        r, c = linear_sum_assignment(-sim)
        ok = sim[r, c] > 0
        matched_gt[r[ok]] = c[ok]
        tr_matched[c[ok]] = True
    return use, matched_gt, tr_matched


def _count(frames: list[_Frame], threshold: float) -> _Counts:
    tp = fp = fn = ids = frag = 0
    similarity_sum = 0.0
    tp_scores = []
    last_match: dict[tuple[str, int], int] = {}   # gt track -> tracker id in the previous frame (-1: missed)
    was_tracked: dict[tuple[str, int], bool] = {}
    for fr in frames:
        use, matched_gt, tr_matched = _match_frame(fr, threshold)
        tr_ids, tr_scores, no_fp = fr.tr_ids[use], fr.tr_scores[use], fr.tr_no_fp[use]
        counted = ~fr.gt_ignored
        hit = counted & (matched_gt >= 0)
        tp += int(hit.sum())
        fn += int((counted & (matched_gt < 0)).sum())
        similarity_sum += float(fr.similarity[:, use][np.flatnonzero(hit), matched_gt[hit]].sum())
        tp_scores.append(tr_scores[matched_gt[hit]])
        on_ignored = np.zeros(len(tr_ids), bool)
        on_ignored[matched_gt[fr.gt_ignored & (matched_gt >= 0)]] = True
        fp += int((~tr_matched & ~no_fp).sum())
        for g in np.flatnonzero(counted):
            key = (fr.seq, int(fr.gt_ids[g]))
            now = int(tr_ids[matched_gt[g]]) if matched_gt[g] >= 0 else -1
            before = last_match.get(key, -1)
            if now >= 0 and before >= 0 and now != before:
                ids += 1
            if now >= 0 and before < 0 and was_tracked.get(key, False):
                frag += 1
            was_tracked[key] = was_tracked.get(key, False) or now >= 0
            last_match[key] = now
    return _Counts(tp, fp, fn, ids, frag, similarity_sum, np.concatenate(tp_scores) if tp_scores else np.zeros(0))


def _mota_by_threshold(frames: list[_Frame], thresholds: np.ndarray, n_gt: int) -> np.ndarray:
    """MOTA at each of (K,) thresholds: :func:`_count`'s FN, FP and IDS, vectorised over frames and thresholds.

    In a frame whose positive similarities pair each ground truth and each tracker box at most once (most
    frames), the Hungarian matching at any threshold is those pairs among the boxes kept, so a counted ground
    truth is matched iff its box's score >= t; the other frames are matched once per distinct score of their
    boxes.
    """
    key_of: dict[tuple[str, int], int] = {}
    entry_key: list[int] = []
    entry_order: list[int] = []
    entry_id: list[int] = []
    entry_score: list[float] = []
    fp_scores: list[np.ndarray] = []
    # per frame with conflicts: (first entry index, (levels,) scores descending, (levels + 1, G) matched tracker
    # ids with every score >= level kept (-1 none), (levels + 1,) FP)
    conflicts: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []
    for position, fr in enumerate(frames):
        counted = np.flatnonzero(~fr.gt_ignored)
        keys = [key_of.setdefault((fr.seq, int(fr.gt_ids[g])), len(key_of)) for g in counted.tolist()]
        start = len(entry_key)
        entry_key += keys
        entry_order += [position] * len(keys)
        positive = fr.similarity > 0
        if positive.size and (positive.sum(axis=0).max() > 1 or positive.sum(axis=1).max() > 1):
            levels = np.unique(fr.tr_scores)[::-1]
            now_levels: list[np.ndarray] = []
            fp_levels: list[int] = []
            for level in (np.inf, *levels.tolist()):
                use, matched_gt, tr_matched = _match_frame(fr, level)
                ids = np.r_[fr.tr_ids[use], -1]  # the appended -1 stands for "unmatched" (index -1)
                now_levels.append(ids[matched_gt[counted]])
                fp_levels.append(int((~tr_matched & ~fr.tr_no_fp[use]).sum()))
            conflicts.append((start, levels, np.array(now_levels, dtype=np.int64).reshape(len(now_levels), -1),
                              np.array(fp_levels)))
            entry_id += [-1] * len(keys)
            entry_score += [np.inf] * len(keys)
            continue
        has = positive.any(axis=1) if positive.size else np.zeros(len(fr.gt_ids), bool)
        column = np.where(has, np.argmax(positive, axis=1) if positive.size else 0, -1)[counted]
        # index -1 picks the appended "unmatched" values
        entry_id += np.r_[fr.tr_ids, -1][column].tolist()
        entry_score += np.r_[fr.tr_scores, np.inf][column].tolist()
        unmatched = ~positive.any(axis=0) if positive.size else np.ones(len(fr.tr_ids), bool)
        fp_scores.append(fr.tr_scores[unmatched & ~fr.tr_no_fp])
    key, order = np.asarray(entry_key, np.int64), np.asarray(entry_order, np.int64)
    tr_id, tr_score = np.asarray(entry_id, np.int64), np.asarray(entry_score, np.float64)
    sequence = np.lexsort((order, key))  # each ground-truth track's counted frames in order
    same_track = np.r_[False, key[sequence][1:] == key[sequence][:-1]]
    fp_sorted = np.sort(np.concatenate(fp_scores)) if fp_scores else np.zeros(0)
    mota = np.empty(len(thresholds))
    for k, t in enumerate(thresholds.tolist()):
        now = np.where(tr_score >= t, tr_id, -1)
        fp = len(fp_sorted) - int(np.searchsorted(fp_sorted, t, side="left"))
        for start, levels, now_by_level, fp_by_level in conflicts:
            level = int(np.sum(levels >= t))
            now[start:start + now_by_level.shape[1]] = now_by_level[level]
            fp += int(fp_by_level[level])
        ordered = now[sequence]
        before = np.r_[-1, ordered[:-1]]
        ids = int(np.sum(same_track & (ordered >= 0) & (before >= 0) & (ordered != before)))
        fn = int(np.sum(now < 0))
        mota[k] = 1.0 - (fn + fp + ids) / n_gt
    return mota
