"""Tracking benchmark protocols: KITTI tracking (TrackEval's ``Kitti2DBox``) and MOTChallenge (``MotChallenge2DBox``).

Both read the benchmark's text files and apply TrackEval 1.3.0's preprocessing before the metrics:

KITTI (per class, ``car`` or ``pedestrian``): ground truth of the class and of its distractor class (``van``
for car, ``person`` for pedestrian) is kept for matching; tracker boxes of the class are matched per frame
to it (IoU >= 0.5, Hungarian); tracker boxes matched to a distractor, or to a ground truth with occlusion > 2
or truncation > 0, are removed; unmatched tracker boxes no taller than 25 px, or covering a DontCare region
by more than half their own area, are removed; then only ground truth of the class with occlusion <= 2 and
truncation <= 0 remains. Rows with negative track ids are dropped (DontCare rows are read first).

MOTChallenge (pedestrian): tracker boxes matched (IoU >= 0.5, Hungarian) to ground truth of a distractor
class (person on vehicle, static person, distractor, reflection; non-MOT vehicle for MOT20) are removed;
ground truth is kept where its class is pedestrian and its 'consider' flag is not 0.
"""

from __future__ import annotations

import configparser
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from avdata.errors import InputError
from avdata.eval import geometry
from avdata.eval.tracking import Similarity, TrackingSequence, _max_weight_matching, _overlapping_pairs

__all__ = [
    "KITTI_TRACKING_CLASSES",
    "TrackTable",
    "kitti_tracking_sequences",
    "mot_sequences",
    "read_kitti_tracking",
    "read_mot",
]

_EPS = np.finfo(np.float64).eps
KITTI_TRACKING_CLASSES = ("car", "pedestrian")
_KITTI_CLASS_ID = {"car": 1, "van": 2, "truck": 3, "pedestrian": 4, "person": 5, "cyclist": 6, "tram": 7,
                   "misc": 8, "dontcare": 9, "car_2": 1}
_KITTI_DISTRACTOR = {"car": 2, "pedestrian": 5}
_MOT_DISTRACTORS = (2, 7, 8, 12)
_MOT20_EXTRA_DISTRACTOR = 6


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackTable:
    """Rows of one tracking file.

    Attributes:
        frame: (N,) 0-based frame index.
        track_id: (N,) track id.
        class_id: (N,) benchmark class id.
        box: (N, 4) image box (x0, y0, x1, y1).
        truncation: (N,) truncation (KITTI, integer levels); zeros elsewhere.
        occlusion: (N,) occlusion (KITTI) ; zeros elsewhere.
        consider: (N,) MOTChallenge's 'consider' flag (ground truth); ones elsewhere.
        ignore_region: (R, 4) DontCare boxes, with ``ignore_frame`` (R,).
        ignore_frame: (R,) frame of each DontCare box.
    """

    frame: np.ndarray
    track_id: np.ndarray
    class_id: np.ndarray
    box: np.ndarray
    truncation: np.ndarray
    occlusion: np.ndarray
    consider: np.ndarray
    ignore_region: np.ndarray
    ignore_frame: np.ndarray

    def take(self, index: np.ndarray) -> TrackTable:
        keep = {k: getattr(self, k)[index] for k in ("frame", "track_id", "class_id", "box", "truncation",
                                                      "occlusion", "consider")}
        return TrackTable(**keep, ignore_region=self.ignore_region, ignore_frame=self.ignore_frame)


def _read_rows(path: Path) -> list[list[str]]:
    if not path.is_file():
        raise InputError(f"{path}: expected a tracking file, got no such file")
    text = path.read_text()
    delimiter = "," if "," in text.split("\n", 1)[0] else None
    return [[f.strip() for f in line.split(delimiter)] for line in text.splitlines() if line.strip()]


def read_kitti_tracking(path: str | Path, num_frames: int) -> TrackTable:
    """Reads a KITTI tracking label or result file (``frame id type trunc occ alpha x0 y0 x1 y1 ...``)."""
    path = Path(path)
    rows = _read_rows(path)
    keep, ignore = [], []
    for n, row in enumerate(rows, start=1):
        if len(row) < 10:
            raise InputError(f"{path}:{n}: expected at least 10 fields, got {len(row)}")
        name = row[2].lower()
        if name not in _KITTI_CLASS_ID:
            raise InputError(f"{path}:{n}: type: expected one of {sorted(_KITTI_CLASS_ID)}, got {row[2]!r}")
        try:
            values = [float(row[0]), float(row[1]), _KITTI_CLASS_ID[name], float(row[3]), float(row[4]),
                      *map(float, row[6:10])]
        except ValueError:
            raise InputError(f"{path}:{n}: expected numeric frame, id, truncation, occlusion, box, got {row[:10]}") from None
        if name == "dontcare":
            ignore.append(values)
        elif values[1] >= 0:
            keep.append(values)
    data = np.array(keep, dtype=np.float64).reshape(-1, 9)
    ign = np.array(ignore, dtype=np.float64).reshape(-1, 9)
    frames = np.r_[data[:, 0], ign[:, 0]].astype(np.int64)
    if len(frames) and (frames.min() < 0 or frames.max() >= num_frames):
        raise InputError(f"{path}: frame: expected frames in [0, {num_frames}), got {frames.min()}..{frames.max()}")
    return TrackTable(
        frame=data[:, 0].astype(np.int64), track_id=data[:, 1].astype(np.int64), class_id=data[:, 2].astype(np.int64),
        box=data[:, 5:9], truncation=data[:, 3].astype(np.int64), occlusion=data[:, 4].astype(np.int64),
        consider=np.ones(len(data), dtype=np.int64), ignore_region=ign[:, 5:9], ignore_frame=ign[:, 0].astype(np.int64),
    )


def read_mot(path: str | Path, num_frames: int, is_gt: bool) -> TrackTable:
    """Reads a MOTChallenge file (``frame, id, x, y, w, h, conf|consider, class, visibility``; frames from 1)."""
    path = Path(path)
    rows = _read_rows(path)
    try:
        data = np.array([[float(v) for v in r[:8]] + [1.0] * (8 - len(r[:8])) for r in rows]).reshape(-1, 8)
    except ValueError:
        raise InputError(f"{path}: expected numeric comma-separated MOTChallenge rows") from None
    if is_gt and any(len(r) < 8 for r in rows):
        raise InputError(f"{path}: expected at least 8 columns in ground truth (class in column 8)")
    frames = data[:, 0].astype(np.int64) - 1
    if len(frames) and (frames.min() < 0 or frames.max() >= num_frames):
        raise InputError(f"{path}: frame: expected frames in [1, {num_frames}], got {frames.min() + 1}..{frames.max() + 1}")
    box = np.c_[data[:, 2:4], data[:, 2:4] + data[:, 4:6]]
    return TrackTable(
        frame=frames, track_id=data[:, 1].astype(np.int64),
        class_id=data[:, 7].astype(np.int64) if is_gt else np.ones(len(data), dtype=np.int64),
        box=box, truncation=np.zeros(len(data), dtype=np.int64), occlusion=np.zeros(len(data), dtype=np.int64),
        consider=data[:, 6].astype(np.int64) if is_gt else np.ones(len(data), dtype=np.int64),
        ignore_region=np.zeros((0, 4)), ignore_frame=np.zeros(0, dtype=np.int64),
    )


def _sorted(table: TrackTable) -> TrackTable:
    return table.take(np.argsort(table.frame, kind="stable"))


def _matched_at_half(gt: TrackTable, tr: TrackTable) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame Hungarian matches with IoU >= 0.5 (frame-sorted tables): (gt index, tracker index)."""
    pg, pd = _overlapping_pairs(gt.frame, gt.box, tr.frame, tr.box)
    iou = geometry.box2d_iou(gt.box[pg], tr.box[pd], paired=True)
    weight = np.where(iou >= 0.5 - _EPS, iou, 0.0)
    matched = _max_weight_matching(gt.frame[pg], pg, pd, weight, len(gt.frame), len(tr.frame))
    return pg[matched], pd[matched]


def _sequence(gt: TrackTable, tr: TrackTable, num_frames: int) -> TrackingSequence:
    return TrackingSequence.from_boxes(
        num_frames=num_frames, gt_frame=gt.frame, gt_id=gt.track_id, gt_boxes=gt.box,
        tracker_frame=tr.frame, tracker_id=tr.track_id, tracker_boxes=tr.box, similarity=Similarity.IOU_2D,
    )


def kitti_tracking_sequences(
    gt_folder: str | Path, tracker_folder: str | Path, classes: tuple[str, ...] = KITTI_TRACKING_CLASSES,
    split: str = "training",
) -> dict[str, dict[str, TrackingSequence]]:
    """Preprocessed sequences of a KITTI tracking evaluation, per class then per sequence.

    Args:
        gt_folder: folder with ``label_02/<seq>.txt`` and ``evaluate_tracking.seqmap.<split>`` (lines
            ``<seq> empty <first> <length>``); without a seqmap every label file is used, its length the last
            labelled frame + 1.
        tracker_folder: folder of ``<seq>.txt`` result files (a missing file means no output).
        classes: ``car`` and / or ``pedestrian``.
        split: seqmap suffix.

    Returns:
        ``{class: {sequence: TrackingSequence}}``.
    """
    gt_folder, tracker_folder = Path(gt_folder), Path(tracker_folder)
    bad = [c for c in classes if c not in KITTI_TRACKING_CLASSES]
    if bad:
        raise InputError(f"classes: expected a subset of {KITTI_TRACKING_CLASSES}, got {bad}")
    seqmap = gt_folder / f"evaluate_tracking.seqmap.{split}"
    lengths: dict[str, int | None] = {}
    if seqmap.is_file():
        for line in seqmap.read_text().splitlines():
            parts = line.split()
            if len(parts) >= 4:
                lengths[parts[0]] = int(parts[3])
    else:
        lengths = {p.stem: None for p in sorted((gt_folder / "label_02").glob("*.txt"))}
    if not lengths:
        raise InputError(f"{gt_folder}: expected label_02/*.txt or {seqmap.name}, got neither")
    out: dict[str, dict[str, TrackingSequence]] = {c: {} for c in classes}
    for seq, length in lengths.items():
        label = gt_folder / "label_02" / f"{seq}.txt"
        if length is None:
            frames = [int(float(r[0])) for r in _read_rows(label)]
            length = max(frames) + 1 if frames else 0
        gt_all = _sorted(read_kitti_tracking(label, length))
        tr_file = tracker_folder / f"{seq}.txt"
        tr_all = _sorted(read_kitti_tracking(tr_file, length)) if tr_file.is_file() else _sorted(
            _empty_table())
        for cls in classes:
            out[cls][seq] = _kitti_preprocess(gt_all, tr_all, cls, length)
    return out


def _empty_table() -> TrackTable:
    """A table with no rows (a sequence the tracker produced no file for)."""
    z = np.zeros(0, dtype=np.int64)
    return TrackTable(frame=z, track_id=z, class_id=z, box=np.zeros((0, 4)), truncation=z, occlusion=z, consider=z,
                      ignore_region=np.zeros((0, 4)), ignore_frame=z)


def _kitti_preprocess(gt_all: TrackTable, tr_all: TrackTable, cls: str, num_frames: int) -> TrackingSequence:
    cls_id, distractor = _KITTI_CLASS_ID[cls], _KITTI_DISTRACTOR[cls]
    gt = gt_all.take(np.flatnonzero(np.isin(gt_all.class_id, [cls_id, distractor])))
    tr = tr_all.take(np.flatnonzero(tr_all.class_id == cls_id))
    mg, md = _matched_at_half(gt, tr)
    bad_match = (gt.class_id[mg] == distractor) | (gt.occlusion[mg] > 2 + _EPS) | (gt.truncation[mg] > 0 + _EPS)
    remove = np.zeros(len(tr.frame), dtype=bool)
    remove[md[bad_match]] = True
    unmatched = np.ones(len(tr.frame), dtype=bool)
    unmatched[md] = False
    too_small = (tr.box[:, 3] - tr.box[:, 1]) <= 25 + _EPS
    in_dontcare = np.zeros(len(tr.frame), dtype=bool)
    if len(gt_all.ignore_frame):
        order = np.argsort(gt_all.ignore_frame, kind="stable")
        reg_frame, reg_box = gt_all.ignore_frame[order], gt_all.ignore_region[order]
        pd, pr = _overlapping_pairs(tr.frame, tr.box, reg_frame, reg_box)
        a, r = tr.box[pd], reg_box[pr]
        iw = np.maximum(np.minimum(a[:, 2], r[:, 2]) - np.maximum(a[:, 0], r[:, 0]), 0)
        ih = np.maximum(np.minimum(a[:, 3], r[:, 3]) - np.maximum(a[:, 1], r[:, 1]), 0)
        area = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
        ioa = np.divide(iw * ih, area, out=np.zeros(len(pd)), where=area > _EPS)
        in_dontcare[pd[ioa > 0.5 + _EPS]] = True
    remove |= unmatched & (too_small | in_dontcare)
    keep_gt = (gt.occlusion <= 2) & (gt.truncation <= 0) & (gt.class_id == cls_id)
    return _sequence(gt.take(np.flatnonzero(keep_gt)), tr.take(np.flatnonzero(~remove)), num_frames)


def mot_sequences(
    gt_folder: str | Path, tracker_folder: str | Path, mot20: bool = False
) -> dict[str, TrackingSequence]:
    """Preprocessed pedestrian sequences of a MOTChallenge evaluation.

    Args:
        gt_folder: folder of ``<seq>/gt/gt.txt`` with ``<seq>/seqinfo.ini`` (``seqLength``).
        tracker_folder: folder of ``<seq>.txt`` files.
        mot20: add MOT20's non-MOT-vehicle distractor class.

    Returns:
        ``{sequence: TrackingSequence}``.
    """
    gt_folder, tracker_folder = Path(gt_folder), Path(tracker_folder)
    seqs = sorted(p.parent.parent.name for p in gt_folder.glob("*/gt/gt.txt"))
    if not seqs:
        raise InputError(f"{gt_folder}: expected <seq>/gt/gt.txt files, got none")
    distractors = _MOT_DISTRACTORS + ((_MOT20_EXTRA_DISTRACTOR,) if mot20 else ())
    out = {}
    for seq in seqs:
        ini = configparser.ConfigParser()
        ini.read(gt_folder / seq / "seqinfo.ini")
        try:
            length = int(ini["Sequence"]["seqLength"])
        except KeyError:
            raise InputError(f"{gt_folder / seq / 'seqinfo.ini'}: expected [Sequence] seqLength, got none") from None
        gt = _sorted(read_mot(gt_folder / seq / "gt" / "gt.txt", length, is_gt=True))
        tr_file = tracker_folder / f"{seq}.txt"
        tr = _sorted(read_mot(tr_file, length, is_gt=False)) if tr_file.is_file() else _empty_table()
        mg, md = _matched_at_half(gt, tr)
        remove = np.zeros(len(tr.frame), dtype=bool)
        remove[md[np.isin(gt.class_id[mg], distractors)]] = True
        keep_gt = (gt.consider != 0) & (gt.class_id == 1)
        out[seq] = _sequence(gt.take(np.flatnonzero(keep_gt)), tr.take(np.flatnonzero(~remove)), length)
    return out
