"""AB3DMOT's KITTI 3D MOT protocol (``scripts/KITTI/evaluate.py`` of xinshuoweng/AB3DMOT), from its formulas.

Per class (``car``: GT ``Car``, ``Van`` its neighbour; ``pedestrian``: GT ``Pedestrian``, KITTI tracking's
``Person`` (a sitting person; ``Person_sitting`` in KITTI object) its neighbour, where the script's substring test
``"person_sitting" in "person"`` drops every ``Person`` line; ``cyclist``: GT ``Cyclist``) and sequence:

- a track's score is the mean score of all its boxes in the sequence, and a threshold keeps or drops whole
  tracks (the script replaces every box's score by its track's mean before thresholding);
- frame by frame, the kept tracker boxes of the class and its neighbour are matched to ground truth of the class
  and its neighbour by Hungarian assignment on ``1 - similarity`` (2D IoU of the image boxes, or 3D IoU),
  pairs below ``min_similarity`` forbidden (the most matches first, then the least cost, as the script's
  Munkres with cost 1e9 on forbidden pairs);
- as in the KITTI devkit, ground truth occluded > 2, truncated > 0 or of the neighbour class is ignored (a
  match to it is no TP, unmatched it is no FN); ground truth is not filtered by height; an unmatched tracker
  box of the neighbour class, at most 25 px high, or covering a DontCare region by more than half its area
  is no FP.

CLEAR MOT over all sequences: ``MOTA = 1 - (FN + FP + IDS) / n_gt``; ``MOTP`` the mean similarity of all
matches, those to ignored ground truth included (the devkit's ``total_cost / tp``). IDS and FRAG are the
devkit's, per ground-truth trajectory (its frames in order, ignored ones included): an IDS where it is
matched in this and the previous of its frames to different tracker ids, the previous one not ignored (or
the trajectory's first); a FRAG where its match changes (from none or another id) at a non-ignored frame,
tracked since the last ignored frame, and the next frame is tracked too (at the last frame, the change alone).

AB3DMOT's recall-integrated metrics, with L = 40:

    sMOTA_r = clip(1 - (FN + FP + IDS - (1 - r) n_gt) / (r n_gt), 0, 1)     at threshold t_r
    sAMOTA = sum_r sMOTA_r / L,  AMOTA = sum_r MOTA_r / L,  AMOTP = sum_r MOTP_r / L

over the script's recall points: the scores of the matches of the run without a threshold (those to ignored
ground truth included), sorted descending; the k-th point r = k / L takes the first score whose recall
``i / m`` (m = matches + FN) is the nearest to r; a recall the tracker never reaches contributes 0 (the sum is
still divided by L). MOTA, MOTP, IDS, FRAG, FP and FN are reported at the best single threshold as the
definition says: the track score, among all of the class's track scores, with the highest MOTA (the highest
such score on a tie). The script instead takes the best of its sampled t_r with a MOTA above 0 (else no
threshold at all); that MOTA and threshold are given too (``script_MOTA``, ``script_threshold``). A class
without scored ground truth in the sequences (e.g. Cyclist in KITTI val 0001, 0006, 0008) is a warning, and
its metrics are NaN.
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
_MAX_IGNORED_HEIGHT_PX = 25.0
#: The object types of KITTI's tracking labels, lower-cased as AB3DMOT compares them.
_KITTI_TYPES = ("car", "van", "truck", "pedestrian", "person", "person_sitting", "cyclist", "tram", "misc", "dontcare")
_FORBIDDEN = 1e9  # the script's cost of a pair below the similarity threshold


@dataclass(frozen=True, slots=True)
class _Counts:
    tp: int                 # matches to counted ground truth
    matches: int            # all matches, those to ignored ground truth included
    fp: int
    fn: int
    ids: int
    frag: int
    similarity_sum: float   # over all matches
    match_scores: np.ndarray

    def metrics(self) -> dict[str, float]:
        n_gt = self.tp + self.fn
        return {"MOTA": 1.0 - (self.fn + self.fp + self.ids) / n_gt if n_gt else float("nan"),
                "MOTP": self.similarity_sum / self.matches if self.matches else 0.0, "IDS": self.ids,
                "FRAG": self.frag, "FP": self.fp, "FN": self.fn, "TP": self.tp}


@dataclass(frozen=True, slots=True, kw_only=True)
class Kitti3dmotResult:
    """Per class: sAMOTA, AMOTA, AMOTP and, at the best threshold, MOTA, MOTP, IDS, FRAG, FP, FN, TP, threshold."""

    table: dict[str, dict[str, float]]


def evaluate_kitti_3dmot(gt_folder: Path, tracker_folder: Path, sequences: dict[str, int],
                         classes: tuple[str, ...] = ("car", "pedestrian", "cyclist"), similarity: str = "2d",
                         min_similarity: float = 0.5) -> Kitti3dmotResult:
    """AB3DMOT's KITTI evaluation of ``tracker_folder/<seq>.txt`` against ``gt_folder/label_02/<seq>.txt``.

    Args:
        gt_folder: folder with ``label_02/<seq>.txt``.
        tracker_folder: KITTI tracking results with a score column.
        sequences: the sequences to evaluate (each must have both files) -> their number of frames T, as
            :func:`~avdata.eval.tracking.kitti.read_kitti_seqmap` reads them; every frame must be in [0, T).
        classes: subset of ``car``, ``pedestrian``, ``cyclist``.
        similarity: ``2d`` (image boxes) or ``3d`` (3D IoU).
        min_similarity: least similarity of a match (AB3DMOT: 0.5 in 2D; 0.25, 0.5 or 0.7 in 3D).
    """
    if similarity not in ("2d", "3d") or not 0.0 < min_similarity <= 1.0:
        raise InputError(f"kitti-3dmot: expected similarity 2d or 3d and a threshold in (0, 1], got {similarity!r}, "
                         f"{min_similarity}")
    if bad := [c for c in classes if c not in CLASSES]:
        raise InputError(f"kitti-3dmot: expected classes among {sorted(CLASSES)}, got {bad}")
    data = {seq: (_read(Path(gt_folder) / "label_02" / f"{seq}.txt", False, n_frames),
                  _read(Path(tracker_folder) / f"{seq}.txt", True, n_frames)) for seq, n_frames in sequences.items()}
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
        rows = {"sAMOTA": 0.0, "AMOTA": 0.0, "AMOTP": 0.0}
        # the script starts from MOTA 0 with no threshold, and keeps a sampled threshold only above that
        script_best, script_mota = (-np.inf, everything.metrics()), 0.0
        for threshold, r in _recall_points(everything.match_scores, everything.matches + everything.fn):
            m = _count(frames, threshold).metrics()
            rows["sAMOTA"] += min(1.0, max(0.0, 1 - (m["FN"] + m["FP"] + m["IDS"] - (1 - r) * n_gt) / (r * n_gt))) / _L
            rows["AMOTA"] += m["MOTA"] / _L
            rows["AMOTP"] += m["MOTP"] / _L
            if m["MOTA"] > script_mota:
                script_best, script_mota = (threshold, m), m["MOTA"]
        candidates = np.unique(np.concatenate([f.tr_scores for f in frames]))
        mota = _mota_by_threshold(frames, candidates, n_gt)
        at = len(mota) - 1 - int(np.argmax(mota[::-1])) if len(mota) else -1  # a tie goes to the highest score
        best = (float(candidates[at]), _count(frames, float(candidates[at])).metrics()) if at >= 0 else script_best
        table[cls] = rows | best[1] | {"threshold": best[0], "GT": n_gt, "script_MOTA": script_best[1]["MOTA"],
                                       "script_threshold": script_best[0]}
    return Kitti3dmotResult(table=table)


def _recall_points(match_scores: np.ndarray, n_matchable: int) -> list[tuple[float, float]]:
    """The script's (threshold, r) pairs: per r = k / L, the first descending score whose recall is nearest to r."""
    scores = np.sort(match_scores)[::-1]
    points = []
    target = 0
    for i, score in enumerate(scores.tolist()):
        last = i == len(scores) - 1
        left = (i + 1) / n_matchable
        right = left if last else (i + 2) / n_matchable
        r = target / _L
        if not last and right - r < r - left:  # the next score is nearer to r
            continue
        if target > 0:  # the script drops recall 0
            points.append((score, r))
        target += 1
    return points


def _read(path: Path, with_score: bool, n_frames: int) -> KittiLabels:
    if not path.is_file():
        raise InputError(f"{path}: expected a KITTI tracking {'result' if with_score else 'label'} file, got none")
    labels, problems = read_labels(path, tracking=True, with_score=with_score)
    if problems:
        raise InputError(f"{path}: {problems[0].message}")
    unknown = ~np.isin(np.char.lower(labels.cls.astype(str)), _KITTI_TYPES)
    if np.any(unknown):  # AB3DMOT passes over a type it does not evaluate: "Cra" would be boxes lost without a word
        k = int(np.argmax(unknown))
        raise InputError(f"{path}: line {labels.line[k]}: type: expected a KITTI type ({', '.join(_KITTI_TYPES)}, any "
                         f"case), got {str(labels.cls[k])!r}")
    beyond = labels.frame >= n_frames  # the evaluation walks every frame up to the last: 10^9 of them would not end
    if np.any(beyond):
        k = int(np.argmax(beyond))
        raise InputError(f"{path}: line {labels.line[k]}: frame: expected frames in [0, {n_frames}) (the seqmap's "
                         f"length), got {labels.frame[k]}")
    return labels


@dataclass(frozen=True, slots=True)
class _Frame:
    gt_ids: np.ndarray          # (G,) ground-truth track ids (ignored ones included)
    gt_ignored: np.ndarray      # (G,)
    tr_ids: np.ndarray          # (T,)
    tr_scores: np.ndarray       # (T,) the mean score of each box's track in the sequence
    tr_no_fp: np.ndarray        # (T,) unmatched, still no FP (neighbour class, too low, or in a DontCare region)
    similarity: np.ndarray      # (G, T), 0 below the least similarity of a match
    seq: str


def _frames(seq: str, gt: KittiLabels, tr: KittiLabels, cls: str, similarity: str, min_similarity: float) -> list[_Frame]:
    name, neighbours = CLASSES[cls][0].lower(), tuple(n.lower() for n in CLASSES[cls][1])
    # AB3DMOT lower-cases both files' types: a tracker writing "car" is matched (it scored MOTA 0 here, silently).
    gt_cls, tr_cls = np.char.lower(gt.cls.astype(str)), np.char.lower(tr.cls.astype(str))
    gt_keep = np.isin(gt_cls, (name, *neighbours))
    dontcare = gt_cls == "dontcare"
    tr_keep = np.isin(tr_cls, (name, *neighbours))
    track, inverse = np.unique(tr.track_id[tr_keep], return_inverse=True)
    mean_score = np.zeros(len(tr.cls))
    mean_score[tr_keep] = (np.bincount(inverse, weights=tr.score[tr_keep], minlength=len(track))
                           / np.bincount(inverse, minlength=len(track)))[inverse]
    out = []
    last = int(max(gt.frame.max(initial=-1), tr.frame.max(initial=-1)))
    for f in range(last + 1):
        g = np.flatnonzero(gt_keep & (gt.frame == f))
        t = np.flatnonzero(tr_keep & (tr.frame == f))
        ignored = (gt_cls[g] != name) | (gt.occluded[g] > 2) | (gt.truncated[g] > 0)
        if similarity == "2d":
            sim = box2d_iou(gt.bbox[g], tr.bbox[t])
        else:
            sim = box3d_iou(_rows3d(gt, g), _rows3d(tr, t))
        dc = gt.bbox[dontcare & (gt.frame == f)]
        tr_box = tr.bbox[t]
        area = np.clip(tr_box[:, 2] - tr_box[:, 0], 0, None) * np.clip(tr_box[:, 3] - tr_box[:, 1], 0, None)
        inter = _intersection(tr_box, dc)
        in_dontcare = np.any(inter > 0.5 * area[:, None], axis=1) if len(dc) else np.zeros(len(t), bool)
        low = np.abs(tr_box[:, 3] - tr_box[:, 1]) <= _MAX_IGNORED_HEIGHT_PX
        out.append(_Frame(gt.track_id[g], ignored, tr.track_id[t], mean_score[t], low | in_dontcare | (tr_cls[t] != name),
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
    """One frame's matching of ground truth to the tracks scored >= threshold: the most pairs, then the least cost.

    Returns the tracks used, the matched track of each ground-truth box (-1: none; an index among the used
    tracks) and which used tracks matched.
    """
    use = fr.tr_scores >= threshold
    sim = fr.similarity[:, use]
    matched_gt = np.full(len(fr.gt_ids), -1)
    tr_matched = np.zeros(int(use.sum()), bool)
    if sim.size and sim.max() > 0:
        r, c = linear_sum_assignment(np.where(sim > 0, 1.0 - sim, _FORBIDDEN))
        ok = sim[r, c] > 0
        matched_gt[r[ok]] = c[ok]
        tr_matched[c[ok]] = True
    return use, matched_gt, tr_matched


def _id_events(key: np.ndarray, ignored: np.ndarray, tracker_id: np.ndarray) -> tuple[int, int]:
    """The devkit's IDS and FRAG from every ground-truth appearance, sorted by (trajectory, frame).

    ``tracker_id`` is the matched tracker id (-1: none) of each appearance, ignored ones included.
    """
    if not len(key):
        return 0, 0
    first = np.r_[True, key[1:] != key[:-1]]
    last = np.r_[key[1:] != key[:-1], True]
    tracked = tracker_id >= 0
    before = np.r_[-1, tracker_id[:-1]]
    after_tracked = np.r_[tracked[1:], False]
    changed = ~first & (before != tracker_id)
    counted = ~first & ~ignored
    prev_counted = np.r_[True, first[:-1] | ~ignored[:-1]]  # the previous appearance is the first or not ignored
    ids = counted & tracked & (before >= 0) & changed & prev_counted
    # "tracked since the last ignored frame": the latest event before each appearance is a tracked one (the first
    # appearance is an event either way: tracked, or reset)
    event = np.where(first, np.where(tracked, 1, -1), np.where(ignored, -1, np.where(tracked, 1, 0)))
    latest = np.maximum.accumulate(np.where(event != 0, np.arange(len(key)), 0))
    armed = np.r_[False, event[latest[:-1]] > 0]
    frag = counted & tracked & changed & np.where(last, True, armed & after_tracked)
    return int(ids.sum()), int(frag.sum())


def _count(frames: list[_Frame], threshold: float) -> _Counts:
    tp = matches = fp = fn = 0
    similarity_sum = 0.0
    match_scores = []
    key_of: dict[tuple[str, int], int] = {}
    keys: list[int] = []
    ignored: list[np.ndarray] = []
    tracker_ids: list[np.ndarray] = []
    for fr in frames:
        use, matched_gt, tr_matched = _match_frame(fr, threshold)
        tr_ids, tr_scores, no_fp = fr.tr_ids[use], fr.tr_scores[use], fr.tr_no_fp[use]
        hit = matched_gt >= 0
        tp += int((hit & ~fr.gt_ignored).sum())
        matches += int(hit.sum())
        fn += int((~hit & ~fr.gt_ignored).sum())
        similarity_sum += float(fr.similarity[:, use][np.flatnonzero(hit), matched_gt[hit]].sum())
        match_scores.append(tr_scores[matched_gt[hit]])
        fp += int((~tr_matched & ~no_fp).sum())
        keys += [key_of.setdefault((fr.seq, int(g)), len(key_of)) for g in fr.gt_ids.tolist()]
        ignored.append(fr.gt_ignored)
        tracker_ids.append(np.r_[tr_ids, -1][matched_gt])  # index -1 picks the appended "none"
    key = np.asarray(keys, np.int64)
    order = np.argsort(key, kind="stable")  # frames are in order within a sequence
    ids, frag = _id_events(key[order], np.concatenate(ignored)[order] if ignored else np.zeros(0, bool),
                           np.concatenate(tracker_ids)[order].astype(np.int64) if tracker_ids else np.zeros(0, np.int64))
    return _Counts(tp, matches, fp, fn, ids, frag, similarity_sum,
                   np.concatenate(match_scores) if match_scores else np.zeros(0))


def _mota_by_threshold(frames: list[_Frame], thresholds: np.ndarray, n_gt: int) -> np.ndarray:
    """MOTA at each of (K,) thresholds: :func:`_count`'s FN, FP and IDS, vectorised over frames and thresholds.

    In a frame whose positive similarities pair each ground truth and each tracker box at most once (most
    frames), the matching at any threshold is those pairs among the boxes kept, so a ground truth is matched
    iff its box's score >= t; the other frames are matched once per distinct score of their boxes.
    """
    key_of: dict[tuple[str, int], int] = {}
    entry_key: list[int] = []
    entry_id: list[int] = []
    entry_score: list[float] = []
    entry_ignored: list[np.ndarray] = []
    fp_scores: list[np.ndarray] = []
    # per frame with conflicts: (first entry index, (levels,) scores descending, (levels + 1, G) matched tracker
    # ids with every score >= level kept (-1 none), (levels + 1,) FP)
    conflicts: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []
    for fr in frames:
        keys = [key_of.setdefault((fr.seq, int(g)), len(key_of)) for g in fr.gt_ids.tolist()]
        start = len(entry_key)
        entry_key += keys
        entry_ignored.append(fr.gt_ignored)
        positive = fr.similarity > 0
        if positive.size and (positive.sum(axis=0).max() > 1 or positive.sum(axis=1).max() > 1):
            levels = np.unique(fr.tr_scores)[::-1]
            now_levels: list[np.ndarray] = []
            fp_levels: list[int] = []
            for level in (np.inf, *levels.tolist()):
                use, matched_gt, tr_matched = _match_frame(fr, level)
                now_levels.append(np.r_[fr.tr_ids[use], -1][matched_gt])  # index -1 picks the appended "none"
                fp_levels.append(int((~tr_matched & ~fr.tr_no_fp[use]).sum()))
            conflicts.append((start, levels, np.array(now_levels, dtype=np.int64).reshape(len(now_levels), -1),
                              np.array(fp_levels)))
            entry_id += [-1] * len(keys)
            entry_score += [np.inf] * len(keys)
            continue
        has = positive.any(axis=1) if positive.size else np.zeros(len(fr.gt_ids), bool)
        column = np.where(has, np.argmax(positive, axis=1) if positive.size else 0, -1)
        # index -1 picks the appended "unmatched" values
        entry_id += np.r_[fr.tr_ids, -1][column].tolist()
        entry_score += np.r_[fr.tr_scores, np.inf][column].tolist()
        unmatched = ~positive.any(axis=0) if positive.size else np.ones(len(fr.tr_ids), bool)
        fp_scores.append(fr.tr_scores[unmatched & ~fr.tr_no_fp])
    key = np.asarray(entry_key, np.int64)
    ignored = np.concatenate(entry_ignored) if entry_ignored else np.zeros(0, bool)
    tr_id, tr_score = np.asarray(entry_id, np.int64), np.asarray(entry_score, np.float64)
    sequence = np.argsort(key, kind="stable")  # each ground-truth trajectory's frames in order
    fp_sorted = np.sort(np.concatenate(fp_scores)) if fp_scores else np.zeros(0)
    mota = np.empty(len(thresholds))
    for k, t in enumerate(thresholds.tolist()):
        now = np.where(tr_score >= t, tr_id, -1)
        fp = len(fp_sorted) - int(np.searchsorted(fp_sorted, t, side="left"))
        for start, levels, now_by_level, fp_by_level in conflicts:
            level = int(np.sum(levels >= t))
            now[start:start + now_by_level.shape[1]] = now_by_level[level]
            fp += int(fp_by_level[level])
        ids, _ = _id_events(key[sequence], ignored[sequence], now[sequence])
        fn = int(np.sum((now < 0) & ~ignored))
        mota[k] = 1.0 - (fn + fp + ids) / n_gt
    return mota
