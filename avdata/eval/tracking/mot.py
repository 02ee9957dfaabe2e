"""MOTChallenge protocol (TrackEval's ``MotChallenge2DBox``, pedestrians): files, preprocessing, sequences.

Tracker boxes matched (IoU >= 0.5, Hungarian) to ground truth of a distractor class (person on vehicle, static
person, distractor, reflection; non-MOT vehicle for MOT20) are removed; ground truth is kept where its class
is pedestrian and its 'consider' flag is not 0. As in TrackEval, every sequence needs a tracker file, frames
lie in [1, seqLength], and a track id appears once per frame; NaN and non-numeric values are refused.
"""

from __future__ import annotations

import configparser
from pathlib import Path

import numpy as np

from avdata.errors import InputError
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
from avdata.inputs import is_present, require_file
from avdata.schema.limits import MAX_CAMERA_VALUE_PX

__all__ = ["mot_sequences", "read_mot"]

_MOT_DISTRACTORS = (2, 7, 8, 12)
_MOT20_EXTRA_DISTRACTOR = 6
_FIELDS = ("frame", "id", "bb_left", "bb_top", "bb_width", "bb_height", "conf", "class")


def read_mot(path: str | Path, num_frames: int, is_gt: bool) -> TrackTable:
    """Reads a MOTChallenge file (``frame, id, x, y, w, h, conf|consider, class, visibility``; frames from 1).

    Args:
        path: the file.
        num_frames: T (``seqLength``); frames must lie in [1, T].
        is_gt: ground truth (needs the class column 8) or tracker output.

    Returns:
        The rows.
    """
    path = Path(path)
    rows = read_rows(path, "ground-truth file" if is_gt else "tracker file")
    parsed, line_numbers = [], []
    for n, row in enumerate(rows, start=1):
        if not row:
            continue
        if len(row) < (8 if is_gt else 6):
            raise InputError(f"{path}:{n}: expected at least {8 if is_gt else 6} comma-separated fields, got {len(row)}")
        fields = row[:8] + ["1"] * (8 - len(row[:8]))
        parsed.append(parse_numbers(path, n, fields, _FIELDS))
        line_numbers.append(n)
    data = np.array(parsed, dtype=np.float64).reshape(-1, 8)
    lines = np.array(line_numbers, dtype=np.int64)
    used = 8 if is_gt else 6
    require_finite(path, lines, data[:, :used], _FIELDS[:used])
    # int64 casts below would make id 5.2 track 5 and 1e308 some other id; 1e308 px overflowed the IoU
    require_integers(path, lines, data[:, :2], _FIELDS[:2])
    require_within(path, lines, data[:, 2:6], _FIELDS[2:6], MAX_CAMERA_VALUE_PX)
    negative = data[:, 4:6] < 0.0
    if negative.any():  # a box of negative width has a negative area: IoU of any value
        row, col = np.argwhere(negative)[0]
        raise InputError(f"{path}:{lines[row]}: {_FIELDS[4 + col]}: expected a size >= 0, got {data[row, 4 + col]:g}")
    frames = data[:, 0].astype(np.int64) - 1
    if len(frames) and (frames.min() < 0 or frames.max() >= num_frames):
        k = int(np.argmax((frames < 0) | (frames >= num_frames)))
        raise InputError(f"{path}:{lines[k]}: frame: expected frames in [1, {num_frames}], got {frames[k] + 1}")
    track_id = data[:, 1].astype(np.int64)
    check_unique_ids(path, frames, track_id, frame_base=1)
    box = np.c_[data[:, 2:4], data[:, 2:4] + data[:, 4:6]]
    return TrackTable(
        frame=frames, track_id=track_id,
        class_id=data[:, 7].astype(np.int64) if is_gt else np.ones(len(data), dtype=np.int64),
        box=box, truncation=np.zeros(len(data), dtype=np.int64), occlusion=np.zeros(len(data), dtype=np.int64),
        consider=data[:, 6].astype(np.int64) if is_gt else np.ones(len(data), dtype=np.int64),
        ignore_region=np.zeros((0, 4)), ignore_frame=np.zeros(0, dtype=np.int64),
    )



def mot_sequences(
    gt_folder: str | Path, tracker_folder: str | Path, mot20: bool = False
) -> dict[str, TrackingSequence]:
    """Preprocessed pedestrian sequences of a MOTChallenge evaluation.

    Args:
        gt_folder: folder of ``<seq>/gt/gt.txt`` with ``<seq>/seqinfo.ini`` (``seqLength``).
        tracker_folder: folder of ``<seq>.txt`` files, one per sequence (files of other sequences are ignored
            with a warning).
        mot20: add MOT20's non-MOT-vehicle distractor class.

    Returns:
        ``{sequence: TrackingSequence}``.
    """
    gt_folder, tracker_folder = Path(gt_folder), Path(tracker_folder)
    # Not glob("*/gt/gt.txt"): it passes over a broken link, and its sequence would be left out without a word.
    seqs = sorted(p.parent.name for p in gt_folder.glob("*/gt") if is_present(p / "gt.txt"))
    if not seqs:
        raise InputError(f"{gt_folder}: expected <seq>/gt/gt.txt files, got none")
    tracker_files = {seq: tracker_file(tracker_folder, seq) for seq in seqs}
    ignored_tracker_files(tracker_folder, seqs)
    distractors = _MOT_DISTRACTORS + ((_MOT20_EXTRA_DISTRACTOR,) if mot20 else ())
    out = {}
    for seq in seqs:
        ini_path = gt_folder / seq / "seqinfo.ini"
        ini = configparser.ConfigParser()
        require_file(ini_path, "seqinfo.ini")  # configparser skips a missing file and would wait on a FIFO
        try:
            ini.read(ini_path, encoding="utf-8")
            text = ini["Sequence"]["seqLength"].strip()
            if not (text.isascii() and text.isdigit()):
                raise ValueError(f"seqLength = {text!r}")
            length = int(text)
        except (KeyError, ValueError, configparser.Error) as exc:
            raise InputError(f"{ini_path}: expected [Sequence] seqLength = <frames>, got {exc}") from None
        gt = read_mot(gt_folder / seq / "gt" / "gt.txt", length, is_gt=True).sorted_by_frame()
        tr = read_mot(tracker_files[seq], length, is_gt=False).sorted_by_frame()
        mg, md = matched_at_half(gt, tr)
        remove = np.zeros(len(tr.frame), dtype=bool)
        remove[md[np.isin(gt.class_id[mg], distractors)]] = True
        keep_gt = (gt.consider != 0) & (gt.class_id == 1)
        out[seq] = sequence_2d(gt.take(np.flatnonzero(keep_gt)), tr.take(np.flatnonzero(~remove)), length)
    return out
