"""Detections from a detector's result files: one entry point over every supported format.

>>> from avdata.perception.detection_files import read_detections
>>> found = read_detections(path, "ab3dmot")          # doctest: +SKIP
>>> found.scenes["0001"][0]                            # Detections of sequence 0001, frame 0  # doctest: +SKIP

Formats (``format`` argument; readers in ``avdata.sources.kitti.detections``):

=================  ==========================================================================  ===============
format             PATH                                                                        score
=================  ==========================================================================  ===============
``ab3dmot``        AB3DMOT's CSV: a folder of ``<seq>.txt`` (one class) or a folder of such    logit
                   folders (``pointrcnn_Car_val/``, ...), merged per sequence and frame
``kitti-tracking`` KITTI tracking results: a folder of ``<seq>.txt`` or one such file           probability
``kitti-object``   KITTI object results: a folder of ``<frame:06d>.txt`` (one sequence)          probability
``nuscenes``       a nuScenes detection submission JSON; scene = sample token, frame 0        probability
                   (the results name samples only), boxes in ``world`` (nuScenes' global frame)
``argoverse2``     an AV2 detection table (feather); scene = log_id, frame = rank of the     probability
                   timestamp_ns among the log's detection times, boxes in ``ego``
``unified``        the unified prediction table (Parquet or JSON; ``avdata eval detection``'s  probability
                   columns scene, frame_index, object_id, class, x/y/z_world_m, length/width/
                   height_m, yaw_world_rad, score); needs ``dataset`` (its frames' times)
=================  ==========================================================================  ===============

Unified-table boxes are in ``world`` with the dataset's frame times. Every KITTI-format box is in ``ego/cam0``
(KITTI's rectified camera 0, the frame of the KITTI converters' tree; y down), classes are unified (``car``,
``pedestrian``, ``cyclist``, ...), times are ``frame * 100 ms`` (KITTI's 10 Hz).
A score declared a logit becomes ``sigmoid(score)`` in ``Detections.scores`` (the order is unchanged); a
probability outside [0, 1] costs its record; a
KITTI tracking file without scores (e.g. labels) gets score 1. ``Detections.extras`` keeps ``box2d_px`` (N, 4),
``score_raw``, ``alpha_rad`` and ``kitti_class`` for writing KITTI results again.

A tracker wants boxes upright about +z: :func:`upright` re-expresses ``ego/cam0`` detections in
``ego/cam0_flu`` (the same origin, x forward, y left, z up; an exact axis permutation), :func:`camera_boxes`
turns boxes of that frame back into KITTI's label geometry. :func:`match_to_dataset` keys what was read by a
unified dataset's scenes and frames (``avdata track``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from avdata.errors import InputError
from avdata.frames import Boxes3D, Transform
from avdata.perception.detections import Detections
from avdata.sources.kitti import CLASS_MAP
from avdata.sources.kitti.detections import (
    AB3DMOT_CLASSES,
    KittiDetectionRows,
    read_ab3dmot_csv,
    read_kitti_object_results,
    read_kitti_tracking_results,
)

__all__ = ["CAMERA_FRAME", "FLU_T_CAM0", "FORMATS", "NON_KITTI_FORMATS", "UPRIGHT_FRAME", "DetectionFiles", "MatchedDetections",
           "camera_boxes", "match_to_dataset", "read_detections", "upright"]

#: KITTI's rectified camera 0 in the KITTI converters' frame tree.
CAMERA_FRAME = "ego/cam0"
#: ``ego/cam0`` with axes x forward, y left, z up (the frame trackers use for KITTI results).
UPRIGHT_FRAME = "ego/cam0_flu"
FLU_T_CAM0 = Transform(rotation=np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), translation=np.zeros(3))
#: format -> how its score is stated.
FORMATS = {"ab3dmot": "logit", "kitti-tracking": "probability", "kitti-object": "probability", "unified": "probability",
           "nuscenes": "probability", "argoverse2": "probability"}
#: formats whose files give boxes in a frame other than KITTI's camera, without 2D boxes (no KITTI results from them).
NON_KITTI_FORMATS = ("unified", "nuscenes", "argoverse2")
_FRAME_PERIOD_NS = 100_000_000


@dataclass(frozen=True, slots=True, kw_only=True)
class DetectionFiles:
    """What :func:`read_detections` found.

    Attributes:
        scenes: scene -> frame index -> that frame's detections (frames without detections are absent).
        problems: one line per record that could not be read (file, line, field, value); each cost its record.
        warnings: one line per record kept after a repair beyond float noise (a quaternion normalised).
    """

    scenes: dict[str, dict[int, Detections]] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def read_detections(path: Path | str, format: str, score: str | None = None,  # noqa: A002
                    dataset: Path | str | None = None) -> DetectionFiles:
    """Reads a detector's result files into per-scene, per-frame :class:`Detections`.

    Args:
        path: the file or folder (see the module docstring per format).
        format: ``ab3dmot``, ``kitti-tracking``, ``kitti-object`` (boxes in ``ego/cam0``), ``unified`` or
            ``nuscenes`` (``world``), ``argoverse2`` (``ego``).
        score: ``logit`` or ``probability``; None for the format's own (``ab3dmot``: logit, the others:
            probability; nuScenes and AV2 scores are always probabilities).
        dataset: the unified dataset root whose frames the ``unified`` table refers to (its frame times).

    Returns:
        The detections and one problem line per unreadable record.

    Raises:
        InputError: unknown format, or a path that is not what the format reads.
    """
    path = Path(path)
    if format not in FORMATS:
        raise InputError(f"detections: expected a format in {sorted(FORMATS)}, got {format!r}")
    score = score or FORMATS[format]
    if score not in ("logit", "probability"):
        raise InputError(f"detections: expected score 'logit' or 'probability', got {score!r}")
    if not path.exists():
        raise InputError(f"{path}: detection path does not exist")
    if format == "unified":
        if dataset is None:
            raise InputError(f"{path}: the unified table needs the dataset it refers to (dataset=ROOT)")
        return _read_unified(path, dataset, score)
    if format == "nuscenes":
        return _read_nuscenes(path)
    if format == "argoverse2":
        return _read_argoverse2(path)
    parts, problems = [], []
    for file in _files(path, format):
        reader = {"ab3dmot": read_ab3dmot_csv, "kitti-tracking": read_kitti_tracking_results,
                  "kitti-object": read_kitti_object_results}[format]
        rows, bad = reader(file)
        parts.append((file, rows))
        problems += bad
    scenes: dict[str, dict[int, Detections]] = {}
    for file, rows in parts:
        keep, bad = _score_check(rows, score, file)
        problems += bad
        rows = _select(rows, keep)
        for scene in np.unique(rows.scene).tolist():
            for frame_index in np.unique(rows.frame[rows.scene == scene]).tolist():
                mask = (rows.scene == scene) & (rows.frame == frame_index)
                dets = _detections(_select(rows, mask), score, int(frame_index))
                frames = scenes.setdefault(scene, {})
                old = frames.get(int(frame_index))
                frames[int(frame_index)] = dets if old is None else Detections.concatenate(
                    [old, dets], CAMERA_FRAME, dets.timestamp_ns)
    ordered = {scene: dict(sorted(frames.items())) for scene, frames in sorted(scenes.items())}
    return DetectionFiles(scenes=ordered, problems=problems)


def upright(detections: Detections) -> Detections:
    """``ego/cam0`` detections in ``ego/cam0_flu`` (x forward, y left, z up): the boxes become upright about +z."""
    if detections.boxes.frame != CAMERA_FRAME:
        raise InputError(f"detections: expected boxes in {CAMERA_FRAME!r}, got {detections.boxes.frame!r}")
    return detections.to(UPRIGHT_FRAME, FLU_T_CAM0)


def camera_boxes(boxes_flu: Boxes3D) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(hwl (N, 3), bottom centre (N, 3), rotation_y (N,)) in ``ego/cam0`` of boxes in ``ego/cam0_flu``."""
    if boxes_flu.frame != UPRIGHT_FRAME:
        raise InputError(f"boxes: expected frame {UPRIGHT_FRAME!r}, got {boxes_flu.frame!r}")
    return boxes_flu.transform(FLU_T_CAM0.inverse(), CAMERA_FRAME).to_kitti_camera()


def _files(path: Path, format: str) -> list[Path]:  # noqa: A002
    if format == "kitti-object":
        return [path]
    if path.is_file():
        return [path]
    files = sorted(path.glob("*.txt"))
    if format == "ab3dmot" and not files:
        # AB3DMOT's layout: one <detector>_<Class>_<split> folder per class
        folders = [f for f in sorted(path.iterdir()) if f.is_dir() and set(f.name.split("_")) & set(AB3DMOT_CLASSES.values())]
        files = sorted(p for folder in folders for p in folder.glob("*.txt"))
    if not files:
        raise InputError(f"{path}: expected <seq>.txt detection files for format {format!r}, got none")
    return files


def _score_check(rows: KittiDetectionRows, score: str, file: Path) -> tuple[np.ndarray, list[str]]:
    raw = rows.score_raw
    # NaN: a tracking result (or label) file without the score column, taken as certain
    ok = np.isnan(raw) | (np.isfinite(raw) if score == "logit" else (raw >= 0.0) & (raw <= 1.0))
    problems = [f"{file}: scene {rows.scene[i]} frame {rows.frame[i]}: field score: expected a {score}"
                f"{' in [0, 1]' if score == 'probability' else ''}, got {float(raw[i])!r}" for i in np.flatnonzero(~ok)]
    return ok, problems


def _select(rows: KittiDetectionRows, mask: np.ndarray) -> KittiDetectionRows:
    return KittiDetectionRows(**{name: getattr(rows, name)[mask] for name in KittiDetectionRows.__dataclass_fields__})


def _detections(rows: KittiDetectionRows, score: str, frame_index: int) -> Detections:
    classes = np.array([CLASS_MAP.get(c, "other") for c in rows.kitti_class.tolist()], dtype=str)
    boxes = Boxes3D.from_kitti_camera(rows.hwl_m, rows.bottom_cam0_m, rows.rotation_y_rad, CAMERA_FRAME, classes=classes)
    # exp(-logit) overflows below -709: a logit beyond +-700 is a sigmoid of 0 or 1 within float noise anyway
    scores = 1.0 / (1.0 + np.exp(-np.clip(rows.score_raw, -700.0, 700.0))) if score == "logit" else rows.score_raw
    scores = np.where(np.isnan(rows.score_raw), 1.0, scores)
    dets = Detections(boxes=boxes, scores=scores, sensors=np.full(len(rows), CAMERA_FRAME),
                      timestamp_ns=frame_index * _FRAME_PERIOD_NS)
    return replace(dets, extras={"box2d_px": rows.box2d_px, "score_raw": rows.score_raw, "alpha_rad": rows.alpha_rad,
                                 "kitti_class": rows.kitti_class})


def _read_unified(path: Path, dataset: Path | str, score: str) -> DetectionFiles:
    from avdata.eval.unified import DETECTION_COLUMNS, read_table
    from avdata.schema.dataset import DatasetReader

    table = read_table(path, (*DETECTION_COLUMNS, "score")).to_pydict()
    frames = DatasetReader(dataset).frames().select(["scene", "frame_index", "timestamp_ns"]).to_pydict()
    times = {(s, int(f)): int(t) for s, f, t in zip(frames["scene"], frames["frame_index"], frames["timestamp_ns"],
                                                       strict=True)}
    scene = np.asarray(table["scene"], dtype=str)
    frame = np.asarray(table["frame_index"], dtype=np.int64)
    raw = np.asarray(table["score"], dtype=np.float64)
    known = np.array([(s, int(f)) in times for s, f in zip(scene.tolist(), frame.tolist(), strict=True)], dtype=bool)
    in_range = np.isfinite(raw) if score == "logit" else (raw >= 0.0) & (raw <= 1.0)
    problems = [f"{path}: row {i}: scene, frame_index: expected a frame of {dataset}, got ({str(scene[i])!r}, "
                f"{int(frame[i])})" for i in np.flatnonzero(~known)]  # str(): numpy 2's repr is np.str_('...')
    problems += [f"{path}: row {i}: field score: expected a {score}{' in [0, 1]' if score == 'probability' else ''}, "
                 f"got {float(raw[i])!r}" for i in np.flatnonzero(known & ~in_range)]
    keep = known & in_range
    column = {name: np.asarray(table[name], dtype=np.float64) for name in DETECTION_COLUMNS[4:]}
    boxes = Boxes3D.from_yaw(np.c_[column["x_world_m"], column["y_world_m"], column["z_world_m"]],
                             np.c_[column["length_m"], column["width_m"], column["height_m"]], column["yaw_world_rad"],
                             "world", classes=np.asarray(table["class"], dtype=str))
    scores = 1.0 / (1.0 + np.exp(-raw)) if score == "logit" else raw
    scenes: dict[str, dict[int, Detections]] = {}
    for key in sorted({(s, int(f)) for s, f in zip(scene[keep].tolist(), frame[keep].tolist(), strict=True)}):
        rows = np.flatnonzero(keep & (scene == key[0]) & (frame == key[1]))
        dets = Detections(boxes=boxes[rows], scores=scores[rows], sensors=np.full(len(rows), "world"),
                          timestamp_ns=times[key])
        scenes.setdefault(key[0], {})[key[1]] = replace(dets, extras={"score_raw": raw[rows]})
    return DetectionFiles(scenes=scenes, problems=problems)


def _read_nuscenes(path: Path) -> DetectionFiles:
    from avdata.sources.nuscenes.detections import read_nuscenes_submission

    rows, problems = read_nuscenes_submission(path)
    boxes = Boxes3D(center=rows.center_world_m, size_lwh=rows.size_lwh_m, quat_wxyz=rows.quat_wxyz, frame="world",
                    classes=rows.detection_name)
    scenes: dict[str, dict[int, Detections]] = {}
    for token in dict.fromkeys(rows.sample_token.tolist()):
        index = np.flatnonzero(rows.sample_token == token)
        dets = Detections(boxes=boxes[index], scores=rows.score[index], sensors=np.full(len(index), "world"),
                          timestamp_ns=0)
        scenes[token] = {0: replace(dets, extras={"velocity_world_mps": rows.velocity_world_mps[index],
                                                  "attribute_name": rows.attribute_name[index]})}
    return DetectionFiles(scenes=scenes, problems=problems, warnings=list(rows.repaired))


def _read_argoverse2(path: Path) -> DetectionFiles:
    from avdata.sources.argoverse2.conventions import unified_class
    from avdata.sources.argoverse2.detections import read_av2_detections

    rows, problems = read_av2_detections(path)
    c = rows.columns
    classes = np.array([unified_class(category) for category in c["category"].tolist()], dtype=str)
    boxes = Boxes3D(center=np.c_[c["tx_m"], c["ty_m"], c["tz_m"]],
                    size_lwh=np.c_[c["length_m"], c["width_m"], c["height_m"]],
                    quat_wxyz=np.c_[c["qw"], c["qx"], c["qy"], c["qz"]], frame="ego", classes=classes)
    scenes: dict[str, dict[int, Detections]] = {}
    for log_id in sorted(set(c["log_id"].tolist())):
        in_log = c["log_id"] == log_id
        for frame_index, time_ns in enumerate(np.unique(c["timestamp_ns"][in_log]).tolist()):
            index = np.flatnonzero(in_log & (c["timestamp_ns"] == time_ns))
            dets = Detections(boxes=boxes[index], scores=c["score"][index], sensors=np.full(len(index), "ego"),
                              timestamp_ns=int(time_ns))
            scenes.setdefault(log_id, {})[frame_index] = replace(dets, extras={"category": c["category"][index]})
    return DetectionFiles(scenes=scenes, problems=problems, warnings=[f"{path}: {line}" for line in rows.repaired])


@dataclass(frozen=True, slots=True, kw_only=True)
class MatchedDetections:
    """Detections keyed by a unified dataset's scenes and frames (what :func:`match_to_dataset` found).

    Attributes:
        scenes: dataset scene -> dataset frame index -> that frame's detections (in their files' frame).
        problems: one line per file scene or frame the dataset lacks; each cost its detections.
    """

    scenes: dict[str, dict[int, Detections]]
    problems: list[str]


def match_to_dataset(found: DetectionFiles, format: str, path: Path | str, dataset: Path | str) -> MatchedDetections:  # noqa: A002
    """Keys ``found`` (read from ``path`` in ``format``) by the scenes and frames of the unified ``dataset``.

    A file's scene is the dataset scene of that name, or whose ``kitti_sequence`` (KITTI: ``0001``) or
    ``log_id`` (Argoverse 2) metadata it is; its frames are matched by frame index (KITTI formats and the
    unified table), by the frame's time (Argoverse 2: ``timestamp_ns``), or, for a nuScenes submission, by the
    sample token that ``avdata export nuscenes`` writes for the frame (the converted dataset keeps no
    original tokens). A scene or frame the dataset lacks costs its detections, with one line.
    """
    from avdata.schema.dataset import DatasetReader

    reader = DatasetReader(dataset, verify=True)
    table = reader.frames().select(["scene", "frame_index", "timestamp_ns"]).to_pydict()
    frames = list(zip(table["scene"], table["frame_index"], table["timestamp_ns"], strict=True))
    problems: list[str] = []
    scenes: dict[str, dict[int, Detections]] = {}
    if format == "nuscenes":
        from avdata.exporters.nuscenes import sample_token

        by_token = {sample_token(s, int(f)): (s, int(f)) for s, f, _ in frames}
        for token, per_frame in found.scenes.items():
            if token not in by_token:
                problems.append(f"{path}: results[{token!r}]: sample_token: expected a sample of {dataset} "
                                f"(as avdata export nuscenes names them), got {token!r}")
                continue
            scene, frame_index = by_token[token]
            scenes.setdefault(scene, {})[frame_index] = per_frame[0]
        return MatchedDetections(scenes={s: dict(sorted(f.items())) for s, f in sorted(scenes.items())},
                                 problems=problems)
    names: dict[str, str] = {}
    for scene in reader.scenes:
        metadata = reader.scene(scene).metadata
        for key in (scene, metadata.get("kitti_sequence"), metadata.get("log_id")):
            if key is not None:
                names.setdefault(str(key), scene)
    for key, per_frame in found.scenes.items():
        scene = names.get(key)
        if scene is None:
            problems.append(f"{path}: scene {key!r}: expected a scene of {dataset} (by name, KITTI sequence or "
                            f"log id), got {key!r} ({sum(len(d) for d in per_frame.values())} detections dropped)")
            continue
        keyed: list[tuple[int | None, Detections, str]]
        if format == "argoverse2":
            index_of = {int(t): int(f) for s, f, t in frames if s == scene}
            keyed = [(index_of.get(int(d.timestamp_ns)), d, f"timestamp_ns {d.timestamp_ns}") for d in per_frame.values()]
        else:
            known = {int(f) for s, f, _ in frames if s == scene}
            keyed = [(f if f in known else None, d, f"frame {f}") for f, d in per_frame.items()]
        for matched, dets, what in keyed:
            if matched is None:
                problems.append(f"{path}: scene {key!r} {what}: expected a frame of {scene} in {dataset}, got none "
                                f"({len(dets)} detections dropped)")
                continue
            scenes.setdefault(scene, {})[matched] = dets
    return MatchedDetections(scenes={s: dict(sorted(f.items())) for s, f in sorted(scenes.items())}, problems=problems)
