"""KITTI label files, read into columns with one problem per unreadable line.

Object (``label_2/000000.txt``, 15 fields) and tracking (``label_02/0001.txt``, 17 fields), each with
an optional trailing score (results files).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from avdata.inputs import c_floats, c_int, read_text_bytes
from avdata.schema.limits import FLOAT32_MAX, MAX_ANGLE_RAD, MAX_BOX_SIZE_M, MAX_CAMERA_VALUE_PX, MAX_COORDINATE_M
from avdata.storage import Location

#: Label columns after the class (object) or frame, track id and class (tracking).
_BOX_FIELDS = 14
_FIELD_NAMES = ("truncated", "occluded", "alpha", "bbox_left", "bbox_top", "bbox_right", "bbox_bottom",
                "height", "width", "length", "x", "y", "z", "rotation_y", "score")
DONT_CARE = "DontCare"
#: Tracking frame numbers: KITTI names each frame's files with six digits (velodyne/0001/000000.bin).
MAX_FRAMES = 1_000_000


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
        score: (N,) detection score of results files, NaN where the line has none.
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
    score: np.ndarray

    def __len__(self) -> int:
        """The number of rows."""
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


def read_labels(path: Path | Location, tracking: bool = False, *,
                with_score: bool = False) -> tuple[KittiLabels, list[LabelProblem]]:
    """Reads a KITTI label or results file, each line checked on its own.

    ``label_2/000000.txt``: object, 15 fields (16 with a score); ``label_02/0001.txt``: tracking, 17
    fields (18 with a score).

    A line is a problem (and left out) when it is not UTF-8, has the wrong number of fields, a field
    that is not a number, a non-finite number, an ``occluded`` that is not an integer -1..3, a
    negative height, width or length (DontCare lines excepted: KITTI writes -1 there), or (tracking) a
    frame that is not an integer in [0, 10^6), a negative track id on an object, or a track id already
    used in the same frame (the later line is the problem).

    Args:
        path: the label (or results) file.
        tracking: the tracking layout (frame and track id before the class).
        with_score: require the score column (results files); without it the score is read when present.

    Returns:
        The readable lines as columns, and one problem per unreadable line (message starts ``line N:``).

    Raises:
        InputError: the file cannot be read at all.
    """
    data = read_text_bytes(path)  # a FIFO or a 10 GB file is refused before reading
    lead = 3 if tracking else 1
    rows: list[tuple[int, int, int, str, list[float]]] = []
    problems: list[LabelProblem] = []
    seen_ids: dict[tuple[int, int], int] = {}
    for number, raw in enumerate(data.splitlines(), start=1):
        try:
            fields = raw.decode("utf-8").split()
        except UnicodeDecodeError:
            problems.append(LabelProblem(line=number, frame=-1, message=(
                f"line {number}: expected UTF-8 text, got {raw[:60]!r}")))
            continue
        if not fields:
            continue
        frame = c_int(fields[0]) if tracking else None
        frame = frame if frame is not None and frame < MAX_FRAMES else -1  # (-1: not a frame, named by the problem)
        parsed = _parse_line(fields, lead, with_score)
        if isinstance(parsed, str):
            message: str | None = parsed
        else:
            track, cls, numbers = parsed
            message = _tracking_problem(fields, frame, track, cls, number, seen_ids) if tracking else None
        if message is not None:
            problems.append(LabelProblem(line=number, frame=frame, message=f"line {number}: {message}"))
            continue
        rows.append((number, frame, track, cls, numbers))
    values = np.array([r[4] for r in rows], dtype=np.float64).reshape(-1, _BOX_FIELDS + 1)
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
        score=values[:, 14],
    )
    return labels, problems


def _parse_line(fields: list[str], lead: int, with_score: bool) -> tuple[int, str, list[float]] | str:
    """(track id, class, the numbers with the score last, NaN when absent) of one line, or what is wrong with it.

    Args:
        fields: the line's fields.
        lead: the fields before the numbers (1: class; 3: frame, track id, class).
        with_score: whether the score column is required.
    """
    expected = lead + _BOX_FIELDS
    counts = (expected + 1,) if with_score else (expected, expected + 1)
    if len(fields) not in counts:
        wanted = f"{expected + 1} fields (with the score)" if with_score else \
            f"{expected} fields ({expected + 1} with a score)"
        return f"expected {wanted}, got {len(fields)}"
    track = c_int(fields[1]) if lead == 3 else -1
    if track is None:  # '1_0', '+1', '٣', or 20 digits, which overflowed the int64 column (a traceback)
        return f"track id: expected an integer below 2^31, got {fields[1][:40]!r}"
    try:
        numbers = c_floats(fields[lead:]) + ([math.nan] if len(fields) == expected else [])
    except ValueError:
        return f"expected numbers after the class, got {' '.join(fields[lead:])!r}"
    cls = fields[lead - 1]
    if not (cls.isascii() and cls.isprintable()):  # e.g. a UTF-8 byte-order mark glued to the first class
        return f"expected an ASCII class name, got {cls!r}"
    bad = [k for k, v in enumerate(numbers[:_BOX_FIELDS + (len(fields) - expected)]) if not math.isfinite(v)]
    if bad:
        return f"{_FIELD_NAMES[bad[0]]}: expected a finite number, got {fields[lead + bad[0]]!r}"
    if max(map(abs, numbers[3:7])) > MAX_CAMERA_VALUE_PX:
        return (f"bbox: expected pixel coordinates within {MAX_CAMERA_VALUE_PX:g}, got "
                f"{' '.join(fields[lead + 3:lead + 7])}")
    big = [k for k in (0, 2) if abs(numbers[k]) > FLOAT32_MAX]  # stored as float32
    if big:
        return f"{_FIELD_NAMES[big[0]]}: expected a value within float32 range, got {fields[lead + big[0]]!r}"
    if numbers[1] not in (-1.0, 0.0, 1.0, 2.0, 3.0):
        return f"occluded: expected an integer -1..3, got {fields[lead + 1]!r}"
    if cls != DONT_CARE and min(numbers[7:10]) < 0.0:
        return f"dimensions: expected non-negative height, width, length, got {' '.join(fields[lead + 7:lead + 10])}"
    if cls != DONT_CARE and max(numbers[7:10]) > MAX_BOX_SIZE_M:
        return (f"dimensions: expected height, width, length <= {MAX_BOX_SIZE_M:g} m, got "
                f"{' '.join(fields[lead + 7:lead + 10])}")
    if cls != DONT_CARE and max(map(abs, numbers[10:13])) > MAX_COORDINATE_M:
        return f"location: expected coordinates within {MAX_COORDINATE_M:g} m, got {' '.join(fields[lead + 10:lead + 13])}"
    turned = [k for k in (2, 13) if abs(numbers[k]) > MAX_ANGLE_RAD]  # DontCare's -10 is within
    if turned:
        return (f"{_FIELD_NAMES[turned[0]]}: expected an angle within +-{MAX_ANGLE_RAD:.4g} rad (two turns), "
                f"got {fields[lead + turned[0]]!r}")
    return track, cls, numbers


def _tracking_problem(fields: list[str], frame: int, track: int, cls: str, number: int,
                      seen_ids: dict[tuple[int, int], int]) -> str | None:
    """What is wrong with a tracking line's frame or track id, or None (then its id is recorded in ``seen_ids``)."""
    if frame < 0:
        return f"expected a frame number in [0, {MAX_FRAMES}) (six digits, as KITTI names frames), got {fields[0]!r}"
    if cls == DONT_CARE:
        return None
    if track < 0:
        return f"track id: expected a non-negative id on a {cls}, got {fields[1]!r}"
    first = seen_ids.setdefault((frame, track), number)
    if first != number:
        return f"track id: expected ids unique within frame {frame}, got {track} again (first on line {first})"
    return None
