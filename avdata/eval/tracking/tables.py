"""Rows of a tracking benchmark file, and the steps KITTI and MOTChallenge preprocessing share."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from avdata.errors import InputError
from avdata.eval import geometry
from avdata.eval.matching import max_weight_matching, overlapping_pairs
from avdata.eval.names import Similarity
from avdata.eval.problems import warn
from avdata.eval.tracking.sequence import TrackingSequence
from avdata.inputs import is_present, require_file, require_folder

__all__ = [
    "TrackTable",
    "check_unique_ids",
    "empty_table",
    "ignored_tracker_files",
    "matched_at_half",
    "read_rows",
    "sequence_2d",
    "tracker_file",
]

_EPS = np.finfo(np.float64).eps


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
        """The rows at ``index`` ((K,) integer or (N,) bool); the DontCare regions stay."""
        keep = {k: getattr(self, k)[index] for k in ("frame", "track_id", "class_id", "box", "truncation",
                                                      "occlusion", "consider")}
        return TrackTable(**keep, ignore_region=self.ignore_region, ignore_frame=self.ignore_frame)




    def sorted_by_frame(self) -> TrackTable:
        """The rows in frame order (stable)."""
        return self.take(np.argsort(self.frame, kind="stable"))


def empty_table() -> TrackTable:
    """A table with no rows (a sequence without any object)."""
    z = np.zeros(0, dtype=np.int64)
    return TrackTable(frame=z, track_id=z, class_id=z, box=np.zeros((0, 4)), truncation=z, occlusion=z, consider=z,
                      ignore_region=np.zeros((0, 4)), ignore_frame=z)


def read_rows(path: Path, what: str) -> list[list[str]]:
    """Whitespace- or comma-separated fields of every non-empty line (the delimiter is the first line's).

    Args:
        path: the file.
        what: what the file is, for the error message ("tracker file", "ground-truth file").

    Returns:
        The fields of each non-empty line; line numbers are kept by the caller through ``line_numbers``.
    """
    require_file(path, what)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: expected UTF-8 text, got byte {exc.object[exc.start]:#04x} at offset {exc.start}") from None
    delimiter = "," if "," in text.split("\n", 1)[0] else None
    return [[f.strip() for f in line.split(delimiter)] if line.strip() else [] for line in text.splitlines()]


def check_unique_ids(path: Path, frame: np.ndarray, track_id: np.ndarray, frame_base: int) -> None:
    """Refuses a track id used twice in one frame (TrackEval's ``_check_unique_ids``), naming file and frame.

    Args:
        path: the file.
        frame: (N,) 0-based frame of each row.
        track_id: (N,) track id of each row.
        frame_base: how the file numbers frames (0 for KITTI, 1 for MOTChallenge), for the message.
    """
    if len(frame) < 2:
        return
    order = np.lexsort((track_id, frame))
    f, i = frame[order], track_id[order]
    dup = np.flatnonzero((f[1:] == f[:-1]) & (i[1:] == i[:-1]))
    if len(dup):
        k = dup[0]
        raise InputError(f"{path}: frame {f[k] + frame_base}: expected each track id once per frame, got id {i[k]} "
                         f"{int(np.sum((f == f[k]) & (i == i[k])))} times")


def tracker_file(tracker_folder: Path, seq: str) -> Path:
    """The tracker's file of ``seq``; a missing one is an error, as in TrackEval ("Tracker file not found").

    Args:
        tracker_folder: folder of ``<seq>.txt`` files.
        seq: sequence name.

    Returns:
        The path.
    """
    path = tracker_folder / f"{seq}.txt"
    if is_present(path):
        require_file(path, "tracker file")  # a folder or FIFO is said as such
        return path
    require_folder(tracker_folder, "folder of tracker result files <seq>.txt")
    hint = ""
    if (tracker_folder / "data" / f"{seq}.txt").is_file():
        hint = f" (the results are in {tracker_folder / 'data'}; pass that folder)"
    raise InputError(f"{path}: expected the tracker file of sequence {seq}, got no such file{hint}")


def ignored_tracker_files(tracker_folder: Path, sequences: list[str]) -> None:
    """Warns about tracker ``*.txt`` files of sequences that are not evaluated.

    Args:
        tracker_folder: folder of tracker files.
        sequences: the evaluated sequence names.
    """
    extra = sorted(p.name for p in tracker_folder.glob("*.txt") if p.stem not in set(sequences))
    if extra:
        shown = ", ".join(extra[:5]) + (f" and {len(extra) - 5} more" if len(extra) > 5 else "")
        warn(f"{tracker_folder}: ignored {len(extra)} tracker file(s) of sequences not in the seqmap: {shown}")


def matched_at_half(gt: TrackTable, tr: TrackTable) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame Hungarian matches with IoU >= 0.5 (frame-sorted tables).

    Args:
        gt: ground-truth rows, frame-sorted.
        tr: tracker rows, frame-sorted.

    Returns:
        (K,) ground-truth indices and (K,) tracker indices of the matches.
    """
    pg, pd = overlapping_pairs(gt.frame, gt.box, tr.frame, tr.box)
    iou = geometry.box2d_iou(gt.box[pg], tr.box[pd], paired=True)
    weight = np.where(iou >= 0.5 - _EPS, iou, 0.0)
    n_frames = int(max(gt.frame.max(initial=-1), tr.frame.max(initial=-1))) + 1
    gt_offsets, tr_offsets = (np.searchsorted(t.frame, np.arange(n_frames + 1)) for t in (gt, tr))
    matched = max_weight_matching(gt.frame[pg], pg, pd, weight, gt_offsets, tr_offsets)
    return pg[matched], pd[matched]


def sequence_2d(gt: TrackTable, tr: TrackTable, num_frames: int) -> TrackingSequence:
    """The tracking sequence of two tables compared by 2D IoU.

    Args:
        gt: ground-truth rows.
        tr: tracker rows.
        num_frames: T.

    Returns:
        The sequence.
    """
    return TrackingSequence.from_boxes(
        num_frames=num_frames, gt_frame=gt.frame, gt_id=gt.track_id, gt_boxes=gt.box,
        tracker_frame=tr.frame, tracker_id=tr.track_id, tracker_boxes=tr.box, similarity=Similarity.IOU_2D,
    )
