"""The "avdata" protocol: ground truth from a unified dataset's object and visibility tables.

Predictions use the ground truth's column names (Parquet, or JSON as ``{"columns": [...], "rows": [...]}``
or a list of records):

* detections and tracks: ``scene`` (str), ``frame_index`` (int), ``object_id`` (str; the track id for
  tracking), ``class`` (str, unified taxonomy), ``score`` (float, detections), ``x_world_m``, ``y_world_m``,
  ``z_world_m``, ``length_m``, ``width_m``, ``height_m``, ``yaw_world_rad``;
* trajectory predictions: ``scene``, ``frame_index`` (when predicted), ``object_id``, ``mode`` (int),
  ``probability`` (float), ``step`` (int >= 1, frames ahead), ``x_world_m``, ``y_world_m``.

Visibility decides what counts as a miss: a ground-truth object at a frame is *visible* when some sensor has
it in its field of view with at least one lidar point or a positive visible fraction, or with neither known
(``n_points`` -1 and ``visible_fraction`` NaN, e.g. KITTI's camera labels: the field of view decides). Invisible objects are
ignored: not misses, and a detection matched to one is neither a true nor a false positive (tracking removes
such tracker boxes, as TrackEval removes boxes matched to distractors).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from avdata.errors import InputError, one_line, shown
from avdata.eval.matching import greedy_match, max_weight_matching
from avdata.eval.names import Similarity
from avdata.eval.prediction import PredictionConfig, evaluate_prediction
from avdata.eval.problems import warn
from avdata.eval.tracking.sequence import TrackingSequence
from avdata.inputs import DuplicateKeyError, require_file, unique_object
from avdata.schema.limits import MAX_ANGLE_RAD, MAX_BOX_SIZE_M, MAX_COORDINATE_M, MAX_SPEED_MPS

__all__ = [
    "DETECTION_COLUMNS",
    "TRAJECTORY_COLUMNS",
    "UnifiedDetectionConfig",
    "check_frames",
    "check_unique_track_ids",
    "detection_breakdown",
    "prediction_metrics",
    "read_table",
    "tracking_sequences",
    "visible_mask",
    "warn_unknown_classes",
]

DETECTION_COLUMNS = ("scene", "frame_index", "object_id", "class", "x_world_m", "y_world_m", "z_world_m",
                     "length_m", "width_m", "height_m", "yaw_world_rad")
TRAJECTORY_COLUMNS = ("scene", "frame_index", "object_id", "mode", "probability", "step", "x_world_m", "y_world_m")
_DEFAULT_PREDICTION = PredictionConfig()
#: Bounds of the float columns (avdata.schema.limits, as the scene writer refuses): a negative size is no box
#: (IoU and safe distances would take it as one); sizes are the columns bounded below by 0.
_RANGES = {
    **dict.fromkeys(("length_m", "width_m", "height_m"), (0.0, MAX_BOX_SIZE_M)),
    **dict.fromkeys((f"{axis}_{frame}_m" for axis in "xyz" for frame in ("world", "ego")),
                    (-MAX_COORDINATE_M, MAX_COORDINATE_M)),
    **dict.fromkeys(("yaw_world_rad", "yaw_ego_rad"), (-MAX_ANGLE_RAD, MAX_ANGLE_RAD)),
    **dict.fromkeys(("vx_world_mps", "vy_world_mps"), (-MAX_SPEED_MPS, MAX_SPEED_MPS)),
}
_BOX = ["x_world_m", "y_world_m", "z_world_m", "length_m", "width_m", "height_m", "yaw_world_rad"]


_STRING_COLUMNS = frozenset({"scene", "object_id", "class", "source_class"})
_INTEGER_COLUMNS = frozenset({"frame_index", "mode", "step"})
#: Flags: JSON true/false or a Parquet boolean column (the text "false" is not false, and 2 is no flag).
_BOOLEAN_COLUMNS = frozenset({"overlap_nlz"})


def read_table(path: str | Path, required: Sequence[str]) -> pa.Table:
    """Reads a Parquet or JSON prediction table and checks its columns and values.

    Required columns are typed: ``scene``, ``object_id``, ``class`` and ``source_class`` strings (numbers are
    turned into their text), ``frame_index``, ``mode`` and ``step`` integers, every other one a finite float. A
    null, non-numeric or non-finite value is an :class:`InputError` naming the file, row, column and value.
    Other columns are kept as read (the names above typed the same way; ``overlap_nlz`` must be booleans).

    Args:
        path: ``.parquet`` or ``.json`` file.
        required: columns that must be present.

    Returns:
        The table: the required columns, then the others.
    """
    path = Path(path)
    require_file(path, "Parquet or JSON table", missing="expected a Parquet or JSON table, got no such file")
    columns: dict[str, pa.Array | list[Any]]
    if path.suffix == ".parquet":
        try:
            table = pq.read_table(path)
        except (pa.ArrowException, OSError) as exc:
            raise InputError(f"{path}: expected a Parquet table, got {exc}") from None
        columns = {c: table[c].combine_chunks() for c in table.column_names}
        n_rows = len(table)
    elif path.suffix == ".json":
        try:
            data = json.loads(path.read_text(encoding="utf-8"), object_pairs_hook=unique_object)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise InputError(f"{path}: expected UTF-8 JSON, got {exc}") from None
        except DuplicateKeyError as exc:  # json.loads would keep the last value without a word
            raise InputError(f"{path}: expected JSON with each key once per object, got {exc}") from None
        except (ValueError, RecursionError) as exc:  # an integer of 5000 digits, arrays nested 100000 deep
            raise InputError(f"{path}: expected JSON, got {one_line(exc)}") from None
        if isinstance(data, dict) and "columns" in data and "rows" in data:
            names, rows = data["columns"], data["rows"]
            if (not isinstance(names, list) or not all(isinstance(c, str) for c in names)
                    or len(set(names)) < len(names) or not isinstance(rows, list)):
                # a name given twice would keep its last column without a word
                raise InputError(f"{path}: expected 'columns' a list of distinct names and 'rows' a list, got "
                                 f"columns {shown(names)}, rows of type {type(rows).__name__}")
            width = len(data["columns"])
            short = next((i for i, r in enumerate(data["rows"]) if not isinstance(r, list) or len(r) != width), None)
            if short is not None:
                raise InputError(f"{path}: rows[{short}]: expected a list of {width} values, got {shown(data['rows'][short])}")
            columns = {c: [r[i] for r in data["rows"]] for i, c in enumerate(data["columns"])}
            n_rows = len(data["rows"])
        elif isinstance(data, list) and all(isinstance(r, dict) for r in data):
            names = list(dict.fromkeys(k for r in data for k in r))
            columns = {c: [r.get(c) for r in data] for c in names}
            n_rows = len(data)
        else:
            raise InputError(f"{path}: expected a list of records or {{'columns', 'rows'}}, got {type(data).__name__}")
    else:
        raise InputError(f"{path}: expected a .parquet or .json file, got suffix {path.suffix!r}")
    missing = [c for c in required if c not in columns]
    if missing and n_rows:
        raise InputError(f"{path}: expected columns {list(required)}, missing {missing}")
    out = {c: _typed_column(path, c, columns.get(c, [])) for c in required}
    for name, values in columns.items():
        if name not in out:
            out[name] = _other_column(path, name, values)
    return pa.table(out)


def _other_column(path: Path, name: str, values: pa.Array | list[Any]) -> pa.Array:
    """A column no protocol requires, kept as read (a known name gets its type); mixed JSON types are an error."""
    if name in _STRING_COLUMNS or name in _INTEGER_COLUMNS:
        return _typed_column(path, name, values)
    if name in _BOOLEAN_COLUMNS:
        pylist = values.to_pylist() if isinstance(values, pa.Array) else list(values)
        bad = next((i for i, v in enumerate(pylist) if not isinstance(v, bool)), None)
        if bad is not None:
            raise InputError(f"{path}: row {bad}: {name}: expected true or false, got {pylist[bad]!r}")
        return pa.array(pylist, pa.bool_())
    if isinstance(values, pa.Array):
        return values
    try:
        return pa.array(values)
    except (pa.ArrowInvalid, pa.ArrowTypeError):
        kinds = sorted({type(v).__name__ for v in values if v is not None})
        raise InputError(f"{path}: {name}: expected values of one type, got {', '.join(kinds)}") from None


def _typed_column(path: Path, name: str, values: pa.Array | list[Any]) -> pa.Array:
    """One column as string, int64 or finite float64, or an error naming the first bad row and value."""
    target = pa.string() if name in _STRING_COLUMNS else pa.int64() if name in _INTEGER_COLUMNS else pa.float64()
    kind = "a string" if name in _STRING_COLUMNS else "an integer" if name in _INTEGER_COLUMNS else "a number"
    try:
        array = values if isinstance(values, pa.Array) else pa.array(values)
        if not _type_fits(array.type, target):
            # A cast would read text "1.5" as a number and true as 1 without a word; nor is a boolean a name.
            first = int(np.argmax(array.is_valid().to_numpy(zero_copy_only=False)))
            raise InputError(f"{path}: row {first}: {name}: expected {kind}, got {shown(array[first].as_py())} "
                             f"(a column of {array.type})")
        array = array.cast(target)
    except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError, OverflowError):
        pylist = values.to_pylist() if isinstance(values, pa.Array) else values
        if name in _STRING_COLUMNS and isinstance(values, list):
            # Numbers are taken as their text; a list, an object or a boolean is no name (it would become "[1]").
            odd = next((i for i, v in enumerate(pylist) if isinstance(v, (bool, list, dict))), None)
            if odd is not None:
                raise InputError(f"{path}: row {odd}: {name}: expected {kind}, got {shown(pylist[odd])}") from None
            array = pa.array([None if v is None else str(v) for v in values], pa.string())
        else:
            row = next((i for i, v in enumerate(pylist) if not _fits(v, name)), 0)
            value = pylist[row]
            bits = " (64 bits)" if isinstance(value, (int, float)) and not isinstance(value, bool) else ""
            raise InputError(f"{path}: row {row}: {name}: expected {kind}{bits}, got {shown(pylist[row])}") from None
    if array.null_count:
        row = int(np.flatnonzero(array.is_null().to_numpy(zero_copy_only=False))[0])
        raise InputError(f"{path}: row {row}: {name}: expected a value, got null")
    if target == pa.string() and len(array) and pc.any(pc.match_substring(array, "\x00")).as_py():
        # NumPy's strings drop trailing NULs: scene "s0\x00" would be scene "s0" without a word.
        row = int(np.flatnonzero(pc.match_substring(array, "\x00").to_numpy(zero_copy_only=False))[0])
        raise InputError(f"{path}: row {row}: {name}: expected text without NUL characters, got {array[row].as_py()!r}")
    if target == pa.float64():
        numbers = array.to_numpy(zero_copy_only=False)
        bad = np.flatnonzero(~np.isfinite(numbers))
        if len(bad):
            raise InputError(f"{path}: row {bad[0]}: {name}: expected a finite number, got {numbers[bad[0]]}")
        low, high = _RANGES.get(name, (-np.inf, np.inf))
        if low == 0.0 and np.any(numbers < 0.0):
            row = int(np.argmax(numbers < 0.0))
            raise InputError(f"{path}: row {row}: {name}: expected a size >= 0, got {numbers[row]}")
        outside = np.flatnonzero((numbers < low) | (numbers > high))
        if len(outside):  # finite but absurd: 1e308 m overflows areas and IoUs to NaN without a word
            raise InputError(f"{path}: row {outside[0]}: {name}: expected a value in [{low:g}, {high:g}], "
                             f"got {numbers[outside[0]]}")
    return array


def _type_fits(source: pa.DataType, target: pa.DataType) -> bool:
    """Whether a column of Arrow type ``source`` may be cast to ``target``: numbers to numbers, text or numbers to text."""
    if pa.types.is_dictionary(source):
        source = source.value_type
    if pa.types.is_null(source):
        return True
    numeric = bool(pa.types.is_integer(source) or pa.types.is_floating(source) or pa.types.is_decimal(source))
    if target == pa.string():
        return numeric or bool(pa.types.is_string(source) or pa.types.is_large_string(source)
                               or pa.types.is_binary(source))
    return numeric


def _fits(value: object, name: str) -> bool:
    """Whether a value can be in column ``name``: an int64 or a float64 (a boolean cannot, nor 2**70), or text."""
    if isinstance(value, bool) or value is None:
        return value is None
    if name in _STRING_COLUMNS:
        return isinstance(value, (str, int, float))
    if isinstance(value, float) and name in _INTEGER_COLUMNS:
        return value.is_integer() and -(2.0**63) <= value < 2.0**63
    return isinstance(value, float) or (isinstance(value, int) and -(2**63) <= value < 2**63)


def check_frames(path: str | Path, table: pa.Table, frames: pa.Table) -> None:
    """Every (scene, frame_index) of a prediction table must be a frame of the dataset.

    Args:
        path: the prediction file, for messages.
        table: its rows (``scene``, ``frame_index``).
        frames: the dataset's ``index/frames.parquet``.
    """
    known_scenes = set(_col(frames, "scene").astype(str).tolist())
    scene = _col(table, "scene").astype(str)
    unknown = sorted(set(scene.tolist()) - known_scenes)
    if unknown:
        raise InputError(f"{path}: scene: expected scenes of the dataset ({len(known_scenes)}), got unknown "
                         f"{', '.join(repr(u) for u in unknown[:3])}{' ...' if len(unknown) > 3 else ''}")
    key = np.char.add(np.char.add(scene, "\x1f"), _col(table, "frame_index").astype(str))
    known = np.char.add(np.char.add(_col(frames, "scene").astype(str), "\x1f"), _col(frames, "frame_index").astype(str))
    bad = np.flatnonzero(~np.isin(key, known))
    if len(bad):
        s = str(scene[bad[0]])
        indices = _col(frames, "frame_index", np.int64)[_col(frames, "scene").astype(str) == s]
        raise InputError(f"{path}: row {bad[0]}: frame_index: expected a frame of scene {s!r} "
                         f"({indices.min()}..{indices.max()}), got {_col(table, 'frame_index', np.int64)[bad[0]]}")


def warn_unknown_classes(path: str | Path, table: pa.Table, known: Sequence[str], consequence: str,
                         column: str = "class") -> None:
    """One warning per class of ``table[column]`` outside ``known``, naming it and its number of rows.

    Args:
        path: the prediction file, for messages.
        table: its rows.
        known: the classes the protocol evaluates.
        consequence: what becomes of such rows (e.g. "they can only be false positives").
        column: the class column.
    """
    if column not in table.column_names or not len(table):
        return
    names, counts = np.unique(_col(table, column).astype(str), return_counts=True)
    for name, count in zip(names.tolist(), counts.tolist(), strict=True):
        if name not in known:
            warn(f"{path}: {column}: {count} row(s) of class {name!r}, which is not one of the evaluated classes; "
                 f"{consequence}")


def check_unique_track_ids(path: str | Path, tracks: pa.Table) -> None:
    """A track id may appear once per frame (TrackEval's ``_check_unique_ids``), per class where tracks have one.

    Args:
        path: the tracks file, for messages.
        tracks: its rows.
    """
    key = _keys(tracks)
    if "class" in tracks.column_names:
        key = np.char.add(np.char.add(key, "\x1f"), _col(tracks, "class").astype(str))
    unique, first, counts = np.unique(key, return_index=True, return_counts=True)
    if len(unique) and counts.max() > 1:
        row = int(first[np.argmax(counts > 1)])
        raise InputError(f"{path}: scene {str(_col(tracks, 'scene')[row])!r} frame {_col(tracks, 'frame_index')[row]}: "
                         f"expected each track id once per frame, got object_id {_col(tracks, 'object_id')[row]!r} "
                         f"{counts.max()} times")


def _col(table: pa.Table, name: str, dtype: type | None = None) -> np.ndarray:
    values = table[name].to_numpy(zero_copy_only=False)
    result: np.ndarray = values.astype(dtype) if dtype is not None else values
    return result


def visible_mask(objects: pa.Table, visibility: pa.Table | None) -> np.ndarray:
    """(N,) whether each object row was visible to at least one sensor (all True without visibility)."""
    if visibility is None or len(visibility) == 0:
        return np.ones(len(objects), dtype=bool)
    return np.isin(_keys(objects), _keys(visibility)[_seen(visibility)])


def _seen(visibility: pa.Table) -> np.ndarray:
    """(V,) visibility rows whose sensor sees the object.

    Seen: in the field of view with a lidar point, a positive visible fraction, or neither measure known
    (then the field of view decides).
    """
    n_points = _col(visibility, "n_points", np.int64)
    fraction = _col(visibility, "visible_fraction", np.float64)
    unknown = (n_points < 0) & np.isnan(fraction)
    result: np.ndarray = _col(visibility, "in_fov", bool) & ((n_points > 0) | (fraction > 0) | unknown)
    return result


def _keys(table: pa.Table) -> np.ndarray:
    return np.char.add(
        np.char.add(_col(table, "scene").astype(str), "\x1f"),
        np.char.add(np.char.add(_col(table, "frame_index").astype(str), "\x1f"), _col(table, "object_id").astype(str)),
    )


def _min_occlusion(objects: pa.Table, visibility: pa.Table | None) -> np.ndarray:
    """(N,) best (lowest) occlusion level over the sensors that see the object, -1 when unknown."""
    out = np.full(len(objects), -1, dtype=np.int64)
    if visibility is None or len(visibility) == 0:
        return out
    vkeys = _keys(visibility)
    occ = _col(visibility, "occlusion", np.int64)
    order = np.lexsort((occ, vkeys))
    vkeys, occ = vkeys[order], occ[order]
    first = np.r_[True, vkeys[1:] != vkeys[:-1]]
    ukeys, best = vkeys[first], occ[first]
    okeys = _keys(objects)
    pos = np.clip(np.searchsorted(ukeys, okeys), 0, max(len(ukeys) - 1, 0))
    found = (len(ukeys) > 0) & (ukeys[pos] == okeys) if len(ukeys) else np.zeros(len(okeys), bool)
    out[found] = best[pos[found]]
    return out


@dataclass(frozen=True, slots=True, kw_only=True)
class UnifiedDetectionConfig:
    """Detection matching for the avdata protocol.

    Attributes:
        match_distance_m: a detection matches a ground truth of its class within this BEV centre distance
            (greedy by descending score, nearest free ground truth first, as nuScenes matches).
        score_threshold: detections below this score are dropped before matching; None (the default) keeps
            every detection, as scores may be logits (negative) or any other scale.
        distance_bands_m: edges of the ego-distance bands of the breakdown.
    """

    match_distance_m: float = 2.0
    score_threshold: float | None = None
    distance_bands_m: tuple[float, ...] = (0.0, 20.0, 40.0, 60.0)


_DEFAULT_DETECTION = UnifiedDetectionConfig()


def _rates(tp: int, fp: int, fn: int) -> dict[str, float | int]:
    return {
        "TP": tp, "FP": fp, "FN": fn,
        "precision": tp / max(1, tp + fp), "recall": tp / max(1, tp + fn),
        # Detection has no true negatives: the false-positive rate is the fraction of detections that are false.
        "FPR": fp / max(1, tp + fp), "FNR": fn / max(1, tp + fn),
    }


def detection_breakdown(
    objects: pa.Table, visibility: pa.Table | None, detections: pa.Table,
    config: UnifiedDetectionConfig = _DEFAULT_DETECTION, *, frames: pa.Table,
) -> dict[str, dict[str, float | int]]:
    """Precision, recall, FPR, FNR at a score threshold, overall and broken down.

    Args:
        objects: ground-truth objects table (unified schema).
        visibility: visibility table, or None (every object counts).
        detections: detections table (:data:`DETECTION_COLUMNS` plus ``score``).
        config: matching distance, score threshold, distance bands.
        frames: the dataset's frames table (``index/frames.parquet``): the ego pose of each frame.

    Returns:
        Row name -> rates and counts. Rows: ``all``; ``class=<c>``; ``distance=<lo>-<hi>m`` (ground truth by
        its ego distance, unmatched detections by theirs from the frame's ``world_T_ego``); ``occlusion=<k>``
        (best level over the sensors that see the object; recall only, false positives have no occlusion);
        ``sensor=<name>`` (ground truth visible to that sensor; recall only).
    """
    det = (detections if config.score_threshold is None
           else detections.filter(pc.greater_equal(detections["score"], config.score_threshold)))
    g_cls, d_cls = _col(objects, "class").astype(str), _col(det, "class").astype(str)
    g_key = np.char.add(np.char.add(_col(objects, "scene").astype(str), "\x1f"), _col(objects, "frame_index").astype(str))
    d_key = np.char.add(np.char.add(_col(det, "scene").astype(str), "\x1f"), _col(det, "frame_index").astype(str))
    g_xy = np.c_[_col(objects, "x_world_m", float), _col(objects, "y_world_m", float)]
    d_xy = np.c_[_col(det, "x_world_m", float), _col(det, "y_world_m", float)]
    d_score = _col(det, "score", float)
    visible = visible_mask(objects, visibility)
    match = np.full(len(det), -1)
    for cls in np.unique(np.r_[g_cls, d_cls]):
        gi, di = np.flatnonzero(g_cls == cls), np.flatnonzero(d_cls == cls)
        m = greedy_match(g_key[gi], g_xy[gi], d_key[di], d_xy[di], np.argsort(-d_score[di], kind="stable"),
                         config.match_distance_m, inclusive=True)
        match[di[m >= 0]] = gi[m[m >= 0]]
    matched_gt = np.zeros(len(objects), dtype=bool)
    matched_gt[match[match >= 0]] = True
    ignored_det = (match >= 0) & ~visible[np.maximum(match, 0)]
    tp_det = (match >= 0) & ~ignored_det
    fp_det = match < 0
    fn_gt = visible & ~matched_gt
    tp_gt = visible & matched_gt
    out = {"all": _rates(int(tp_det.sum()), int(fp_det.sum()), int(fn_gt.sum()))}
    for cls in sorted(set(g_cls.tolist()) | set(d_cls.tolist())):
        out[f"class={cls}"] = _rates(int((tp_det & (d_cls == cls)).sum()), int((fp_det & (d_cls == cls)).sum()),
                                     int((fn_gt & (g_cls == cls)).sum()))
    g_dist = np.hypot(_col(objects, "x_ego_m", float), _col(objects, "y_ego_m", float))
    d_dist = _ego_distance(frames, d_key, d_xy)
    d_dist = np.where(match >= 0, g_dist[np.maximum(match, 0)], d_dist)
    edges = list(config.distance_bands_m) + [np.inf]
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        g_in, d_in = (g_dist >= lo) & (g_dist < hi), (d_dist >= lo) & (d_dist < hi)
        name = f"distance={lo:g}-{hi:g}m"
        out[name] = _rates(int((tp_det & d_in).sum()), int((fp_det & d_in).sum()), int((fn_gt & g_in).sum()))
    occ = _min_occlusion(objects, visibility)
    for level in sorted(set(occ[visible].tolist())):
        sel = visible & (occ == level)
        out[f"occlusion={level}"] = {"TP": int((tp_gt & sel).sum()), "FN": int((fn_gt & sel).sum()),
                                     "recall": float((tp_gt & sel).sum() / max(1, sel.sum()))}
    if visibility is not None and len(visibility):
        sensors = _col(visibility, "sensor").astype(str)
        seen = _seen(visibility)
        okeys = _keys(objects)
        for sensor in sorted(set(sensors.tolist())):
            sel = np.isin(okeys, _keys(visibility)[seen & (sensors == sensor)])
            out[f"sensor={sensor}"] = {"TP": int((tp_gt & sel).sum()), "FN": int((fn_gt & sel).sum()),
                                       "recall": float((tp_gt & sel).sum() / max(1, sel.sum()))}
    return out


def _ego_distance(frames: pa.Table, d_key: np.ndarray, d_xy: np.ndarray) -> np.ndarray:
    """(D,) BEV distance of detections from the ego vehicle at their frame (``world_T_ego`` of frames.parquet).

    NaN where the frame's ego pose is unknown.
    """
    f_key = np.char.add(np.char.add(_col(frames, "scene").astype(str), "\x1f"), _col(frames, "frame_index").astype(str))
    ego_xy = np.c_[_col(frames, "world_T_ego_x_m", float), _col(frames, "world_T_ego_y_m", float)]
    if len(f_key) == 0:
        return np.full(len(d_xy), np.nan)
    order = np.argsort(f_key)
    pos = np.clip(np.searchsorted(f_key[order], d_key), 0, len(f_key) - 1)
    known = f_key[order][pos] == d_key
    ego = ego_xy[order][pos]
    return np.where(known, np.hypot(d_xy[:, 0] - ego[:, 0], d_xy[:, 1] - ego[:, 1]), np.nan)


def tracking_sequences(
    objects: pa.Table, visibility: pa.Table | None, tracks: pa.Table, classes: Sequence[str],
    similarity: Similarity = Similarity.IOU_BEV,
) -> dict[str, dict[str, TrackingSequence]]:
    """Tracking sequences per class and scene from a unified dataset and a tracks table.

    Invisible ground truth is dropped, and tracker boxes matched to it (similarity >= 0.5, per-frame
    Hungarian) are removed first.

    Args:
        objects: ground-truth objects table.
        visibility: visibility table or None.
        tracks: tracker output (:data:`DETECTION_COLUMNS`; ``object_id`` is the track id).
        classes: unified classes to evaluate.
        similarity: box similarity (BEV IoU by default; Euclidean uses the xy centres with 2 m zero distance).

    Returns:
        ``{class: {scene: TrackingSequence}}``.
    """
    visible = visible_mask(objects, visibility)
    out: dict[str, dict[str, TrackingSequence]] = {}
    g_scene, t_scene = _col(objects, "scene").astype(str), _col(tracks, "scene").astype(str)
    g_cls, t_cls = _col(objects, "class").astype(str), _col(tracks, "class").astype(str)
    g_frame, t_frame = _col(objects, "frame_index", np.int64), _col(tracks, "frame_index", np.int64)
    g_box = np.stack([_col(objects, c, float) for c in _BOX], axis=1)
    t_box = np.stack([_col(tracks, c, float) for c in _BOX], axis=1).reshape(-1, 7)
    g_ids, t_ids = _col(objects, "object_id").astype(str), _col(tracks, "object_id").astype(str)
    for cls in classes:
        out[cls] = {}
        for scene in sorted(set(g_scene.tolist()) | set(t_scene.tolist())):
            gi = np.flatnonzero((g_scene == scene) & (g_cls == cls))
            ti = np.flatnonzero((t_scene == scene) & (t_cls == cls))
            n_frames = int(max(g_frame[g_scene == scene].max(initial=-1), t_frame[t_scene == scene].max(initial=-1))) + 1
            gb = g_box[gi] if similarity is not Similarity.EUCLIDEAN else g_box[gi, :2]
            tb = t_box[ti] if similarity is not Similarity.EUCLIDEAN else t_box[ti, :2]
            full = TrackingSequence.from_boxes(
                num_frames=n_frames, gt_frame=g_frame[gi], gt_id=g_ids[gi], gt_boxes=gb,
                tracker_frame=t_frame[ti], tracker_id=t_ids[ti], tracker_boxes=tb, similarity=similarity,
            )
            # Detections are stored frame-sorted (stable) inside the sequence.
            g_sorted, t_sorted = gi[np.argsort(g_frame[gi], kind="stable")], ti[np.argsort(t_frame[ti], kind="stable")]
            weight = np.where(full.pair_similarity >= 0.5, full.pair_similarity, 0.0)
            m = max_weight_matching(full.pair_frame, full.pair_gt, full.pair_tracker, weight,
                                     full.gt_offsets, full.tracker_offsets)
            drop_t = full.pair_tracker[m & ~visible[g_sorted][full.pair_gt]]
            keep_t = np.setdiff1d(np.arange(len(t_sorted)), drop_t)
            keep_g = np.flatnonzero(visible[g_sorted])
            gs, ts = g_sorted[keep_g], t_sorted[keep_t]
            out[cls][scene] = TrackingSequence.from_boxes(
                num_frames=n_frames, gt_frame=g_frame[gs], gt_id=g_ids[gs],
                gt_boxes=g_box[gs] if similarity is not Similarity.EUCLIDEAN else g_box[gs, :2],
                tracker_frame=t_frame[ts], tracker_id=t_ids[ts],
                tracker_boxes=t_box[ts] if similarity is not Similarity.EUCLIDEAN else t_box[ts, :2],
                similarity=similarity,
            )
    return out


def prediction_metrics(
    objects: pa.Table, predictions: pa.Table, config: PredictionConfig = _DEFAULT_PREDICTION, *,
    source: str | Path = "predictions",
) -> dict[str, float]:
    """Prediction metrics of trajectory predictions against the objects' future positions.

    Each (scene, frame_index, object_id) prediction has M modes of T steps; step k is compared with the
    object's position at frame_index + k; steps where the object is not annotated are excluded.

    Args:
        objects: ground-truth objects table.
        predictions: :data:`TRAJECTORY_COLUMNS` table; every prediction needs the same modes and steps.
        config: ks and miss threshold.
        source: the predictions file, named by the messages.

    Returns:
        As :func:`avdata.eval.prediction.evaluate_prediction`.
    """
    key = np.char.add(np.char.add(_col(predictions, "scene").astype(str), "\x1f"),
                      np.char.add(np.char.add(_col(predictions, "frame_index").astype(str), "\x1f"),
                                  _col(predictions, "object_id").astype(str)))
    agents, agent = np.unique(key, return_inverse=True)
    modes, mode = np.unique(_col(predictions, "mode", np.int64), return_inverse=True)
    steps, step = np.unique(_col(predictions, "step", np.int64), return_inverse=True)
    n, m, t = len(agents), len(modes), len(steps)
    if len(predictions) != n * m * t:
        raise InputError(f"{source}: expected {n} agents x {m} modes x {t} steps = {n * m * t} rows, got {len(predictions)}")
    pred = np.full((n, m, t, 2), np.nan)
    pred[agent, mode, step] = np.c_[_col(predictions, "x_world_m", float), _col(predictions, "y_world_m", float)]
    prob = np.full((n, m), np.nan)
    probability = _col(predictions, "probability", float)
    prob[agent, mode] = probability
    if np.isnan(pred).any():
        raise InputError(f"{source}: expected every agent to have every mode and step, got gaps")
    differs = np.flatnonzero(probability != prob[agent, mode])
    if len(differs):  # one of them would be kept without a word
        row = int(differs[0])
        raise InputError(f"{source}: row {row}: probability: expected one probability per mode (the same at each "
                         f"step), got {probability[row]} and {prob[agent[row], mode[row]]}")
    first = np.zeros(n, dtype=np.int64)
    first[agent] = np.arange(len(predictions))
    p_scene = _col(predictions, "scene").astype(str)[first]
    p_frame = _col(predictions, "frame_index", np.int64)[first]
    p_obj = _col(predictions, "object_id").astype(str)[first]
    obj_key = _keys(objects)
    order = np.argsort(obj_key)
    sorted_keys = obj_key[order]
    gt = np.zeros((n, t, 2))
    valid = np.zeros((n, t), dtype=bool)
    ox, oy = _col(objects, "x_world_m", float), _col(objects, "y_world_m", float)
    for k, s in enumerate(steps.tolist()):
        want = np.char.add(np.char.add(np.char.add(p_scene, "\x1f"), (p_frame + s).astype(str)),
                           np.char.add("\x1f", p_obj))
        pos = np.clip(np.searchsorted(sorted_keys, want), 0, max(len(sorted_keys) - 1, 0))
        found = sorted_keys[pos] == want if len(sorted_keys) else np.zeros(n, bool)
        idx = order[pos]
        gt[found, k] = np.c_[ox[idx], oy[idx]][found]
        valid[:, k] = found
    keep = valid.any(axis=1)
    if not keep.any():
        raise InputError(f"{source}: expected ground truth for some predicted step, got none")
    return evaluate_prediction(gt[keep], pred[keep], probability=prob[keep], valid=valid[keep], config=config)
