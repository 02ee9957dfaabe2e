"""AB3DMOT's KITTI 3D MOT protocol (``scripts/KITTI/evaluate.py`` of xinshuoweng/AB3DMOT), from its formulas.

Per class (``car``: GT ``Car``, ``Van`` ignored; ``pedestrian``: GT ``Pedestrian``, ``Person_sitting``
ignored; ``cyclist``: GT ``Cyclist``) and sequence, frame by frame: tracker boxes of the class with
``score >= threshold`` are matched to ground truth by Hungarian assignment on ``1 - similarity`` where the
similarity (2D IoU of the image boxes, or 3D IoU of the boxes) is at least ``min_similarity``. As in the
KITTI devkit, ground truth occluded > 2, truncated > 0, of a neighbour class or lower than 25 px is ignored
(a tracker box matched to it is neither TP nor FP; unmatched, it is no FN), and an unmatched tracker box
lower than 25 px or covering a DontCare region by more than half its area is no FP.

CLEAR MOT over all sequences: ``MOTA = 1 - (FN + FP + IDS) / n_gt``, ``MOTP`` the mean similarity of the TPs;
IDS counts a ground-truth track matched in two consecutive frames to different tracker ids; FRAG counts the
times its tracking resumes after an interruption. AB3DMOT's recall-integrated metrics, with L = 40:

    sMOTA_r = clip(1 - (FN + FP + IDS - (1 - r) n_gt) / (r n_gt), 0, 1)     at threshold t_r
    sAMOTA = sum_r sMOTA_r / L,  AMOTA = sum_r MOTA_r / L,  AMOTP = sum_r MOTP_r / L

for r = 1/L .. L/L, with t_r the lowest TP score (of the run without threshold) that reaches recall r; a
recall the tracker never reaches contributes 0 (the sum is still divided by L, as the script does).
MOTA, MOTP, IDS, FRAG, FP and FN are then reported at the best single threshold: the t_r with the highest
MOTA (the script's choice among its sampled thresholds). A class without scored ground truth in the sequences
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
CLASSES = {"car": ("Car", ("Van",)), "pedestrian": ("Pedestrian", ("Person_sitting",)), "cyclist": ("Cyclist", ())}
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
        table[cls] = rows | best[1] | {"threshold": best[0], "GT": n_gt}
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
    result: np.ndarray = np.c_[flu.center, flu.size_lwh, flu.yaw()]
    return result


def _intersection(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0])
    h = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1])
    result: np.ndarray = np.clip(w, 0, None) * np.clip(h, 0, None)
    return result


def _count(frames: list[_Frame], threshold: float) -> _Counts:
    tp = fp = fn = ids = frag = 0
    similarity_sum = 0.0
    tp_scores = []
    last_match: dict[tuple[str, int], int] = {}   # gt track -> tracker id in the previous frame (-1: missed)
    was_tracked: dict[tuple[str, int], bool] = {}
    for fr in frames:
        use = fr.tr_scores >= threshold
        sim = fr.similarity[:, use]
        matched_gt = np.full(len(fr.gt_ids), -1)
        tr_matched = np.zeros(int(use.sum()), bool)
        if sim.size and sim.max() > 0:
            r, c = linear_sum_assignment(-sim)
            ok = sim[r, c] > 0
            matched_gt[r[ok]] = c[ok]
            tr_matched[c[ok]] = True
        tr_ids, tr_scores, no_fp = fr.tr_ids[use], fr.tr_scores[use], fr.tr_no_fp[use]
        counted = ~fr.gt_ignored
        hit = counted & (matched_gt >= 0)
        tp += int(hit.sum())
        fn += int((counted & (matched_gt < 0)).sum())
        similarity_sum += float(sim[np.flatnonzero(hit), matched_gt[hit]].sum())
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
