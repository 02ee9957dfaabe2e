"""KITTI tracking protocol (TrackEval's ``Kitti2DBox``): files, preprocessing, sequences per class.

Per class (``car`` or ``pedestrian``): ground truth of the class and of its distractor class (``van`` for car,
``person`` for pedestrian) is kept for matching; tracker boxes of the class are matched per frame to it
(IoU >= 0.5, Hungarian); tracker boxes matched to a distractor, or to a ground truth with occlusion > 2 or
truncation > 0, are removed; unmatched tracker boxes no taller than 25 px, or covering a DontCare region by
more than half their own area, are removed; then only ground truth of the class with occlusion <= 2 and
truncation <= 0 remains. Rows with negative track ids are dropped (DontCare rows are read first).

Inputs are refused where TrackEval refuses them: no seqmap for the split, a ground-truth or tracker file
missing for a sequence of the seqmap, frames outside the sequence, a track id twice in one frame; and
where TrackEval would compute on garbage: NaN or infinite values, non-numeric fields.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from avdata.errors import InputError
from avdata.eval.matching import overlapping_pairs
from avdata.eval.textfiles import parse_numbers, require_finite, require_integers, require_within
from avdata.eval.tracking.sequence import TrackingSequence
from avdata.eval.tracking.tables import (
    TrackTable,
    check_unique_ids,
    ignored_tracker_files,
    matched_at_half,
    read_rows,
    sequence_2d,
    tracker_file,
)
from avdata.inputs import is_present
from avdata.schema.limits import MAX_CAMERA_VALUE_PX

__all__ = ["KITTI_TRACKING_CLASSES", "kitti_tracking_sequences", "read_kitti_seqmap", "read_kitti_tracking"]

_EPS = np.finfo(np.float64).eps
KITTI_TRACKING_CLASSES = ("car", "pedestrian")
_KITTI_CLASS_ID = {"car": 1, "van": 2, "truck": 3, "pedestrian": 4, "person": 5, "cyclist": 6, "tram": 7,
                   "misc": 8, "dontcare": 9, "car_2": 1}
_KITTI_DISTRACTOR = {"car": 2, "pedestrian": 5}
_FIELDS = ("frame", "track id", "truncated", "occluded", "bbox left", "bbox top", "bbox right", "bbox bottom")


def read_kitti_tracking(path: str | Path, num_frames: int, what: str = "tracking file") -> TrackTable:
    """Reads a KITTI tracking label or result file (``frame id type trunc occ alpha x0 y0 x1 y1 ...``).

    Args:
        path: the file.
        num_frames: T; every frame must be in [0, T).
        what: "ground-truth file" or "tracker file", for messages.

    Returns:
        The rows with a non-negative track id, and the DontCare regions.
    """
    path = Path(path)
    rows = read_rows(path, what)
    parsed, names, line_numbers = [], [], []
    for n, row in enumerate(rows, start=1):
        if not row:
            continue
        if len(row) < 10:
            raise InputError(f"{path}:{n}: expected at least 10 fields, got {len(row)}")
        name = row[2].lower()
        if name not in _KITTI_CLASS_ID:
            raise InputError(f"{path}:{n}: type: expected one of {sorted(_KITTI_CLASS_ID)}, got {row[2]!r}")
        fields = [row[0], row[1], row[3], row[4], *row[6:10]]
        parsed.append(parse_numbers(path, n, fields, _FIELDS))
        names.append(name)
        line_numbers.append(n)
    values = np.array(parsed, dtype=np.float64).reshape(-1, len(_FIELDS))
    lines = np.array(line_numbers, dtype=np.int64)
    require_finite(path, lines, values, _FIELDS)
    # frame and track id; TrackEval also reads the ground truth's truncation and occlusion levels as integers
    checked = 4 if what == "ground-truth file" else 2
    require_integers(path, lines, values[:, :checked], _FIELDS[:checked])
    require_within(path, lines, values[:, 2:], _FIELDS[2:], MAX_CAMERA_VALUE_PX)  # 1e308 px overflowed the IoU
    frame = values[:, 0].astype(np.int64)
    if len(frame) and (frame.min() < 0 or frame.max() >= num_frames):
        k = int(np.argmax((frame < 0) | (frame >= num_frames)))
        raise InputError(f"{path}:{lines[k]}: frame: expected frames in [0, {num_frames}), got {frame[k]}")
    class_id = np.array([_KITTI_CLASS_ID[n] for n in names], dtype=np.int64)
    dontcare = class_id == _KITTI_CLASS_ID["dontcare"]
    keep = ~dontcare & (values[:, 1] >= 0)
    check_unique_ids(path, frame[keep], values[keep, 1].astype(np.int64), frame_base=0)
    return TrackTable(
        frame=frame[keep], track_id=values[keep, 1].astype(np.int64), class_id=class_id[keep],
        box=values[keep, 4:8], truncation=values[keep, 2].astype(np.int64), occlusion=values[keep, 3].astype(np.int64),
        consider=np.ones(int(keep.sum()), dtype=np.int64), ignore_region=values[dontcare, 4:8],
        ignore_frame=frame[dontcare],
    )



def read_kitti_seqmap(gt_folder: str | Path, split: str) -> dict[str, int]:
    """Sequence -> number of frames from ``<gt_folder>/evaluate_tracking.seqmap.<split>``.

    Lines read ``<seq> empty <first frame> <length>``, as TrackEval's KITTI seqmaps.

    Args:
        gt_folder: the ground-truth folder.
        split: seqmap suffix (``training``, ``val``, ...).

    Returns:
        Sequence name -> T, in seqmap order.
    """
    gt_folder = Path(gt_folder)
    seqmap = gt_folder / f"evaluate_tracking.seqmap.{split}"
    if not is_present(seqmap):
        found = sorted(p.name.split(".")[-1] for p in gt_folder.glob("evaluate_tracking.seqmap.*"))
        raise InputError(f"{seqmap}: expected the seqmap of split {split!r}, got no such file"
                         + (f" (splits found: {', '.join(found)})" if found else ""))
    lengths: dict[str, int] = {}
    for n, parts in enumerate(read_rows(seqmap, "seqmap"), start=1):
        if not parts:
            continue
        if len(parts) < 4 or not (parts[3].isascii() and parts[3].isdigit()):
            raise InputError(f"{seqmap}:{n}: expected '<seq> empty <first frame> <length>', got {' '.join(parts)!r}")
        if parts[0] in lengths:
            raise InputError(f"{seqmap}:{n}: expected each sequence once, got {parts[0]!r} again")
        lengths[parts[0]] = int(parts[3])
    if not lengths:
        raise InputError(f"{seqmap}: expected at least one sequence, got none")
    return lengths


def kitti_tracking_sequences(
    gt_folder: str | Path, tracker_folder: str | Path, classes: tuple[str, ...] = KITTI_TRACKING_CLASSES,
    split: str = "training",
) -> dict[str, dict[str, TrackingSequence]]:
    """Preprocessed sequences of a KITTI tracking evaluation, per class then per sequence.

    Args:
        gt_folder: folder with ``label_02/<seq>.txt`` and ``evaluate_tracking.seqmap.<split>`` (lines
            ``<seq> empty <first> <length>``).
        tracker_folder: folder of ``<seq>.txt`` result files, one per sequence of the seqmap (an empty file
            is a tracker without output); files of other sequences are ignored with a warning.
        classes: ``car`` and / or ``pedestrian``.
        split: seqmap suffix.

    Returns:
        ``{class: {sequence: TrackingSequence}}``.
    """
    gt_folder, tracker_folder = Path(gt_folder), Path(tracker_folder)
    bad = [c for c in classes if c not in KITTI_TRACKING_CLASSES]
    if bad:
        raise InputError(f"classes: expected a subset of {KITTI_TRACKING_CLASSES}, got {bad}")
    lengths = read_kitti_seqmap(gt_folder, split)
    tracker_files = {seq: tracker_file(tracker_folder, seq) for seq in lengths}
    ignored_tracker_files(tracker_folder, list(lengths))
    out: dict[str, dict[str, TrackingSequence]] = {c: {} for c in classes}
    for seq, length in lengths.items():
        gt_all = read_kitti_tracking(gt_folder / "label_02" / f"{seq}.txt", length, "ground-truth file")
        tr_all = read_kitti_tracking(tracker_files[seq], length, "tracker file")
        for cls in classes:
            out[cls][seq] = _kitti_preprocess(gt_all.sorted_by_frame(), tr_all.sorted_by_frame(), cls, length)
    return out


def _kitti_preprocess(gt_all: TrackTable, tr_all: TrackTable, cls: str, num_frames: int) -> TrackingSequence:
    cls_id, distractor = _KITTI_CLASS_ID[cls], _KITTI_DISTRACTOR[cls]
    gt = gt_all.take(np.flatnonzero(np.isin(gt_all.class_id, [cls_id, distractor])))
    tr = tr_all.take(np.flatnonzero(tr_all.class_id == cls_id))
    mg, md = matched_at_half(gt, tr)
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
        pd, pr = overlapping_pairs(tr.frame, tr.box, reg_frame, reg_box)
        a, r = tr.box[pd], reg_box[pr]
        iw = np.maximum(np.minimum(a[:, 2], r[:, 2]) - np.maximum(a[:, 0], r[:, 0]), 0)
        ih = np.maximum(np.minimum(a[:, 3], r[:, 3]) - np.maximum(a[:, 1], r[:, 1]), 0)
        area = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
        ioa = np.divide(iw * ih, area, out=np.zeros(len(pd)), where=area > _EPS)
        in_dontcare[pd[ioa > 0.5 + _EPS]] = True
    remove |= unmatched & (too_small | in_dontcare)
    keep_gt = (gt.occlusion <= 2) & (gt.truncation <= 0) & (gt.class_id == cls_id)
    return sequence_2d(gt.take(np.flatnonzero(keep_gt)), tr.take(np.flatnonzero(~remove)), num_frames)

