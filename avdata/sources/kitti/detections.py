"""KITTI-style detection and tracking result files: KITTI object results, KITTI tracking results, AB3DMOT's CSV.

All three carry KITTI's label geometry in rectified camera 0 (x right, y down, z forward): bottom centre
``x, y, z``, size ``h, w, l``, ``rotation_y`` about camera y, plus the camera-2 2D box ``x1, y1, x2, y2`` in
pixels, ``alpha`` and a score. Their layouts (one record per line):

- KITTI object results (``<frame:06d>.txt``, one file per frame, space-separated):
  ``type truncated occluded alpha x1 y1 x2 y2 h w l x y z rotation_y score``
- KITTI tracking results (``<seq>.txt``, one file per sequence, space-separated):
  ``frame track_id type truncated occluded alpha x1 y1 x2 y2 h w l x y z rotation_y [score]``
- AB3DMOT's detection CSV (``<seq>.txt`` in ``<detector>_<Class>_<split>/``, comma-separated):
  ``frame, type (1 Pedestrian, 2 Car, 3 Cyclist), x1, y1, x2, y2, score, h, w, l, x, y, z, rotation_y, alpha``
  where the score is PointRCNN's logit.

A malformed line costs that line: it becomes one problem string naming the file, the line, the field and the
value; the other lines are read.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from avdata.errors import InputError
from avdata.inputs import c_floats, c_int, read_text_bytes
from avdata.schema.limits import MAX_ANGLE_RAD, MAX_BOX_SIZE_M, MAX_CAMERA_VALUE_PX, MAX_COORDINATE_M

__all__ = [
    "AB3DMOT_CLASSES",
    "KittiDetectionRows",
    "format_kitti_tracking_lines",
    "read_ab3dmot_csv",
    "read_kitti_object_results",
    "read_kitti_tracking_results",
]

#: AB3DMOT's CSV class codes.
AB3DMOT_CLASSES = {1: "Pedestrian", 2: "Car", 3: "Cyclist"}

_GEOMETRY = ("x1", "y1", "x2", "y2", "h", "w", "l", "x", "y", "z", "rotation_y", "alpha", "score")
_KITTI_OBJECT = ("type", "truncated", "occluded", "alpha", "x1", "y1", "x2", "y2", "h", "w", "l", "x", "y", "z",
                 "rotation_y", "score")
_KITTI_TRACKING = ("frame", "track_id", *_KITTI_OBJECT)
_AB3DMOT = ("frame", "type", "x1", "y1", "x2", "y2", "score", "h", "w", "l", "x", "y", "z", "rotation_y", "alpha")
#: Not kept (results write -1), but the devkit's fscanf reads them: they must be numbers.
_READ_NOT_KEPT = ("truncated", "occluded")
#: Largest |value| per field (sizes are checked on their own): beyond these a value is damage (avdata.schema.limits).
_LIMITS = {"x1": MAX_CAMERA_VALUE_PX, "y1": MAX_CAMERA_VALUE_PX, "x2": MAX_CAMERA_VALUE_PX, "y2": MAX_CAMERA_VALUE_PX,
           "x": MAX_COORDINATE_M, "y": MAX_COORDINATE_M, "z": MAX_COORDINATE_M,
           "rotation_y": MAX_ANGLE_RAD, "alpha": MAX_ANGLE_RAD}


@dataclass(frozen=True, slots=True, kw_only=True)
class KittiDetectionRows:
    """The records of KITTI-style result files, as columns (one row per record).

    Attributes:
        scene: (N,) sequence name (the file's stem for per-sequence files, the folder's name for KITTI object).
        frame: (N,) frame index within the sequence.
        kitti_class: (N,) KITTI class name (``Car``, ``Pedestrian``, ...).
        track_id: (N,) the file's track id, -1 where the format has none.
        box2d_px: (N, 4) camera-2 box x1, y1, x2, y2 in pixels.
        hwl_m: (N, 3) height, width, length.
        bottom_cam0_m: (N, 3) bottom centre in rectified camera 0.
        rotation_y_rad: (N,) rotation about camera y.
        alpha_rad: (N,) observation angle.
        score_raw: (N,) the file's score as written (NaN where a tracking result has none).
    """

    scene: np.ndarray
    frame: np.ndarray
    kitti_class: np.ndarray
    track_id: np.ndarray
    box2d_px: np.ndarray
    hwl_m: np.ndarray
    bottom_cam0_m: np.ndarray
    rotation_y_rad: np.ndarray
    alpha_rad: np.ndarray
    score_raw: np.ndarray

    def __len__(self) -> int:
        """The number of boxes."""
        return len(self.frame)


def read_ab3dmot_csv(path: Path) -> tuple[KittiDetectionRows, list[str]]:
    """AB3DMOT's detection CSV of one sequence (``<seq>.txt``); returns the rows and one problem per bad line."""
    return _read(path, _AB3DMOT, ",", scene=path.stem, frame=None)


def read_kitti_tracking_results(path: Path) -> tuple[KittiDetectionRows, list[str]]:
    """A KITTI tracking result or label file of one sequence (``<seq>.txt``); DontCare rows are skipped."""
    return _read(path, _KITTI_TRACKING, None, scene=path.stem, frame=None)


def read_kitti_object_results(folder: Path) -> tuple[KittiDetectionRows, list[str]]:
    """A folder of KITTI object result files (``<frame:06d>.txt``), read as one sequence named after the folder."""
    if not folder.is_dir():
        raise InputError(f"{folder}: expected a folder of KITTI object result files (<frame>.txt), got none")
    parts, problems = [], []
    for path in sorted(folder.glob("*.txt")):
        frame = c_int(path.stem)
        if frame is None or frame < 0:
            problems.append(f"{path}: file name: expected <frame>.txt with a frame number, got {path.name!r}")
            continue
        rows, bad = _read(path, _KITTI_OBJECT, None, scene=folder.name, frame=frame)
        parts.append(rows)
        problems += bad
    return _concatenate(parts), problems


def format_kitti_tracking_lines(rows: KittiDetectionRows) -> list[str]:
    """KITTI tracking result lines (``frame track_id type -1 -1 alpha x1 y1 x2 y2 h w l x y z rotation_y score``)."""
    lines = []
    for i in range(len(rows)):
        numbers = [rows.alpha_rad[i], *rows.box2d_px[i], *rows.hwl_m[i], *rows.bottom_cam0_m[i], rows.rotation_y_rad[i],
                   rows.score_raw[i]]
        lines.append(f"{int(rows.frame[i])} {int(rows.track_id[i])} {rows.kitti_class[i]} -1 -1 "
                     + " ".join(f"{v:.6f}" for v in numbers))
    return lines


def _read(path: Path, columns: tuple[str, ...], sep: str | None, scene: str,
          frame: int | None) -> tuple[KittiDetectionRows, list[str]]:
    data = read_text_bytes(path)  # a FIFO would hang read_text; a 10 GB file is refused before reading
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise InputError(f"{path}: cannot read detection file ({error.__class__.__name__}: {error})") from None
    records: list[dict[str, object]] = []
    problems: list[str] = []
    optional_score = columns is _KITTI_TRACKING
    for number, line in enumerate(text.splitlines(), start=1):
        fields = [f.strip() for f in line.split(sep)] if sep else line.split()
        if not fields or fields == [""]:
            continue
        no_score = optional_score and len(fields) == len(columns) - 1
        if no_score:
            fields.append("nan")
        if len(fields) != len(columns):
            problems.append(f"{path}: line {number}: expected {len(columns)} fields, got {len(fields)}")
            continue
        named = dict(zip(columns, fields, strict=True))
        if named["type"] == "DontCare":  # an ignore region of a label file, not a box
            continue
        record, problem = _parse(named, no_score, coded_type=columns is _AB3DMOT)
        if problem:
            problems.append(f"{path}: line {number}: {problem}")
        else:
            records.append(record)
    if frame is not None:
        for record in records:
            record["frame"] = frame
    return _rows(records, scene), problems


def _parse(fields: dict[str, str], no_score: bool, coded_type: bool) -> tuple[dict[str, object], str | None]:
    """One line's record, or what is wrong with it.

    Args:
        fields: column name -> text.
        no_score: a tracking line without the score column.
        coded_type: the type is AB3DMOT's class code (1, 2, 3), not a KITTI class name.
    """
    record: dict[str, object] = {}
    for name, value in fields.items():
        if name == "type":
            if coded_type or value.lstrip("-").isdigit():
                code = c_int(value)
                if code not in AB3DMOT_CLASSES:
                    return record, f"field type: expected 1, 2 or 3, got {value!r}"
                value = AB3DMOT_CLASSES[code]
            elif not (value.isascii() and value.isprintable()):
                return record, f"field type: expected an ASCII class name, got {value!r}"
            record["type"] = value
        elif name in ("frame", "track_id"):
            integer = c_int(value)
            if integer is None or (name == "frame" and integer < 0):
                return record, (f"field {name}: expected an integer{' >= 0' if name == 'frame' else ''} below 2^31, "
                                f"got {value!r}")
            record[name] = integer
        elif name == "score" and no_score:
            record[name] = math.nan  # taken as certain by the readers of these rows
        elif name in _GEOMETRY or name in _READ_NOT_KEPT:
            try:
                (number,) = c_floats([value])
            except ValueError:
                return record, f"field {name}: expected a number, got {value!r}"
            if not math.isfinite(number):
                return record, f"field {name}: expected a finite number, got {value!r}"
            if name in _READ_NOT_KEPT:
                continue
            if name in ("h", "w", "l") and not 0.0 < number <= MAX_BOX_SIZE_M:
                return record, f"field {name}: expected a size > 0 and <= {MAX_BOX_SIZE_M:g} m, got {value!r}"
            limit = _LIMITS.get(name)
            if limit is not None and abs(number) > limit:
                return record, f"field {name}: expected a value within {limit:g}, got {value!r}"
            record[name] = number
    return record, None


def _rows(records: list[dict[str, object]], scene: str) -> KittiDetectionRows:
    def column(name: str, default: float = -1) -> np.ndarray:
        return np.array([r.get(name, default) for r in records], dtype=np.float64)

    n = len(records)
    return KittiDetectionRows(
        scene=np.full(n, scene, dtype=object).astype(str) if n else np.zeros(0, dtype=str),
        frame=column("frame").astype(np.int64),
        kitti_class=np.array([r["type"] for r in records], dtype=str) if n else np.zeros(0, dtype=str),
        track_id=column("track_id").astype(np.int64),
        box2d_px=np.stack([column(k) for k in ("x1", "y1", "x2", "y2")], axis=1).reshape(n, 4),
        hwl_m=np.stack([column(k) for k in ("h", "w", "l")], axis=1).reshape(n, 3),
        bottom_cam0_m=np.stack([column(k) for k in ("x", "y", "z")], axis=1).reshape(n, 3),
        rotation_y_rad=column("rotation_y"),
        alpha_rad=column("alpha"),
        score_raw=column("score", np.nan),
    )


def _concatenate(parts: list[KittiDetectionRows]) -> KittiDetectionRows:
    if not parts:
        return _rows([], "")
    return KittiDetectionRows(**{name: np.concatenate([getattr(p, name) for p in parts])
                                 for name in KittiDetectionRows.__dataclass_fields__})
