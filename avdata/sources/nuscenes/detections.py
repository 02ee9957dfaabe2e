"""nuScenes detection submissions (e.g. CenterPoint's results JSON), read record by record.

A submission is ``{"meta": {...}, "results": {sample_token: [box, ...]}}``, each box
``{translation, size, rotation, velocity, detection_name, detection_score, attribute_name}``:

==================  ===========================  =======================================
field               nuScenes                     here
==================  ===========================  =======================================
``translation``     box centre, global frame     ``center_world_m`` (the converter's ``world`` is
                                                 the global frame, not re-centred)
``size``            **w, l, h**                  ``size_lwh_m`` = (l, w, h)
``rotation``        quaternion (w, x, y, z)      ``quat_wxyz`` (normalised within the one tolerance rule)
``velocity``        (vx, vy) m/s, global; NaN    ``velocity_world_mps`` (N, 2), NaN kept
                    allowed
``detection_name``  one of the 10 classes        ``detection_name`` (also the unified class name)
``detection_score`` probability                  ``score``, checked in [0, 1]
==================  ===========================  =======================================

A box with a missing field or a bad value costs that box, with one line naming the file, the box
(``results[token][k]``), the field and the value; a file that is not such JSON is one :class:`InputError`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from avdata.errors import InputError
from avdata.frames.rotations import quaternion_message, repaired_quaternions
from avdata.sources.nuscenes.categories import ATTRIBUTES, DETECTION_NAMES

__all__ = ["NuscenesDetectionRows", "read_nuscenes_submission"]

#: An empty attribute_name is allowed (classes without attributes).
_ATTRIBUTES = frozenset((*ATTRIBUTES, ""))


@dataclass(frozen=True, slots=True, kw_only=True)
class NuscenesDetectionRows:
    """The usable boxes of a submission, in file order.

    Attributes:
        sample_token: (N,) the sample each box belongs to.
        center_world_m: (N, 3) box centres in the global frame.
        size_lwh_m: (N, 3) length, width, height.
        quat_wxyz: (N, 4) unit quaternions of the boxes in the global frame.
        velocity_world_mps: (N, 2) vx, vy in the global frame (NaN where the submission says NaN).
        detection_name: (N,) nuScenes detection class.
        score: (N,) detection score in [0, 1].
        attribute_name: (N,) attribute or "".
        repaired: one warning line per kept box whose quaternion was normalised beyond float noise.
    """

    sample_token: np.ndarray
    center_world_m: np.ndarray
    size_lwh_m: np.ndarray
    quat_wxyz: np.ndarray
    velocity_world_mps: np.ndarray
    detection_name: np.ndarray
    score: np.ndarray
    attribute_name: np.ndarray
    repaired: tuple[str, ...] = ()

    def __len__(self) -> int:
        """The number of boxes."""
        return len(self.sample_token)


def _numbers(value: Any, length: int, finite: bool) -> np.ndarray | None:
    if not isinstance(value, list) or len(value) != length:
        return None
    if any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value):
        return None
    array = np.asarray(value, dtype=np.float64)
    return array if not finite or np.all(np.isfinite(array)) else None


def _box(box: Any) -> tuple[dict[str, Any] | None, str | None]:
    """(the checked values, None) or (None, "field: expected ..., got ...")."""
    if not isinstance(box, dict):
        return None, f"expected a box object, got {type(box).__name__}"
    out: dict[str, Any] = {}
    for key, length, finite in (("translation", 3, True), ("size", 3, True), ("rotation", 4, True),
                                ("velocity", 2, False)):
        if key not in box:
            return None, f"field {key}: expected {length} numbers, got none"
        array = _numbers(box[key], length, finite)
        if array is None:
            return None, f"field {key}: expected {length} {'finite ' if finite else ''}numbers, got {box[key]!r}"
        out[key] = array
    if not np.all(out["size"] > 0):
        return None, f"field size: expected positive sizes, got {box['size']!r}"
    name, score, attribute = box.get("detection_name"), box.get("detection_score"), box.get("attribute_name", "")
    if name not in DETECTION_NAMES:
        return None, f"field detection_name: expected one of {', '.join(DETECTION_NAMES)}, got {name!r}"
    if isinstance(score, bool) or not isinstance(score, (int, float)) or not 0.0 <= score <= 1.0:
        return None, f"field detection_score: expected a number in [0, 1], got {score!r}"
    if attribute not in _ATTRIBUTES:
        return None, f"field attribute_name: expected a nuScenes attribute or '', got {attribute!r}"
    out.update(detection_name=name, score=float(score), attribute_name=attribute)
    return out, None


def read_nuscenes_submission(path: Path | str) -> tuple[NuscenesDetectionRows, list[str]]:
    """Reads a nuScenes detection submission; each bad box costs itself.

    Args:
        path: the submission JSON.

    Returns:
        (the usable boxes, one problem line per dropped box: file, ``results[token][k]``, field, value).

    Raises:
        InputError: the file is unreadable, not JSON, or has no ``results`` object of box lists.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as error:
        raise InputError(f"{path}: cannot read a nuScenes submission ({' '.join(str(error).split())})") from None
    if not isinstance(data, dict) or not isinstance(data.get("results"), dict):
        got = sorted(data) if isinstance(data, dict) else type(data).__name__
        raise InputError(f"{path}: expected a 'results' object (sample token -> boxes), got {got}")
    kept: list[tuple[str, dict[str, Any]]] = []
    problems: list[str] = []
    for token, boxes in data["results"].items():
        if not isinstance(boxes, list):
            problems.append(f"{path}: results[{token!r}]: expected a list of boxes, got {type(boxes).__name__}")
            continue
        for k, box in enumerate(boxes):
            checked, problem = _box(box)
            if checked is None:
                problems.append(f"{path}: results[{token!r}][{k}]: {problem}")
            else:
                kept.append((f"results[{token!r}][{k}]", checked | {"sample_token": token}))
    quat = np.array([v["rotation"] for _, v in kept], dtype=np.float64).reshape(-1, 4)
    unit, warn, reject = repaired_quaternions(quat)
    problems += [f"{path}: {kept[i][0]}: field rotation: {quaternion_message(quat[i], rejected=True)}"
                 for i in np.flatnonzero(reject)]
    keep = ~reject
    values = [v for (_, v), ok in zip(kept, keep.tolist(), strict=True) if ok]
    size_wlh = np.array([v["size"] for v in values], dtype=np.float64).reshape(-1, 3)
    rows = NuscenesDetectionRows(
        sample_token=np.array([v["sample_token"] for v in values], dtype=str),
        center_world_m=np.array([v["translation"] for v in values], dtype=np.float64).reshape(-1, 3),
        size_lwh_m=size_wlh[:, [1, 0, 2]],
        quat_wxyz=unit[keep],
        velocity_world_mps=np.array([v["velocity"] for v in values], dtype=np.float64).reshape(-1, 2),
        detection_name=np.array([v["detection_name"] for v in values], dtype=str),
        score=np.array([v["score"] for v in values], dtype=np.float64),
        attribute_name=np.array([v["attribute_name"] for v in values], dtype=str),
        repaired=tuple(f"{path}: {kept[i][0]}: field rotation: {quaternion_message(quat[i], rejected=False)}"
                       for i in np.flatnonzero(warn)))
    return rows, problems
