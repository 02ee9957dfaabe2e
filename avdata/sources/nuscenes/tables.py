"""The nuScenes schema's tables as the lookups a conversion needs, streamed with bounded memory."""


import array
import ctypes
import itertools
import json
import math
import operator
from collections import defaultdict
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from isal import isal_zlib

from avdata.errors import InputError
from avdata.frames.rotations import REPAIR_TOLERANCE, SILENT_TOLERANCE, quaternion_message
from avdata.inputs import is_present
from avdata.schema.limits import MAX_BOX_SIZE_M, MAX_COORDINATE_M
from avdata.sources.nuscenes.jsonio import RepeatedKeyRecord, iter_json_chunks, us_to_ns

#: Every table of the nuScenes schema this converter reads (``map`` is optional: map name only).
REQUIRED_TABLES: tuple[str, ...] = (
    "attribute",
    "calibrated_sensor",
    "category",
    "ego_pose",
    "instance",
    "log",
    "sample",
    "sample_annotation",
    "sample_data",
    "scene",
    "sensor",
    "visibility",
)


@dataclass(frozen=True, slots=True, kw_only=True)
class SampleDataRow:
    """The fields of one sample_data row this converter uses (time already in ns)."""

    token: str
    sample_token: str
    ego_pose_row: int
    calibrated_sensor_token: str
    timestamp_ns: int
    filename: str
    is_key_frame: bool
    width: int
    height: int


class _ColumnBlocks:
    """Accumulates table columns as numpy arrays, a block of records at a time, into arrays sized once.

    The arrays are allocated for ``capacity`` rows, an upper bound on the table's rows (:func:`_max_rows`);
    a page of an array becomes memory only when written, so the unused tail costs address space, not
    memory. Filled in place, no column is ever held twice (blocks kept and then concatenated were: on
    nuScenes trainval's ego poses the peak held 213 MB of freed blocks beside the columns).

    Args:
        dtypes: column name -> numpy dtype ("S" for byte strings of any width: the array is widened, one
            copy, when a longer value comes), in the order of the tuples given to :meth:`append`.
        capacity: the most rows expected (more are taken, the arrays then doubled).
    """

    BLOCK = 1 << 12

    def __init__(self, dtypes: dict[str, str], capacity: int):
        self.dtypes = dtypes
        self.capacity = capacity
        self.n_rows = 0
        self.pending: list[list[Any]] = [[] for _ in dtypes]
        self.pending_rows = 0
        self.arrays: dict[str, np.ndarray] = {}

    def extend(self, columns: Sequence[list[Any]]) -> None:
        """Appends rows given a column at a time: one list per dtype, in the order of ``dtypes``, equally long."""
        for pending, column in zip(self.pending, columns, strict=True):
            pending += column
        self.pending_rows += len(columns[0])
        if self.pending_rows >= self.BLOCK:
            self._flush()

    def _flush(self) -> None:
        if not self.pending_rows:
            return
        end = self.n_rows + self.pending_rows
        if end > self.capacity:  # the file grew after it was sized: doubled, one copy per column
            self.capacity = max(end, 2 * self.capacity)
        for (name, dtype), column in zip(self.dtypes.items(), self.pending, strict=True):
            block = np.asarray(column, dtype=dtype)
            array = self.arrays.get(name)
            if array is None or np.promote_types(array.dtype, block.dtype) != array.dtype or len(array) < self.capacity:
                wider = np.empty((self.capacity, *block.shape[1:]),
                                 dtype=block.dtype if array is None else np.promote_types(array.dtype, block.dtype))
                if array is not None:
                    wider[:self.n_rows] = array[:self.n_rows]
                self.arrays[name] = array = wider
            array[self.n_rows:end] = block
        self.n_rows = end
        self.pending = [[] for _ in self.dtypes]
        self.pending_rows = 0

    def columns(self) -> dict[str, np.ndarray]:
        """The columns so far, in append order (views of the arrays; the accumulator is emptied)."""
        self._flush()
        columns = {name: self.arrays[name][:self.n_rows] if name in self.arrays else np.zeros(0, dtype=dtype)
                   for name, dtype in self.dtypes.items()}
        self.arrays.clear()
        return columns


def _max_rows(path: Path, table: str) -> int:
    """An upper bound on the rows of ``table`` at ``path`` that pass :data:`SCHEMA`.

    Each such row's text holds every required key, quoted, with a colon and a value of at least one
    character, and two braces.
    """
    min_chars = 2 + sum(len(field) + 4 for field in SCHEMA[table])
    try:
        size = path.stat().st_size
    except OSError:
        return 1  # a missing file or broken link: the table's reader, run next, names it
    return size // min_chars + 1


class _SceneStrings:
    """Byte strings of each scene in append order, compressed a segment at a time.

    The long strings of the big tables (tokens, filenames) are kept here, not as fixed-width columns:
    such a column holds every value at the longest one's width, and grouping it by scene copies it
    (~250 MB for nuScenes trainval's filenames, twice at the peak). Here each value goes to its
    scene's buffer as it is parsed (grouped as it comes, in table order within the scene), and each
    scene's buffer is deflated once it holds :attr:`SEGMENT` bytes (ISA-L level 1: filenames ~10x smaller,
    hex tokens ~2x, at 0.4-2 GB/s).

    Args:
        n_scenes: the number of scenes (values are appended by scene index).
    """

    SEGMENT = 1 << 14

    def __init__(self, n_scenes: int):
        self._pending = [bytearray() for _ in range(n_scenes)]
        self._lengths = [array.array("I") for _ in range(n_scenes)]
        self._segments: list[list[bytes]] = [[] for _ in range(n_scenes)]

    def extend(self, scene: int, values: list[bytes]) -> None:
        """Appends ``values`` to scene ``scene``'s, in order."""
        pending = self._pending[scene]
        pending += b"".join(values)
        self._lengths[scene].extend(map(len, values))
        if len(pending) >= self.SEGMENT:
            self._segments[scene].append(isal_zlib.compress(pending, 1))
            self._pending[scene] = bytearray()

    def finish(self) -> None:
        """Deflates what is pending (after the last append)."""
        for scene, pending in enumerate(self._pending):
            if pending:
                self._segments[scene].append(isal_zlib.compress(pending, 1))
                self._pending[scene] = bytearray()

    def values(self, scene: int) -> np.ndarray:
        """(N,) the scene's values in append order as fixed-width bytes (``"S"``, as the other columns)."""
        return np.array(self._list(scene), dtype="S")

    def keep(self, scene: int, mask: np.ndarray) -> None:
        """Keeps only scene ``scene``'s values where ``mask`` (one bool per value, in order) is True."""
        kept = [value for value, keep in zip(self._list(scene), mask.tolist(), strict=True) if keep]
        self.drop(scene)
        self.extend(scene, kept)
        self.finish()

    def _list(self, scene: int) -> list[bytes]:
        data = b"".join([isal_zlib.decompress(segment) for segment in self._segments[scene]]) + self._pending[scene]
        ends = np.cumsum(self._lengths[scene], dtype=np.int64).tolist()
        starts = [0, *ends[:-1]] if ends else []
        return [data[start:end] for start, end in zip(starts, ends, strict=True)]

    def drop(self, scene: int) -> None:
        """Forgets scene ``scene``'s values."""
        self._pending[scene], self._lengths[scene], self._segments[scene] = bytearray(), array.array("I"), []


def _s_bytes(value: Any) -> bytes:
    """``value`` as a fixed-width bytes column (``np.asarray(..., dtype="S")``) stores it."""
    return value.encode("ascii") if type(value) is str else np.asarray(value, dtype="S").tobytes()


_SAMPLE_TOKEN = operator.itemgetter("sample_token")
_CS_TOKEN = operator.itemgetter("calibrated_sensor_token")
_INSTANCE_TOKEN = operator.itemgetter("instance_token")
#: An annotation's visibility token that names no visibility row.
_UNKNOWN = -3


def _take(kept: list[int], *columns: list[Any]) -> tuple[list[Any], ...]:
    """Each list of ``columns`` reduced to the entries at ``kept``."""
    return tuple([column[i] for i in kept] for column in columns)


def _runs(values: list[int]) -> Iterator[tuple[int, int, int]]:
    """(value, start, end) of each run of equal consecutive ``values`` (one run per scene in a table's order)."""
    if not values:
        return
    if values[0] == values[-1] and values.count(values[0]) == len(values):
        yield values[0], 0, len(values)
        return
    starts = [0, *(np.flatnonzero(np.diff(values)) + 1).tolist(), len(values)]
    for start, end in itertools.pairwise(starts):
        yield values[start], start, end


def _rank_in_group(groups: np.ndarray) -> np.ndarray:
    """(N,) each row's place among the rows of its group, in row order (where a scene's strings hold its value)."""
    order = np.argsort(groups, kind="stable")
    rank = np.empty(len(groups), dtype=np.int64)
    rank[order] = np.arange(len(groups)) - np.searchsorted(groups[order], groups[order])
    return rank


def _grouped(columns: dict[str, np.ndarray], group: str) -> dict[str, np.ndarray]:
    """``columns`` sorted stably by their int column ``group``, in place."""
    if np.all(columns[group][1:] >= columns[group][:-1]):
        return columns  # already grouped (tables written scene by scene): no copy of every column
    order = np.argsort(columns[group], kind="stable")
    for name in columns:
        columns[name] = columns[name][order]  # replaced one at a time: the peak holds one column twice, not all
    return columns


#: The fields each table's rows must have, and their kinds (checked record by record; others are optional).
SCHEMA: dict[str, dict[str, str]] = {
    "scene": {"token": "token", "name": "str", "log_token": "token"},
    "log": {"token": "token"},
    "sensor": {"token": "token", "channel": "str", "modality": "str"},
    "calibrated_sensor": {"token": "token", "sensor_token": "token", "translation": "vec3", "rotation": "quat"},
    "category": {"token": "token", "name": "str"},
    "attribute": {"token": "token", "name": "str"},
    "visibility": {"token": "token", "level": "str"},
    "instance": {"token": "token", "category_token": "token"},
    "sample": {"token": "token", "scene_token": "token", "timestamp": "time_us"},
    "ego_pose": {"token": "token", "translation": "vec3", "rotation": "quat"},
    "sample_data": {"token": "token", "sample_token": "token", "ego_pose_token": "token",
                    "calibrated_sensor_token": "token", "timestamp": "time_us", "is_key_frame": "bool",
                    "filename": "str"},
    "sample_annotation": {"token": "token", "sample_token": "token", "instance_token": "token",
                          "translation": "vec3", "size": "size3", "rotation": "quat", "attribute_tokens": "tokens"},
    "map": {"token": "token", "log_tokens": "tokens"},
}
#: Optional fields, checked when present (the converter turns them into integers).
OPTIONAL: dict[str, dict[str, str]] = {
    "sample_data": {"width": "size_px", "height": "size_px"},
    "sample_annotation": {"num_lidar_pts": "count", "num_radar_pts": "count"},
    "map": {"filename": "str"},
}
_EXPECTED = {
    "size_px": "null or an integer in 0 .. 2**31",
    "count": "an integer in -1 .. 2**31",
    "token": "a non-empty string",
    "str": "a string",
    "number": "a finite number",
    "time_us": "microseconds in 0 .. 9.2e15 (int64 nanoseconds)",
    "bool": "true or false",
    "vec3": f"3 finite numbers within {MAX_COORDINATE_M:g} m",
    "size3": f"3 finite numbers in 0 .. {MAX_BOX_SIZE_M:g} m",
    "quat": f"a unit quaternion (w, x, y, z) (| |q| - 1 | <= {REPAIR_TOLERANCE:g})",
    "tokens": "a list of strings",
}


_MAX_TIME_US = (2**63 - 1) // 1000


def _is_number(value: Any) -> bool:
    return (type(value) is float and math.isfinite(value)) or type(value) is int


def _is_token(value: Any) -> bool:
    return type(value) is str and value != ""


def _is_vector(value: Any, size: int) -> bool:
    return type(value) is list and len(value) == size and all(map(_is_number, value))


def _norm_deviation(quat: list[float]) -> float:
    """| |q| - 1 | in plain Python: this runs once per row of the big tables, where numpy's per-call cost dominates."""
    return abs(math.sqrt(sum(v * v for v in quat)) - 1.0)


#: kind -> check; plain Python, because it runs once per field of every row of the big tables.
_CHECKS: dict[str, Callable[[Any], bool]] = {
    "size_px": lambda value: value is None or (type(value) is int and 0 <= value < 2**31),
    "count": lambda value: type(value) is int and -1 <= value < 2**31,
    "token": _is_token,
    "str": lambda value: type(value) is str,
    "number": _is_number,
    # Times become int64 nanoseconds (x 1000): anything that cannot is refused here, not overflowed later.
    "time_us": lambda value: _is_number(value) and 0 <= value < _MAX_TIME_US,
    "bool": lambda value: type(value) is bool,
    "tokens": lambda value: type(value) is list and all(type(v) is str for v in value),
    # The scene writer's magnitude limits: a row beyond them is refused here, costing only that row.
    "vec3": lambda value: _is_vector(value, 3) and max(map(abs, value)) <= MAX_COORDINATE_M,
    "size3": lambda value: _is_vector(value, 3) and 0.0 <= min(value) and max(value) <= MAX_BOX_SIZE_M,
    "quat": lambda value: _is_vector(value, 4) and _norm_deviation(value) <= REPAIR_TOLERANCE,
}
_MISSING = object()
#: An annotation's prev / next link whose token is of no annotation of its scene.
DANGLING = -2


def row_problem(table: str, row: dict[str, Any]) -> tuple[str | None, str | None]:
    """(error, warning) of one row against :data:`SCHEMA`.

    The error names the first field missing or of the wrong kind; the warning a quaternion normalised
    beyond float noise. Messages read ``<table> <token>: field 'x': expected ..., got ...``.
    """
    schema = SCHEMA[table]
    optional = OPTIONAL.get(table, {})
    if isinstance(row, RepeatedKeyRecord):
        key, first, other = row.repeated
        return (f"{_row_name(table, row)}: field {key!r}: expected it once, got it twice with different values "
                f"({json.dumps(first)[:40]} and {json.dumps(other)[:40]})"), None
    for field, kind in (*schema.items(), *optional.items()):
        value = row.get(field, _MISSING)
        if (value is _MISSING and field not in optional) or (value is not _MISSING and not _CHECKS[kind](value)):
            got = "none" if value is _MISSING else json.dumps(value)[:80]
            return f"{_row_name(table, row)}: field {field!r}: expected {_EXPECTED[kind]}, got {got}", None
    if schema.get("rotation") == "quat" and _norm_deviation(row["rotation"]) > SILENT_TOLERANCE:
        quaternion = np.asarray(row["rotation"], dtype=np.float64)
        return None, f"{table} {row['token']}: field 'rotation': {quaternion_message(quaternion, rejected=False)}"
    return None, None


def _row_name(table: str, row: dict[str, Any]) -> str:
    """``<table> <token>`` for messages (``(no token)`` when the row has none)."""
    token = row.get("token")
    return f"{table} {token if isinstance(token, str) else '(no token)'}"


#: Rows whose | |q| - 1 | is below this pass the chunk check; the rest get :func:`row_problem`'s own
#: (a margin below :data:`SILENT_TOLERANCE`, so float-order differences cannot hide a warning).
_CHUNK_QUAT_DEVIATION = SILENT_TOLERANCE / 2
#: Times at or above this (near 2**53, where int -> float rounds) get :func:`row_problem`'s own check.
_CHUNK_MAX_TIME_US = 9.0e15
_NUMBER_TYPES = frozenset({int, float})


def rows_valid(table: str, rows: list[Any]) -> bool:
    """Whether every row of ``rows`` passes :func:`row_problem` with neither error nor warning.

    The same checks a column at a time (``set(map(type, ...))`` and numpy, C loops instead of a Python
    call per field of each row); False when anything is or might be off (then each row goes through
    :func:`row_problem`, which names the problem). True only when :func:`row_problem` would return
    (None, None) for every row.
    """
    if set(map(type, rows)) != {dict}:
        return False
    optional = OPTIONAL.get(table, {})
    try:
        for field, kind in SCHEMA[table].items():
            if not _column_valid(kind, list(map(operator.itemgetter(field), rows))):
                return False
        for field, kind in optional.items():
            values = map(operator.methodcaller("get", field, _MISSING), rows)
            if not _column_valid(kind, [value for value in values if value is not _MISSING]):
                return False
    except (KeyError, OverflowError, ValueError, TypeError):
        return False  # a field missing, an integer beyond float64 ...: row_problem decides
    return True


def _column_valid(kind: str, values: list[Any]) -> bool:
    """Whether every value passes ``_CHECKS[kind]`` (and a quaternion needs no warning), checked as a column."""
    if not values:
        return True
    types = set(map(type, values))
    if kind in ("token", "str"):
        return types == {str} and (kind == "str" or "" not in values)
    if kind == "bool":
        return types == {bool}
    if kind == "tokens":
        return types == {list} and set(map(type, itertools.chain.from_iterable(values))) <= {str}
    if kind in ("size_px", "count"):
        numbers = [value for value in values if value is not None] if kind == "size_px" else values
        if not set(map(type, numbers)) <= {int}:
            return False
        integers = np.asarray(numbers, dtype=np.int64)
        return bool(np.all((integers >= (0 if kind == "size_px" else -1)) & (integers < 2**31)))
    if kind == "time_us":
        if not types <= _NUMBER_TYPES:
            return False
        times = np.asarray(values, dtype=np.float64)
        return bool(np.all((times >= 0.0) & (times < _CHUNK_MAX_TIME_US)))
    size = {"vec3": 3, "size3": 3, "quat": 4}[kind]
    if types != {list} or set(map(len, values)) != {size}:
        return False
    flat = list(itertools.chain.from_iterable(values))
    if not set(map(type, flat)) <= _NUMBER_TYPES:
        return False
    array = np.asarray(flat, dtype=np.float64).reshape(-1, size)
    if not np.all(np.isfinite(array)):
        return False
    if kind == "vec3":
        return bool(np.all(np.abs(array) <= MAX_COORDINATE_M))
    if kind == "size3":
        return bool(np.all((array >= 0.0) & (array <= MAX_BOX_SIZE_M)))
    if kind == "quat":
        # The squares summed left to right, as _norm_deviation does.
        squares = array * array
        norms = np.sqrt(((squares[:, 0] + squares[:, 1]) + squares[:, 2]) + squares[:, 3])
        return bool(np.all(np.abs(norms - 1.0) <= _CHUNK_QUAT_DEVIATION))
    return True


def _return_freed_heap() -> None:
    """Hands the C heap's free pages back to the kernel (glibc only; elsewhere nothing).

    The parse's decoded rows and chunks die once they are columns, but glibc keeps their pages for the
    process: 17 MB after 200 benchmark scenes' tables, which the conversion's own working set then came
    on top of (peak 170 MB, 150 with them returned; README, Performance).
    """
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        return
    trim(0)


class NuScenesTables:
    """The lookups the conversion needs, built from one version directory of nuScenes-schema tables.

    Small tables are kept as token -> row dicts (instance: its tokens and category tokens only). Of
    the big ones (sample_data, ego_pose, sample_annotation) only the fields the conversion uses are
    kept, with no Python object per row: numbers and references (int32 row numbers; annotations'
    prev / next as rows of their own scene) in numpy columns sorted by scene, so a scene's rows are
    one slice, and tokens and filenames in deflated per-scene buffers (:class:`_SceneStrings`), so
    memory grows by a compact row per record. Dangling tokens found while
    parsing are kept per scene in ``problems`` (file, message) and the record is dropped; records
    whose sample does not exist belong to no scene and are kept in ``orphans``. Every row is checked
    against :data:`SCHEMA` (:func:`row_problem`): a bad row is dropped and reported (in ``problems``
    when its scene is known, else in ``orphans``), so only the records that need it are lost; a
    duplicate token or scene name is an error naming both, and the later row is dropped.
    Quaternions normalised beyond float noise are listed in ``warnings``.

    Args:
        table_dir: the folder of ``*.json`` tables (``<dataroot>/<version>``).
    """

    def __init__(self, table_dir: Path):
        """Parses the tables of ``table_dir`` (see the class docstring)."""
        missing = [t for t in REQUIRED_TABLES if not is_present(table_dir / f"{t}.json")]  # damage: named when read
        if missing:
            raise InputError(f"{table_dir}: expected the nuScenes tables {list(REQUIRED_TABLES)}, missing {', '.join(missing)}")
        self.table_dir = table_dir

        self.problems: dict[str, list[tuple[str, str]]] = defaultdict(list)
        #: (file, message) of records that belong to no scene, reported with the first scene
        self.orphans: list[tuple[str, str]] = []
        #: (file, message) of repairs beyond float noise, reported with the first scene
        self.warnings: list[tuple[str, str]] = []

        def small(name: str) -> dict[str, dict[str, Any]]:
            rows: dict[str, dict[str, Any]] = {}
            for row in self._good_rows(name):
                if row["token"] in rows:
                    self.orphans.append((f"{name}.json", f"{name} {row['token']}: expected unique tokens, got this "
                                                         f"token twice; the later row is dropped"))
                    continue
                rows[row["token"]] = row
            return rows

        self.scene = small("scene")
        self.log = small("log")
        self.sensor = small("sensor")
        self.calibrated_sensor = small("calibrated_sensor")
        self.category = small("category")
        self.attribute = small("attribute")
        self.visibility = small("visibility")
        instances = small("instance")
        #: instance tokens, and each one's category token (the one field of instance.json used)
        self.instance_tokens = list(instances)
        self.instance_category: list[str] = [row["category_token"] for row in instances.values()]
        del instances  # 64k row dicts on trainval
        self.scene_by_name: dict[str, str] = {}
        for token, row in list(self.scene.items()):
            first = self.scene_by_name.setdefault(row["name"], token)
            if first != token:
                self.orphans.append(("scene.json", f"scene {token}: expected unique scene names, got {row['name']!r} "
                                                   f"again (first: scene {first}); the later scene is not converted"))
                del self.scene[token]
        self.map_of_log: dict[str, dict[str, Any]] = {}
        map_path = table_dir / "map.json"
        if is_present(map_path):  # optional; when there, unreadable costs the map names only
            try:
                for row in self._good_rows("map"):
                    for log_token in row["log_tokens"]:
                        self.map_of_log[log_token] = row
            except InputError as error:
                message = str(error).removeprefix(f"{map_path}: ")
                self.orphans.append(("map.json", f"{message}; every scene is written without its map"))
                self.map_of_log.clear()
        scene_index = {token: i for i, token in enumerate(self.scene)}
        self.scene_tokens = list(self.scene)

        #: sample tokens, (S,) scene index, (S,) timestamp as stored (microseconds), (S,) int64 ns
        self.sample_tokens: list[str] = []
        sample_scene, sample_us, sample_ns = [], [], []
        for row in self._good_rows("sample"):
            self.sample_tokens.append(row["token"])
            sample_scene.append(scene_index.get(row["scene_token"], -1))
            sample_us.append(float(row["timestamp"]))
            sample_ns.append(us_to_ns(row["timestamp"]))
        self.sample_scene = np.asarray(sample_scene, dtype=np.int64)
        self.sample_us = np.asarray(sample_us, dtype=np.float64)
        self.sample_ns = np.asarray(sample_ns, dtype=np.int64)
        sample_row = {token: i for i, token in enumerate(self.sample_tokens)}
        scene_of_sample: list[int] = self.sample_scene.tolist()  # per-row lookups: a list beats numpy indexing
        for i in np.flatnonzero(self.sample_scene < 0):
            self.orphans.append(("sample.json", f"sample {self.sample_tokens[i]}: dangling scene_token"))

        poses = _ColumnBlocks({"token": "S", "pose": "f8"}, _max_rows(table_dir / "ego_pose.json", "ego_pose"))
        # A bad pose is dropped: the sample_data using it are then reported with a dangling ego_pose_token.
        for rows in self._good_chunks("ego_pose"):
            poses.extend(([row["token"] for row in rows], [(*row["rotation"], *row["translation"]) for row in rows]))
        pose_columns = poses.columns()
        #: (P, 7) ego poses: quaternion (w, x, y, z) then translation, in ego_pose.json order.
        self.ego_pose = pose_columns["pose"].reshape(-1, 7)

        self.cs_tokens = list(self.calibrated_sensor)
        cs_row = {token: i for i, token in enumerate(self.cs_tokens)}
        #: each scene's sample_data tokens and filenames (the columns' order within the scene)
        self.sample_data_tokens = _SceneStrings(len(self.scene))
        self.sample_data_filenames = _SceneStrings(len(self.scene))
        columns = _ColumnBlocks(
            {
                "scene": "i4",
                "sample": "i4",
                "pose_token": "S",
                "cs": "i4",
                "time_ns": "i8",
                "key": "?",
                "width": "i4",
                "height": "i4",
            },
            _max_rows(table_dir / "sample_data.json", "sample_data"),
        )
        # Each kept row's token hash, for the duplicate check after the table (as for annotations).
        sample_data_hashes = array.array("q")
        # A chunk of rows at a time, a column at a time; row by row only for a chunk with a dangling link.
        for rows in self._good_chunks("sample_data", sample_row):
            samples = [sample_row.get(token, -1) for token in map(_SAMPLE_TOKEN, rows)]
            scenes = [scene_of_sample[sample] if sample >= 0 else -1 for sample in samples]
            sensors = [cs_row.get(token, -1) for token in map(_CS_TOKEN, rows)]
            if -1 in scenes or -1 in sensors:
                kept = []
                for k, row in enumerate(rows):
                    if scenes[k] < 0:
                        self.orphans.append(
                            ("sample_data.json", f"sample_data {row['token']}: dangling sample_token {row['sample_token']}")
                        )
                    elif sensors[k] < 0:
                        self.problems[self.scene_tokens[scenes[k]]].append(
                            ("sample_data.json", f"sample_data {row['token']}: dangling calibrated_sensor_token "
                                                 f"{row['calibrated_sensor_token']}")
                        )
                    else:
                        kept.append(k)
                rows, samples, scenes, sensors = _take(kept, rows, samples, scenes, sensors)
            tokens = [_s_bytes(row["token"]) for row in rows]
            sample_data_hashes.extend(map(hash, tokens))
            filenames = [row["filename"].encode() for row in rows]
            for scene, start, end in _runs(scenes):
                self.sample_data_tokens.extend(scene, tokens[start:end])
                self.sample_data_filenames.extend(scene, filenames[start:end])
            columns.extend((
                scenes,
                samples,
                [row["ego_pose_token"] for row in rows],
                sensors,
                [us_to_ns(row["timestamp"]) for row in rows],
                [bool(row["is_key_frame"]) for row in rows],
                [int(row.get("width") or 0) for row in rows],
                [int(row.get("height") or 0) for row in rows],
            ))
        self.sample_data_tokens.finish()
        self.sample_data_filenames.finish()
        # Joined before grouping: the pose tokens become row numbers before the columns are reordered.
        sample_data = self._join_poses(columns.columns(), pose_columns.pop("token"))
        # A repeated token's later row is skipped like a row whose pose dangles (its columns stay aligned).
        sample_data["pose"][self._repeated_sample_data(np.frombuffer(sample_data_hashes, dtype=np.int64),
                                                       sample_data["scene"])] = -1
        del sample_data_hashes
        self.sample_data = _grouped(sample_data, "scene")
        self.sample_data_offsets = np.searchsorted(self.sample_data.pop("scene"), np.arange(len(self.scene) + 1))

        instance_row = {token: i for i, token in enumerate(self.instance_tokens)}
        self.visibility_tokens = list(self.visibility)
        visibility_row = {token: i for i, token in enumerate(self.visibility_tokens)}
        #: distinct attribute-token tuples; annotations hold an index into this list
        self.attribute_sets: list[tuple[str, ...]] = []
        attribute_set_row: dict[tuple[str, ...], int] = {}
        #: each scene's annotation tokens (the columns' order within the scene)
        self.annotation_tokens = _SceneStrings(len(self.scene))
        links = {name: _SceneStrings(len(self.scene)) for name in ("prev", "next")}
        columns = _ColumnBlocks(
            {
                "scene": "i4",
                "sample": "i4",
                "instance": "i4",
                "box": "f8",
                "attributes": "i4",
                "visibility": "i4",
                "num_lidar_pts": "i4",
                "num_radar_pts": "i4",
            },
            _max_rows(table_dir / "sample_annotation.json", "sample_annotation"),
        )
        # Each kept row's token hash, for the duplicate check after the table (8 bytes a row; a set of the
        # tokens held ~90 bytes a row, the conversion's peak: 19 of its 181 MB on the 200-scene benchmark).
        token_hashes = array.array("q")
        # Visibility token -> row; "" (and a missing or null field) is no visibility.
        visibility_index = {"": -1, **visibility_row}
        for rows in self._good_chunks("sample_annotation", sample_row):
            samples = [sample_row.get(token, -1) for token in map(_SAMPLE_TOKEN, rows)]
            scenes = [scene_of_sample[sample] if sample >= 0 else -1 for sample in samples]
            instance_rows = [instance_row.get(token, -1) for token in map(_INSTANCE_TOKEN, rows)]
            attributes = [tuple(row.get("attribute_tokens", ())) for row in rows]
            visibility_tokens = [row.get("visibility_token") or "" for row in rows]
            visibilities = [visibility_index.get(token, _UNKNOWN) if type(token) is str else _UNKNOWN
                            for token in visibility_tokens]
            if (-1 in scenes or -1 in instance_rows or _UNKNOWN in visibilities
                    or not all(token in self.attribute for token in itertools.chain.from_iterable(attributes))):
                kept = []
                for k, row in enumerate(rows):
                    if scenes[k] < 0:
                        self.orphans.append(("sample_annotation.json", f"sample_annotation {row['token']}: dangling "
                                                                       f"sample_token {row['sample_token']}"))
                        continue
                    bad = [("instance_token", row["instance_token"])] if instance_rows[k] < 0 else []
                    bad += [("attribute_token", t) for t in attributes[k] if t not in self.attribute]
                    bad += [("visibility_token", visibility_tokens[k])] if visibilities[k] == _UNKNOWN else []
                    if bad:
                        self.problems[self.scene_tokens[scenes[k]]].append(
                            ("sample_annotation.json", f"sample_annotation {row['token']}: dangling {bad[0][0]} "
                                                       f"{bad[0][1]}"))
                        continue
                    kept.append(k)
                rows, samples, scenes, instance_rows, attributes, visibilities = _take(
                    kept, rows, samples, scenes, instance_rows, attributes, visibilities)
            token_hashes.extend([hash(row["token"]) for row in rows])
            attribute_sets = []
            for attribute_tokens in attributes:
                index = attribute_set_row.get(attribute_tokens)
                if index is None:
                    index = attribute_set_row[attribute_tokens] = len(self.attribute_sets)
                    self.attribute_sets.append(attribute_tokens)
                attribute_sets.append(index)
            annotation_tokens = [_s_bytes(row["token"]) for row in rows]
            link_values = {name: [_s_bytes(row.get(name, "")) for row in rows] for name in links}
            for scene, start, end in _runs(scenes):
                self.annotation_tokens.extend(scene, annotation_tokens[start:end])
                for name, strings in links.items():
                    strings.extend(scene, link_values[name][start:end])
            columns.extend((
                scenes,
                samples,
                instance_rows,
                [(*row["translation"], *row["size"], *row["rotation"]) for row in rows],
                attribute_sets,
                visibilities,
                [int(row.get("num_lidar_pts", -1)) for row in rows],
                [int(row.get("num_radar_pts", -1)) for row in rows],
            ))
        self.annotation_tokens.finish()
        for strings in links.values():
            strings.finish()
        annotations = columns.columns()
        repeated = self._repeated_tokens(np.frombuffer(token_hashes, dtype=np.int64), annotations["scene"])
        del token_hashes
        if len(repeated):
            # The later rows go, from the columns and from their scenes' strings (aligned with the columns).
            keep = np.ones(len(annotations["scene"]), dtype=bool)
            keep[repeated] = False
            scene_of_row = annotations["scene"]
            for scene in np.unique(scene_of_row[repeated]).tolist():
                in_scene = keep[scene_of_row == scene]
                for strings in (self.annotation_tokens, *links.values()):
                    strings.keep(scene, in_scene)
            annotations = {name: column[keep] for name, column in annotations.items()}
        self.annotations = _grouped(annotations, "scene")
        self.annotation_offsets = np.searchsorted(self.annotations.pop("scene"), np.arange(len(self.scene) + 1))
        #: (annotation row, "prev" | "next") -> the token of a link that is not to an annotation of its scene
        self.dangling_links: dict[tuple[int, str], str] = {}
        self._resolve_links(links)
        _return_freed_heap()

    def _good_chunks(self, table: str, sample_row: dict[str, int] | None = None) -> Iterator[list[dict[str, Any]]]:
        """The rows of ``table`` that pass :func:`row_problem`, a chunk read at a time (never an empty one).

        The others are reported (:meth:`_bad`) and skipped. A chunk of rows is checked at once by
        :func:`rows_valid`; row by row only when it finds something.
        """
        for rows in iter_json_chunks(self.table_dir / f"{table}.json"):
            if not rows_valid(table, rows):
                rows = [row for row in rows if not self._bad(table, row, sample_row)]
            if rows:
                yield rows

    def _good_rows(self, table: str) -> Iterator[dict[str, Any]]:
        """The rows of :meth:`_good_chunks` one by one."""
        for rows in self._good_chunks(table):
            yield from rows

    def _bad(self, table: str, row: Any, sample_row: dict[str, int] | None = None) -> bool:
        """Whether ``row`` fails :func:`row_problem` (then reported, per scene when its sample is known)."""
        if not isinstance(row, dict):
            self.orphans.append((f"{table}.json", f"{table}: expected an object per row, got {json.dumps(row)[:80]}"))
            return True
        error, warning = row_problem(table, row)
        if warning is not None:
            self.warnings.append((f"{table}.json", warning))
        if error is None:
            return False
        sample = sample_row.get(row.get("sample_token"), -1) if sample_row is not None else -1  # type: ignore[arg-type]
        if sample >= 0 and self.sample_scene[sample] >= 0:
            self.problems[self.scene_tokens[self.sample_scene[sample]]].append((f"{table}.json", f"{error}; dropped"))
        else:
            self.orphans.append((f"{table}.json", f"{error}; dropped"))
        return True

    def _join_poses(self, sample_data: dict[str, np.ndarray], pose_tokens: np.ndarray) -> dict[str, np.ndarray]:
        """Replaces the ``pose_token`` column by ``pose``, the row in ``ego_pose``, -1 when it dangles (in place).

        A row whose pose dangles is reported here and skipped by :meth:`sample_data_rows` (kept in the
        columns, which stay aligned with the scene's tokens and filenames).

        Args:
            sample_data: the sample_data columns.
            pose_tokens: (P,) ego_pose tokens in table order (freed here when the caller holds no other reference).
        """
        wanted = sample_data.pop("pose_token")
        order = np.argsort(pose_tokens, kind="stable")
        # A token given twice: the first row is the one found (stable order), the later one is reported.
        for token in np.unique(pose_tokens[order][1:][pose_tokens[order][1:] == pose_tokens[order][:-1]]).tolist():
            self.orphans.append(("ego_pose.json", f"ego_pose {token.decode()}: expected unique tokens, got this token "
                                                  "twice; the later row is dropped"))
        # Searched in sorted order through ``sorter``: no sorted copy of the tokens (83 MB on trainval).
        position = np.clip(np.searchsorted(pose_tokens, wanted, sorter=order), 0, max(len(order) - 1, 0))
        found = pose_tokens[order[position]] == wanted if len(order) else np.zeros(len(wanted), dtype=bool)
        del pose_tokens
        missing = np.flatnonzero(~found)
        if len(missing):
            # Each such row's place among its scene's rows (table order), where its token is.
            scenes = sample_data["scene"]
            place = _rank_in_group(scenes)[missing]
            tokens: dict[int, np.ndarray] = {}
            for i, k in zip(missing.tolist(), place.tolist(), strict=True):
                scene = int(scenes[i])
                if scene not in tokens:
                    tokens[scene] = self.sample_data_tokens.values(scene)
                self.problems[self.scene_tokens[scene]].append(
                    ("sample_data.json", f"sample_data {tokens[scene][k].decode()}: dangling ego_pose_token "
                                         f"{wanted[i].decode()}")
                )
        sample_data["pose"] = np.where(found, order[position] if len(order) else -1, -1).astype(np.int32)
        return sample_data

    def _repeated_sample_data(self, token_hashes: np.ndarray, scenes: np.ndarray) -> np.ndarray:
        """Rows (table order) whose sample_data token an earlier row has, each reported as an error.

        Rows with equal hashes are compared by their tokens, so a hash collision drops nothing.

        Args:
            token_hashes: (D,) ``hash`` of each kept sample_data token, in table order.
            scenes: (D,) each row's scene.
        """
        order = np.argsort(token_hashes, kind="stable")
        same = np.flatnonzero(token_hashes[order][1:] == token_hashes[order][:-1])
        if not len(same):
            return np.zeros(0, dtype=np.int64)
        candidates = np.unique(np.r_[order[same], order[same + 1]])  # table order: the first of a token is kept
        place = _rank_in_group(scenes)[candidates]
        values: dict[int, np.ndarray] = {}
        seen: set[bytes] = set()
        repeated: list[int] = []
        for row, k in zip(candidates.tolist(), place.tolist(), strict=True):
            scene = int(scenes[row])
            if scene not in values:
                values[scene] = self.sample_data_tokens.values(scene)
            token = bytes(values[scene][k])
            if token in seen:
                repeated.append(row)
                self.problems[self.scene_tokens[scene]].append(
                    ("sample_data.json", f"sample_data {token.decode()}: expected unique tokens, got this token twice; "
                                         "the later row is dropped"))
            seen.add(token)
        return np.asarray(repeated, dtype=np.int64)

    def _repeated_tokens(self, token_hashes: np.ndarray, scenes: np.ndarray) -> np.ndarray:
        """Rows (table order) whose annotation token an earlier row has, each reported as an error.

        Rows with equal hashes are compared by their tokens, so a hash collision drops nothing.

        Args:
            token_hashes: (A,) ``hash`` of each kept annotation's token, in table order.
            scenes: (A,) each row's scene; a row's token is its scene's :attr:`annotation_tokens` value at its
                rank among the scene's rows.
        """
        order = np.argsort(token_hashes, kind="stable")  # equal hashes stay in table order
        sorted_hashes = token_hashes[order]
        shared = np.flatnonzero(sorted_hashes[1:] == sorted_hashes[:-1])
        if not len(shared):
            return np.zeros(0, dtype=np.int64)
        rank = _rank_in_group(scenes)
        values: dict[int, np.ndarray] = {}

        def token(row: int) -> bytes:
            scene = int(scenes[row])
            if scene not in values:
                values[scene] = self.annotation_tokens.values(scene)
            return bytes(values[scene][rank[row]])

        repeated: list[int] = []
        for start in np.unique(np.searchsorted(sorted_hashes, sorted_hashes[shared])).tolist():
            group = order[start:np.searchsorted(sorted_hashes, sorted_hashes[start], side="right")].tolist()
            seen: set[bytes] = set()
            for row in group:
                text = token(row)
                if text in seen:
                    repeated.append(row)
                    self.problems[self.scene_tokens[int(scenes[row])]].append(
                        ("sample_annotation.json", f"sample_annotation {text.decode()}: expected unique tokens, got "
                                                   f"this token twice; the later row is dropped"))
                seen.add(text)
        return np.array(sorted(repeated), dtype=np.int64)

    def _resolve_links(self, links: dict[str, _SceneStrings]) -> None:
        """Adds the annotations' ``prev`` / ``next`` columns: the linked annotation's row in its scene.

        -1: no link (empty token); :data:`DANGLING`: a token of no annotation of the scene (another
        scene's or none at all), kept in ``dangling_links``.

        Args:
            links: "prev" / "next" -> each scene's link tokens (emptied here, a scene at a time).
        """
        offsets = self.annotation_offsets
        for name in links:
            self.annotations[name] = np.full(offsets[-1], -1, dtype=np.int32)
        for scene, (start, end) in enumerate(zip(offsets[:-1].tolist(), offsets[1:].tolist(), strict=True)):
            if start == end:
                continue
            scene_tokens = self.annotation_tokens.values(scene)
            order = np.argsort(scene_tokens, kind="stable")
            tokens_sorted = scene_tokens[order]
            for name, strings in links.items():
                scene_links = strings.values(scene)
                strings.drop(scene)
                position = np.minimum(np.searchsorted(tokens_sorted, scene_links), end - start - 1)
                found = tokens_sorted[position] == scene_links
                linked = scene_links != b""
                self.annotations[name][start:end] = np.where(linked & found, order[position],
                                                             np.where(linked, DANGLING, -1))
                for k in np.flatnonzero(linked & ~found).tolist():
                    self.dangling_links[start + k, name] = scene_links[k].decode()

    def dangling_link(self, scene_token: str, k: int, name: str) -> str:
        """The token of annotation ``k`` (of the scene's) ``name`` ("prev" | "next") link, which is :data:`DANGLING`."""
        return self.dangling_links[int(self.annotation_offsets[self.scene_tokens.index(scene_token)]) + k, name]

    def sample_data_rows(self, scene_token: str) -> list[SampleDataRow]:
        """The scene's sample_data rows (in table order), without those whose ego pose dangles."""
        i = self.scene_tokens.index(scene_token)
        part = slice(self.sample_data_offsets[i], self.sample_data_offsets[i + 1])
        c = {name: column[part] for name, column in self.sample_data.items()}
        c["token"], c["filename"] = self.sample_data_tokens.values(i), self.sample_data_filenames.values(i)
        if not np.all(c["pose"] >= 0):
            c = {name: column[c["pose"] >= 0] for name, column in c.items()}
        return [
            SampleDataRow(
                token=token.decode(),
                sample_token=self.sample_tokens[sample],
                ego_pose_row=pose,
                calibrated_sensor_token=self.cs_tokens[cs],
                timestamp_ns=time_ns,
                filename=filename.decode(),
                is_key_frame=key,
                width=width,
                height=height,
            )
            for token, sample, pose, cs, time_ns, filename, key, width, height in zip(
                c["token"].tolist(),
                c["sample"].tolist(),
                c["pose"].tolist(),
                c["cs"].tolist(),
                c["time_ns"].tolist(),
                c["filename"].tolist(),
                c["key"].tolist(),
                c["width"].tolist(),
                c["height"].tolist(),
                strict=True,
            )
        ]

    def annotation_columns(self, scene_token: str) -> dict[str, np.ndarray]:
        """The scene's sample_annotation rows (in table order) as column views.

        Returns:
            ``token`` (N,) bytes; ``sample`` (N,) rows of the sample columns; ``instance`` (N,) indexes
            into ``instance_tokens``; ``box`` (N, 10) translation, size (w, l, h), rotation (w, x, y, z);
            ``attributes`` (N,) indexes into ``attribute_sets``; ``visibility`` (N,) indexes into
            ``visibility_tokens`` or -1; ``num_lidar_pts``, ``num_radar_pts`` (N,) (-1 when absent);
            ``prev``, ``next`` (N,) the linked annotation's position in these columns, -1 when none,
            :data:`DANGLING` when its token is of no annotation of this scene (:meth:`dangling_link`).
        """
        i = self.scene_tokens.index(scene_token)
        part = slice(self.annotation_offsets[i], self.annotation_offsets[i + 1])
        columns = {name: column[part] for name, column in self.annotations.items()}
        columns["token"] = self.annotation_tokens.values(i)
        columns["box"] = columns["box"].reshape(-1, 10)
        return columns
