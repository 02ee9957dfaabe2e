"""KITTI label files: object (``label_2/000000.txt``, 15 fields) and tracking (``label_02/0001.txt``, 17 fields),
each with an optional trailing score (results files), read into columns with one problem per unreadable line."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from avdata.errors import InputError

#: Label columns after the class (object) or frame, track id and class (tracking).
_BOX_FIELDS = 14


@dataclass(frozen=True, slots=True, kw_only=True)
class KittiLabels:
    """Label lines as columns (N rows, DontCare included).

    Attributes:
        line: (N,) 1-based line numbers in the file.
        frame: (N,) frame numbers (tracking), or all -1 (object).
        track_id: (N,) track ids (tracking; -1 for DontCare), or all -1 (object).
        cls: (N,) KITTI class strings, verbatim.
        truncated: (N,) object: fraction 0..1; tracking: level 0, 1, 2.
        occluded: (N,) 0 visible, 1 partly, 2 largely occluded, 3 unknown (-1 for DontCare).
        alpha: (N,) observation angle, radians.
        bbox: (N, 4) left, top, right, bottom in pixels.
        hwl: (N, 3) height, width, length in metres.
        location: (N, 3) bottom centre in rectified camera 0, metres.
        rotation_y: (N,) rotation about camera y, radians.
    """

    line: np.ndarray
    frame: np.ndarray
    track_id: np.ndarray
    cls: np.ndarray
    truncated: np.ndarray
    occluded: np.ndarray
    alpha: np.ndarray
    bbox: np.ndarray
    hwl: np.ndarray
    location: np.ndarray
    rotation_y: np.ndarray

    def __len__(self) -> int:
        return int(self.line.shape[0])

    def select(self, mask: np.ndarray) -> KittiLabels:
        """The rows where ``mask`` (N,) is true."""
        return KittiLabels(**{name: getattr(self, name)[mask] for name in self.__slots__})


@dataclass(frozen=True, slots=True, kw_only=True)
class LabelProblem:
    """A label line that cannot be read: its line number, frame (tracking, -1 unknown) and why."""

    line: int
    frame: int
    message: str


def read_labels(path: Path, tracking: bool) -> tuple[KittiLabels, list[LabelProblem]]:
    """Reads ``label_2/000000.txt`` (object, 15 fields; 16 with a score) or ``label_02/0001.txt``
    (tracking, 17 fields; 18 with a score).

    Returns:
        The readable lines as columns, and one problem per unreadable line.
    """
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(f"{path}: unreadable ({error})") from error
    lead = 3 if tracking else 1
    expected = lead + _BOX_FIELDS
    rows: list[tuple[int, int, int, str, list[float]]] = []
    problems: list[LabelProblem] = []
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        if not fields:
            continue
        frame = -1
        if tracking:
            try:
                frame = int(fields[0])
            except ValueError:
                frame = -1
        if len(fields) not in (expected, expected + 1):
            problems.append(LabelProblem(line=number, frame=frame, message=(
                f"line {number}: expected {expected} fields ({expected + 1} with a score), got {len(fields)}")))
            continue
        try:
            numbers = [float(v) for v in fields[lead : lead + _BOX_FIELDS]]
            track = int(fields[1]) if tracking else -1
        except ValueError:
            problems.append(LabelProblem(line=number, frame=frame, message=(
                f"line {number}: expected numbers after the class, got {' '.join(fields[lead:])!r}")))
            continue
        if tracking and frame < 0:
            problems.append(LabelProblem(line=number, frame=frame, message=(
                f"line {number}: expected a non-negative frame number, got {fields[0]!r}")))
            continue
        rows.append((number, frame, track, fields[lead - 1], numbers))
    values = np.array([r[4] for r in rows], dtype=np.float64).reshape(-1, _BOX_FIELDS)
    labels = KittiLabels(
        line=np.array([r[0] for r in rows], dtype=np.int64),
        frame=np.array([r[1] for r in rows], dtype=np.int64),
        track_id=np.array([r[2] for r in rows], dtype=np.int64),
        cls=np.array([r[3] for r in rows], dtype=str),
        truncated=values[:, 0],
        occluded=values[:, 1].astype(np.int64),
        alpha=values[:, 2],
        bbox=values[:, 3:7],
        hwl=values[:, 7:10],
        location=values[:, 10:13],
        rotation_y=values[:, 13],
    )
    return labels, problems


