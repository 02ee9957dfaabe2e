"""nuScenes ground truth for evaluation: tables, the evaluated samples, ego positions, velocities, bike racks.

Shared by nuScenes detection (:mod:`avdata.eval.detection.nuscenes`) and tracking
(:mod:`avdata.eval.tracking.nuscenes`). Inputs are checked as the devkit checks them: every scene asked for
must exist, a submission must cover exactly the evaluated samples ("Samples in split doesn't match samples in
predictions"), and values must be finite numbers.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from avdata.errors import InputError, one_line, shown
from avdata.eval.problems import warn
from avdata.frames.rotations import matrix_from_quat_wxyz
from avdata.inputs import DuplicateKeyError, read_regular_file, unique_object
from avdata.schema.limits import MAX_COORDINATE_M
from avdata.sources.nuscenes import box_velocity
from avdata.sources.nuscenes.categories import CATEGORY_TO_CLASS

__all__ = [
    "CATEGORY_TO_CLASS",
    "BikeRacks",
    "annotation_velocities",
    "check_submission_samples",
    "finite_array",
    "lidar_ego_translations",
    "load_nuscenes_bike_racks",
    "load_tables",
    "outside_bike_racks",
    "read_json",
    "select_samples",
]


def read_json(path: Path, what: str) -> Any:
    """Parses one JSON file; a missing, non-UTF-8 or malformed file is an :class:`InputError`.

    Args:
        path: the file.
        what: what it holds, for the message.

    Returns:
        The parsed value.
    """
    try:
        return json.loads(read_regular_file(path).decode("utf-8"), object_pairs_hook=unique_object)
    except FileNotFoundError:
        raise InputError(f"{path}: expected the nuScenes {what} file, got no such file") from None
    except OSError as exc:
        raise InputError(f"{path}: expected the nuScenes {what} file, got an unreadable one ({exc.strerror or exc})") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: expected UTF-8 JSON ({what}), got byte {exc.object[exc.start]:#04x}") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: expected JSON ({what}), got a parse error at line {exc.lineno}") from None
    except DuplicateKeyError as exc:  # json.load would keep the last value without a word
        raise InputError(f"{path}: expected JSON ({what}) with each key once per object, got {exc}") from None
    except (ValueError, RecursionError) as exc:  # an integer of 5000 digits, arrays nested 100000 deep
        raise InputError(f"{path}: expected JSON ({what}), got {one_line(exc)}") from None


def load_tables(table_dir: Path, names: Iterable[str]) -> dict[str, list[dict[str, Any]]]:
    """Reads ``<table_dir>/<name>.json`` for each name; each must be a list of records.

    Args:
        table_dir: folder holding the tables.
        names: table names.

    Returns:
        Name -> records.
    """
    tables = {}
    for name in names:
        rows = read_json(table_dir / f"{name}.json", name)
        if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
            raise InputError(f"{table_dir / f'{name}.json'}: expected a list of records, got {type(rows).__name__}")
        tables[name] = rows
    return tables


def select_samples(table_dir: Path, tables: Mapping[str, list[dict[str, Any]]],
                   scene_names: set[str] | None) -> dict[str, dict[str, Any]]:
    """The samples of the evaluated scenes (all scenes when ``scene_names`` is None).

    Args:
        table_dir: the tables' folder, for messages.
        tables: at least ``scene`` and ``sample``.
        scene_names: scene names to evaluate; every one must exist.

    Returns:
        Sample token -> sample record.
    """
    scenes = {s["token"]: s["name"] for s in tables["scene"]}
    if scene_names is not None:
        unknown = sorted(scene_names - set(scenes.values()))
        if unknown:
            raise InputError(f"{table_dir / 'scene.json'}: --scenes: expected scene names of the tables, got unknown "
                             f"{', '.join(unknown)} (scenes: {', '.join(sorted(scenes.values())[:5])}"
                             f"{' ...' if len(scenes) > 5 else ''})")
    samples = {}
    for s in tables["sample"]:
        if s["scene_token"] not in scenes:
            raise InputError(f"{table_dir / 'sample.json'}: sample {s['token']} scene_token: expected a scene of "
                             f"scene.json, got {s['scene_token']!r}")
        if scene_names is None or scenes[s["scene_token"]] in scene_names:
            samples[s["token"]] = s
    if not samples:
        raise InputError(f"{table_dir / 'sample.json'}: expected samples to evaluate, got none")
    return samples


def lidar_ego_translations(table_dir: Path, tables: Mapping[str, list[dict[str, Any]]], samples: Mapping[str, dict[str, Any]]
                           ) -> dict[str, np.ndarray]:
    """Sample token -> (3,) ego translation at the sample's LIDAR_TOP key frame.

    Args:
        table_dir: the tables' folder, for messages.
        tables: ``sample_data``, ``ego_pose``, ``calibrated_sensor``, ``sensor``.
        samples: the evaluated samples.

    Returns:
        One translation per evaluated sample.
    """
    channel = {s["token"]: s["channel"] for s in tables["sensor"]}
    cs_channel = {c["token"]: channel.get(c["sensor_token"]) for c in tables["calibrated_sensor"]}
    poses = {p["token"]: p["translation"] for p in tables["ego_pose"]}
    ego: dict[str, np.ndarray] = {}
    for sd in tables["sample_data"]:
        if sd["is_key_frame"] and sd["sample_token"] in samples and cs_channel.get(sd["calibrated_sensor_token"]) == "LIDAR_TOP":
            if sd["ego_pose_token"] not in poses:
                raise InputError(f"{table_dir / 'sample_data.json'}: {sd['token']} ego_pose_token: expected a pose of "
                                 f"ego_pose.json, got {sd['ego_pose_token']!r}")
            ego[sd["sample_token"]] = finite_array(poses[sd["ego_pose_token"]], 3, table_dir / "ego_pose.json",
                                                   f"{sd['ego_pose_token']} translation")
    missing = sorted(set(samples) - set(ego))
    if missing:
        raise InputError(f"{table_dir / 'sample_data.json'}: expected a LIDAR_TOP key frame per sample, got none for "
                         f"{len(missing)} sample(s), e.g. {missing[0]}")
    return ego


def finite_array(value: Any, length: int, path: Path, where: str) -> np.ndarray:
    """``value`` as a (length,) float array of finite numbers, or an error naming file, record and value.

    Args:
        value: a JSON list.
        length: expected number of elements.
        path: the file, for messages.
        where: record and field, for messages.

    Returns:
        The array.
    """
    # NumPy would take text "1.5" and true as numbers without a word.
    if not isinstance(value, list) or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        raise InputError(f"{path}: {where}: expected {length} numbers, got {shown(value)}")
    try:
        array = np.array(value, dtype=np.float64)
    except OverflowError:  # an integer beyond float64
        raise InputError(f"{path}: {where}: expected {length} numbers, got {shown(value)}") from None
    if array.shape != (length,) or not np.all(np.isfinite(array)):
        raise InputError(f"{path}: {where}: expected {length} finite numbers, got {shown(value)}")
    if np.any(np.abs(array) > MAX_COORDINATE_M):  # 1e308 m is damage, not a place (distances overflow)
        raise InputError(f"{path}: {where}: expected {length} numbers within {MAX_COORDINATE_M:g}, got {shown(value)}")
    return array


def check_submission_samples(path: Path, submitted: Iterable[str], samples: Mapping[str, dict[str, Any]]) -> None:
    """A submission must hold exactly the evaluated samples, as the devkit asserts.

    Args:
        path: the submission, for messages.
        submitted: its sample tokens.
        samples: the evaluated samples.
    """
    submitted = set(submitted)
    extra, missing = sorted(submitted - set(samples)), sorted(set(samples) - submitted)
    if extra:
        raise InputError(f"{path}: results: expected only samples of the evaluated scenes, got {len(extra)} other(s), "
                         f"e.g. {extra[0]!r}")
    if missing:
        raise InputError(f"{path}: results: expected every sample of the evaluated scenes ({len(samples)}), missing "
                         f"{len(missing)}, e.g. {missing[0]!r} (an empty list stands for a sample without boxes)")


def annotation_velocities(table_dir: Path, rows: list[dict[str, Any]], annotations: Mapping[str, dict[str, Any]],
                          timestamp_us: Mapping[str, int]) -> np.ndarray:
    """The devkit's ``box_velocity`` for each annotation row (:func:`avdata.sources.nuscenes.box_velocity`).

    Centre difference over the previous and next annotation of the instance (one-sided at track ends), NaN when
    the time gap exceeds 1.5 s (3 s when centred). A ``prev`` / ``next`` token that is not in the table (the
    Lyft tables have them) counts as no link, with one warning giving their number.

    Args:
        table_dir: the tables' folder, for messages.
        rows: N annotations.
        annotations: token -> annotation, every annotation of the table.
        timestamp_us: sample token -> timestamp in microseconds.

    Returns:
        (N, 2) xy velocities in m/s.
    """
    dangling = 0
    first_xyz, last_xyz, first_t, last_t, has_prev, has_next = [], [], [], [], [], []
    for a in rows:
        prev = annotations.get(a["prev"]) if a["prev"] != "" else None
        nxt = annotations.get(a["next"]) if a["next"] != "" else None
        dangling += (a["prev"] != "" and prev is None) + (a["next"] != "" and nxt is None)
        first, last = prev or a, nxt or a
        first_xyz.append(first["translation"])
        last_xyz.append(last["translation"])
        first_t.append(timestamp_us[first["sample_token"]])
        last_t.append(timestamp_us[last["sample_token"]])
        has_prev.append(prev is not None)
        has_next.append(nxt is not None)
    velocity = box_velocity(np.array(first_xyz, dtype=np.float64).reshape(-1, 3),
                            np.array(last_xyz, dtype=np.float64).reshape(-1, 3),
                            np.array(first_t, dtype=np.float64), np.array(last_t, dtype=np.float64),
                            np.array(has_prev, dtype=bool), np.array(has_next, dtype=bool))[:, :2]
    if dangling:
        warn(f"{table_dir / 'sample_annotation.json'}: {dangling} prev/next link(s) point to annotations not in the "
             f"table; those velocities use the links present (one-sided or none)")
    return velocity


@dataclass(frozen=True, slots=True, kw_only=True)
class BikeRacks:
    """Bicycle racks (``static_object.bicycle_rack`` annotations) of each sample.

    The devkit's ``filter_eval_boxes`` drops every bicycle and motorcycle, ground truth and prediction,
    whose centre lies inside a rack of its sample (parked bikes are not evaluated).

    Attributes:
        sample: (K,) sample key of each rack.
        center_m: (K, 3) rack box centre, global frame.
        size_lwh_m: (K, 3) rack box length, width, height.
        rotation: (K, 3, 3) rack box orientation.
    """

    sample: np.ndarray
    center_m: np.ndarray
    size_lwh_m: np.ndarray
    rotation: np.ndarray


def outside_bike_racks(name: np.ndarray, sample: np.ndarray, center_m: np.ndarray, racks: BikeRacks) -> np.ndarray:
    """(N,) False for bicycles and motorcycles whose centre is inside a rack of their sample (faces included).

    Args:
        name: (N,) class names.
        sample: (N,) sample keys.
        center_m: (N, 3) box centres, global frame.
        racks: the racks.

    Returns:
        (N,) bool, True for boxes that are evaluated.
    """
    keep = np.ones(len(name), dtype=bool)
    cycles = np.isin(name, ["bicycle", "motorcycle"])
    for k in range(len(racks.sample)):
        rows = np.flatnonzero(cycles & (sample == racks.sample[k]))
        local = (center_m[rows] - racks.center_m[k]) @ racks.rotation[k]
        inside = np.all(np.abs(local) <= racks.size_lwh_m[k] / 2.0, axis=1)
        keep[rows[inside]] = False
    return keep


def load_nuscenes_bike_racks(table_dir: str | Path, scene_names: set[str] | None = None) -> BikeRacks:
    """The ``static_object.bicycle_rack`` annotations of the samples of ``scene_names`` (all if None).

    Args:
        table_dir: folder holding the tables.
        scene_names: scenes to evaluate; None for all.

    Returns:
        The racks.
    """
    table_dir = Path(table_dir)
    tables = load_tables(table_dir, ("scene", "sample", "sample_annotation", "instance", "category"))
    samples = select_samples(table_dir, tables, scene_names)
    rack_categories = {c["token"] for c in tables["category"] if c["name"] == "static_object.bicycle_rack"}
    rack_instances = {i["token"] for i in tables["instance"] if i["category_token"] in rack_categories}
    rows = [a for a in tables["sample_annotation"] if a["instance_token"] in rack_instances and a["sample_token"] in samples]
    wlh = np.array([a["size"] for a in rows], dtype=np.float64).reshape(-1, 3)
    quat = np.array([a["rotation"] for a in rows], dtype=np.float64).reshape(-1, 4)
    return BikeRacks(
        sample=np.array([a["sample_token"] for a in rows], dtype=object),
        center_m=np.array([a["translation"] for a in rows], dtype=np.float64).reshape(-1, 3),
        size_lwh_m=wlh[:, [1, 0, 2]],
        rotation=matrix_from_quat_wxyz(quat) if len(rows) else np.zeros((0, 3, 3)),
    )
