"""nuScenes and nuScenes-schema datasets (Lyft Level 5) -> the unified format.

The source's rows of DESIGN.md §2, and what this module does with each:

=================  ==========================================================================
nuScenes           how it is converted
=================  ==========================================================================
frame of labels    global (map) frame -> ``world`` (scene metadata says so; not re-centred)
box origin         centre -> centre
size order         **w, l, h** -> l, w, h (``Boxes3D.from_nuscenes``)
rotation           quaternion (w, x, y, z) of the box in global -> same, in ``world``
ego z              the ego pose's z is 0 in nuScenes (poses are in the map plane); kept as given
ego poses          every sample_data has its own ego_pose -> one ``world -> ego`` entry on ``/tf``
                   stamped with the *sample_data's* timestamp (see Lyft below), de-duplicated
sweeps             non-key-frame sample_data -> sensor messages at their own times, not frames
cameras            images already undistorted -> CameraCalibration with K and empty D; camera
                   sensor frames are already optical -> calibrated_sensor goes to /tf_static as is
lidar              ``.pcd.bin`` = 5 float32 (x, y, z, intensity, ring) -> stored untouched in the
                   sensor's own frame (LIDAR_TOP is turned 90° about z; that is on /tf_static)
radar              binary ``.pcd`` -> header parsed, every field kept
Lyft timestamps    float microseconds (``1556675185903083.2``) -> int64 ns, see :func:`us_to_ns`
=================  ==========================================================================

Frames are samples (key frames); a frame's ``sensor_timestamps_ns`` holds each channel's key-frame
sample_data time. Sensor frames are ``ego/<channel lower-case>`` (``ego/lidar_top``, ``ego/cam_front``).

Lyft quirk: every Lyft ego_pose row carries the LiDAR's timestamp although the poses referenced by
camera sample_data were interpolated to each camera's capture time (7 different poses share one
``ego_pose.timestamp``). Stamping each pose with its sample_data's timestamp (in nuScenes both are
equal) keeps lookups at a camera's time on that camera's own pose.

The tables are read without nuscenes-devkit and without building its object graph: the big tables
(sample_data, ego_pose, sample_annotation) are stream-parsed record by record and only the fields
used here are kept, grouped by scene; scenes are converted one at a time.
"""

from __future__ import annotations

import json
import math
import re
from collections import defaultdict
from collections.abc import Iterator
from dataclasses import dataclass, field
from decimal import ROUND_HALF_EVEN, Decimal
from pathlib import Path
from typing import Any

import numpy as np

from avdata.converters.base import ConvertConfig, Converter, ConverterOptions, Report
from avdata.errors import InputError
from avdata.frames import Boxes3D, Transform
from avdata.schema import DatasetWriter, ObjectLabels

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

#: nuScenes and Lyft category name -> unified class. nuScenes names are matched by the longest
#: dotted prefix (``vehicle.bus.rigid`` -> ``vehicle.bus``); Lyft's flat names are listed verbatim.
CLASS_MAP: dict[str, str] = {
    "vehicle.car": "car",
    "vehicle.truck": "truck",
    "vehicle.bus": "bus",
    "vehicle.trailer": "trailer",
    "vehicle.construction": "construction_vehicle",
    "vehicle.motorcycle": "motorcycle",
    "vehicle.bicycle": "bicycle",
    "human.pedestrian": "pedestrian",
    "movable_object.trafficcone": "traffic_cone",
    "movable_object.barrier": "barrier",
    "animal": "animal",
    # Lyft Level 5
    "car": "car",
    "truck": "truck",
    "bus": "bus",
    "pedestrian": "pedestrian",
    "bicycle": "bicycle",
    "motorcycle": "motorcycle",
    "emergency_vehicle": "other",
    "other_vehicle": "other",
}

#: Size of the velocity window of the devkit's ``NuScenes.box_velocity`` (seconds).
MAX_VELOCITY_TIME_DIFF_S = 1.5

_PCD_TYPES = {
    ("F", 4): "<f4",
    ("F", 8): "<f8",
    ("I", 1): "i1",
    ("I", 2): "<i2",
    ("I", 4): "<i4",
    ("U", 1): "u1",
    ("U", 2): "<u2",
    ("U", 4): "<u4",
}


def unified_class(category: str) -> str:
    """The unified class of a nuScenes or Lyft category name (``other`` when unmapped)."""
    name = category
    while name:
        if name in CLASS_MAP:
            return CLASS_MAP[name]
        name = name.rpartition(".")[0]
    return "other"


def us_to_ns(timestamp_us: int | float) -> int:
    """Microseconds as the tables store them -> int64 nanoseconds, exactly.

    nuScenes stores integers: ``× 1000``. Lyft stores floats such as ``1556675185903083.2``. Their
    JSON text is Python's ``repr`` of the float (the shortest decimal that round-trips), so the
    text is recovered from the float with ``repr``; that decimal × 1000 is rounded half to even to
    whole nanoseconds: ``1556675185903083.2`` -> ``1556675185903083200`` (the float's binary value,
    ...083.25, would give ...083250).
    """
    if isinstance(timestamp_us, bool) or not isinstance(timestamp_us, (int, float)):
        raise InputError(f"expected a timestamp in microseconds, got {timestamp_us!r}")
    if isinstance(timestamp_us, int):
        return timestamp_us * 1000
    if not math.isfinite(timestamp_us):
        raise InputError(f"expected a finite timestamp in microseconds, got {timestamp_us!r}")
    if timestamp_us.is_integer():
        return int(timestamp_us) * 1000
    return int((Decimal(repr(timestamp_us)) * 1000).quantize(Decimal(1), rounding=ROUND_HALF_EVEN))


def iter_json_array(path: Path, chunk_chars: int = 1 << 20) -> Iterator[dict[str, Any]]:
    """The objects of a JSON array file (a nuScenes table), parsed a chunk at a time with bounded memory.

    Each chunk read is cut after its last ``}``. nuScenes records are flat objects, so that cut is a
    record boundary unless a string holds a ``}``; the records before it are then decoded by one
    ``json.loads`` call, otherwise one at a time with ``raw_decode`` up to the last complete one.

    Args:
        path: a file holding one JSON array of objects.
        chunk_chars: characters read at a time.
    """
    decoder = json.JSONDecoder()
    with open(path, encoding="utf-8") as stream:
        buffer = stream.read(chunk_chars).lstrip()
        if not buffer.startswith("["):
            raise InputError(f"{path}: expected a JSON array, got {buffer[:20]!r}")
        buffer = buffer[1:]
        at_end = False
        while not at_end:
            more = stream.read(chunk_chars)
            at_end = not more
            buffer += more
            cut = buffer.rfind("}") + 1
            try:
                records = json.loads("[" + buffer[:cut].lstrip(" \t\r\n,") + "]") if cut else None
            except json.JSONDecodeError:
                records = None
            if records is not None:
                buffer = buffer[cut:]
            else:
                records, buffer = _decode_records(decoder, buffer, path, at_end)
            for record in records:
                if not isinstance(record, dict):
                    raise InputError(f"{path}: expected an array of objects, got {type(record).__name__}")
                yield record
    rest = buffer.strip(" \t\r\n,")
    if rest != "]":
        raise InputError(f"{path}: expected the array to end with ']', got {rest[:20]!r}")


_SEPARATORS = re.compile(r"[\s,]*")


def _decode_records(decoder: json.JSONDecoder, buffer: str, path: Path, at_end: bool) -> tuple[list[Any], str]:
    """(the complete records at the start of ``buffer``, what follows them), one ``raw_decode`` each."""
    records: list[Any] = []
    position = 0
    while True:
        # The pattern matches the empty string, so match() never returns None here.
        position = _SEPARATORS.match(buffer, position).end()  # type: ignore[union-attr]
        if position >= len(buffer) or buffer[position] == "]":
            return records, buffer[position:]
        try:
            record, position = decoder.raw_decode(buffer, position)
        except json.JSONDecodeError as error:
            if at_end:
                raise InputError(f"{path}: malformed JSON near character {error.pos}: {error.msg}") from None
            return records, buffer[position:]
        records.append(record)


def read_pcd(data: bytes, source: str) -> np.ndarray:
    """Every field of a binary PCD file (nuScenes radar) as a packed little-endian structured array.

    Args:
        data: the file's bytes.
        source: file name for error messages.

    Returns:
        (N,) structured array with the header's FIELDS in order (x, y, z first in nuScenes radar);
        a field with COUNT k > 1 becomes k fields ``name_0 .. name_{k-1}``.
    """
    header: dict[str, list[str]] = {}
    offset = 0
    while True:
        end = data.find(b"\n", offset)
        if end < 0:
            raise InputError(f"{source}: expected a PCD header ending in a DATA line, got none")
        line = data[offset:end].decode("ascii", errors="replace").strip()
        offset = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        header[key.upper()] = values
        if key.upper() == "DATA":
            break
    if header["DATA"] != ["binary"]:
        raise InputError(f"{source}: expected PCD 'DATA binary', got 'DATA {' '.join(header['DATA'])}'")
    names = header.get("FIELDS", [])
    sizes = header.get("SIZE", [])
    types = header.get("TYPE", [])
    counts = header.get("COUNT", ["1"] * len(names))
    if not names or not (len(names) == len(sizes) == len(types) == len(counts)):
        raise InputError(f"{source}: expected FIELDS, SIZE, TYPE, COUNT of equal length, got {header}")
    dtype = []
    for name, size, kind, count in zip(names, sizes, types, counts, strict=True):
        code = _PCD_TYPES.get((kind.upper(), int(size)))
        if code is None:
            raise InputError(f"{source}: field {name!r}: expected a PCD TYPE/SIZE among {sorted(_PCD_TYPES)}, got {kind}/{size}")
        dtype.extend([(name, code)] if int(count) == 1 else [(f"{name}_{i}", code) for i in range(int(count))])
    record = np.dtype(dtype)
    n_points = int(header.get("POINTS", header.get("WIDTH", ["0"]))[0])
    if len(data) - offset < n_points * record.itemsize:
        raise InputError(f"{source}: expected {n_points} points of {record.itemsize} bytes, got {len(data) - offset} bytes")
    return np.frombuffer(data, dtype=record, count=n_points, offset=offset).copy()


def read_lidar_bin(data: bytes, source: str) -> dict[str, np.ndarray]:
    """A ``.pcd.bin`` / Lyft ``.bin`` sweep: 5 float32 per point (x, y, z, intensity, ring).

    Returns:
        ordered float32 columns x, y, z, intensity, ring, each (N,), exactly as stored.
    """
    if len(data) % 20:
        raise InputError(f"{source}: expected a multiple of 20 bytes (5 float32 per point), got {len(data)} bytes")
    values = np.frombuffer(data, dtype="<f4").reshape(-1, 5)
    return {
        "x": values[:, 0],
        "y": values[:, 1],
        "z": values[:, 2],
        "intensity": values[:, 3],
        "ring": values[:, 4],
    }


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


@dataclass(frozen=True, slots=True, kw_only=True)
class AnnotationRow:
    """The fields of one sample_annotation row this converter uses."""

    token: str
    sample_token: str
    instance_token: str
    translation: tuple[float, float, float]
    size_wlh: tuple[float, float, float]
    rotation_wxyz: tuple[float, float, float, float]
    attribute_tokens: tuple[str, ...]
    visibility_token: str
    num_lidar_pts: int
    num_radar_pts: int
    prev: str
    next: str


class _ColumnBlocks:
    """Accumulates table columns as numpy arrays, a block of records at a time (bounded overhead).

    Args:
        dtypes: column name -> numpy dtype ("S" for byte strings of any width), in the order of the
            tuples given to :meth:`append`.
    """

    BLOCK = 1 << 12

    def __init__(self, dtypes: dict[str, str]):
        self.dtypes = dtypes
        self.pending: list[tuple[Any, ...]] = []
        self.blocks: dict[str, list[np.ndarray]] = {name: [] for name in dtypes}

    def append(self, values: tuple[Any, ...]) -> None:
        self.pending.append(values)
        if len(self.pending) >= self.BLOCK:
            self._flush()

    def _flush(self) -> None:
        if self.pending:
            for (name, dtype), column in zip(self.dtypes.items(), zip(*self.pending, strict=True), strict=True):
                self.blocks[name].append(np.asarray(column, dtype=dtype))
            self.pending.clear()

    def columns(self) -> dict[str, np.ndarray]:
        """The columns so far, in append order (the accumulator is emptied)."""
        self._flush()
        columns = {
            name: np.concatenate(blocks) if blocks else np.zeros(0, dtype=self.dtypes[name])
            for name, blocks in self.blocks.items()
        }
        self.blocks = {name: [] for name in self.dtypes}
        return columns

    def grouped(self, group: str) -> dict[str, np.ndarray]:
        """The columns, sorted stably by the int column ``group`` (the accumulator is emptied)."""
        columns = self.columns()
        order = np.argsort(columns[group], kind="stable")
        return {name: column[order] for name, column in columns.items()}


class NuScenesTables:
    """The lookups the conversion needs, built from one version directory of nuScenes-schema tables.

    Small tables are kept as token -> row dicts. The big ones (sample_data, ego_pose,
    sample_annotation) are stream-parsed into numpy columns (tokens as fixed-width bytes, links as
    row numbers) sorted by scene, so a scene's rows are one slice. Dangling tokens found while
    parsing are kept per scene in ``problems`` (file, message) and the record is dropped; records
    whose sample does not exist belong to no scene and are kept in ``orphans``.

    Args:
        table_dir: the folder of ``*.json`` tables (``<dataroot>/<version>``).
    """

    def __init__(self, table_dir: Path):
        missing = [t for t in REQUIRED_TABLES if not (table_dir / f"{t}.json").is_file()]
        if missing:
            raise InputError(f"{table_dir}: expected the nuScenes tables {list(REQUIRED_TABLES)}, missing {', '.join(missing)}")
        self.table_dir = table_dir

        def small(name: str) -> dict[str, dict[str, Any]]:
            return {row["token"]: row for row in iter_json_array(table_dir / f"{name}.json")}

        self.scene = small("scene")
        self.log = small("log")
        self.sensor = small("sensor")
        self.calibrated_sensor = small("calibrated_sensor")
        self.category = small("category")
        self.attribute = small("attribute")
        self.visibility = small("visibility")
        self.instance = small("instance")
        self.scene_by_name = {row["name"]: token for token, row in self.scene.items()}
        map_path = table_dir / "map.json"
        self.map_of_log: dict[str, dict[str, Any]] = {}
        if map_path.is_file():
            for row in iter_json_array(map_path):
                for log_token in row.get("log_tokens", []):
                    self.map_of_log[log_token] = row
        scene_index = {token: i for i, token in enumerate(self.scene)}
        self.scene_tokens = list(self.scene)
        self.problems: dict[str, list[tuple[str, str]]] = defaultdict(list)
        #: (file, message) of records that belong to no scene, reported with the first scene
        self.orphans: list[tuple[str, str]] = []

        #: sample tokens, (S,) scene index, (S,) timestamp as stored (microseconds), (S,) int64 ns
        self.sample_tokens: list[str] = []
        sample_scene, sample_us, sample_ns = [], [], []
        for row in iter_json_array(table_dir / "sample.json"):
            self.sample_tokens.append(row["token"])
            sample_scene.append(scene_index.get(row["scene_token"], -1))
            sample_us.append(float(row["timestamp"]))
            sample_ns.append(us_to_ns(row["timestamp"]))
        self.sample_scene = np.asarray(sample_scene, dtype=np.int64)
        self.sample_us = np.asarray(sample_us, dtype=np.float64)
        self.sample_ns = np.asarray(sample_ns, dtype=np.int64)
        sample_row = {token: i for i, token in enumerate(self.sample_tokens)}
        for i in np.flatnonzero(self.sample_scene < 0):
            self.orphans.append(("sample.json", f"sample {self.sample_tokens[i]}: dangling scene_token"))

        poses = _ColumnBlocks({"token": "S", "pose": "f8"})
        for row in iter_json_array(table_dir / "ego_pose.json"):
            poses.append((row["token"], (*row["rotation"], *row["translation"])))
        pose_columns = poses.columns()
        #: (P, 7) ego poses: quaternion (w, x, y, z) then translation, in ego_pose.json order.
        self.ego_pose = pose_columns["pose"].reshape(-1, 7)

        self.cs_tokens = list(self.calibrated_sensor)
        cs_row = {token: i for i, token in enumerate(self.cs_tokens)}
        columns = _ColumnBlocks(
            {
                "token": "S",
                "scene": "i8",
                "sample": "i8",
                "pose_token": "S",
                "cs": "i8",
                "time_ns": "i8",
                "key": "?",
                "width": "i4",
                "height": "i4",
                "filename": "S",
            }
        )
        for row in iter_json_array(table_dir / "sample_data.json"):
            sample = sample_row.get(row["sample_token"], -1)
            scene = int(self.sample_scene[sample]) if sample >= 0 else -1
            if scene < 0:
                self.orphans.append(
                    ("sample_data.json", f"sample_data {row['token']}: dangling sample_token {row['sample_token']}")
                )
                continue
            if row["calibrated_sensor_token"] not in cs_row:
                self.problems[self.scene_tokens[scene]].append(
                    (
                        "sample_data.json",
                        f"sample_data {row['token']}: dangling calibrated_sensor_token {row['calibrated_sensor_token']}",
                    )
                )
                continue
            columns.append(
                (
                    row["token"],
                    scene,
                    sample,
                    row["ego_pose_token"],
                    cs_row[row["calibrated_sensor_token"]],
                    us_to_ns(row["timestamp"]),
                    bool(row["is_key_frame"]),
                    int(row.get("width") or 0),
                    int(row.get("height") or 0),
                    row["filename"].encode(),
                )
            )
        self.sample_data = self._join_poses(columns.grouped("scene"), pose_columns["token"])
        self.sample_data_offsets = np.searchsorted(self.sample_data["scene"], np.arange(len(self.scene) + 1))

        self.instance_tokens = list(self.instance)
        instance_row = {token: i for i, token in enumerate(self.instance_tokens)}
        self.visibility_tokens = list(self.visibility)
        visibility_row = {token: i for i, token in enumerate(self.visibility_tokens)}
        #: distinct attribute-token tuples; annotations hold an index into this list
        self.attribute_sets: list[tuple[str, ...]] = []
        attribute_set_row: dict[tuple[str, ...], int] = {}
        columns = _ColumnBlocks(
            {
                "token": "S",
                "scene": "i8",
                "sample": "i8",
                "instance": "i8",
                "box": "f8",
                "attributes": "i8",
                "visibility": "i8",
                "num_lidar_pts": "i8",
                "num_radar_pts": "i8",
                "prev": "S",
                "next": "S",
            }
        )
        for row in iter_json_array(table_dir / "sample_annotation.json"):
            sample = sample_row.get(row["sample_token"], -1)
            scene = int(self.sample_scene[sample]) if sample >= 0 else -1
            if scene < 0:
                self.orphans.append(
                    ("sample_annotation.json", f"sample_annotation {row['token']}: dangling sample_token {row['sample_token']}")
                )
                continue
            attributes = tuple(row.get("attribute_tokens", ()))
            visibility = row.get("visibility_token", "")
            bad = [("instance_token", row["instance_token"])] if row["instance_token"] not in instance_row else []
            bad += [("attribute_token", t) for t in attributes if t not in self.attribute]
            bad += [("visibility_token", visibility)] if visibility and visibility not in visibility_row else []
            if bad:
                self.problems[self.scene_tokens[scene]].append(
                    ("sample_annotation.json", f"sample_annotation {row['token']}: dangling {bad[0][0]} {bad[0][1]}")
                )
                continue
            if attributes not in attribute_set_row:
                attribute_set_row[attributes] = len(self.attribute_sets)
                self.attribute_sets.append(attributes)
            columns.append(
                (
                    row["token"],
                    scene,
                    sample,
                    instance_row[row["instance_token"]],
                    (*row["translation"], *row["size"], *row["rotation"]),
                    attribute_set_row[attributes],
                    visibility_row[visibility] if visibility else -1,
                    int(row.get("num_lidar_pts", -1)),
                    int(row.get("num_radar_pts", -1)),
                    row.get("prev", ""),
                    row.get("next", ""),
                )
            )
        self.annotations = columns.grouped("scene")
        self.annotation_offsets = np.searchsorted(self.annotations["scene"], np.arange(len(self.scene) + 1))

    def _join_poses(self, sample_data: dict[str, np.ndarray], pose_tokens: np.ndarray) -> dict[str, np.ndarray]:
        """Replaces the ``pose_token`` column by ``pose``, the row in ``ego_pose``; drops dangling ones.

        Args:
            sample_data: the sample_data columns.
            pose_tokens: (P,) ego_pose tokens in table order.
        """
        wanted = sample_data.pop("pose_token")
        order = np.argsort(pose_tokens, kind="stable")
        position = np.clip(np.searchsorted(pose_tokens[order], wanted), 0, max(len(order) - 1, 0))
        found = pose_tokens[order][position] == wanted if len(order) else np.zeros(len(wanted), dtype=bool)
        for i in np.flatnonzero(~found):
            self.problems[self.scene_tokens[sample_data["scene"][i]]].append(
                (
                    "sample_data.json",
                    f"sample_data {sample_data['token'][i].decode()}: dangling ego_pose_token {wanted[i].decode()}",
                )
            )
        sample_data["pose"] = order[position] if len(order) else np.zeros(len(wanted), dtype=np.int64)
        return {name: column[found] for name, column in sample_data.items()}

    def sample_data_rows(self, scene_token: str) -> list[SampleDataRow]:
        """The scene's sample_data rows (in table order)."""
        i = self.scene_tokens.index(scene_token)
        part = slice(self.sample_data_offsets[i], self.sample_data_offsets[i + 1])
        c = {name: column[part] for name, column in self.sample_data.items()}
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

    def annotation_rows(self, scene_token: str) -> list[AnnotationRow]:
        """The scene's sample_annotation rows (in table order)."""
        i = self.scene_tokens.index(scene_token)
        part = slice(self.annotation_offsets[i], self.annotation_offsets[i + 1])
        c = {name: column[part] for name, column in self.annotations.items()}
        box = c["box"].reshape(-1, 10).tolist()
        return [
            AnnotationRow(
                token=token.decode(),
                sample_token=self.sample_tokens[sample],
                instance_token=self.instance_tokens[instance],
                translation=tuple(b[:3]),
                size_wlh=tuple(b[3:6]),
                rotation_wxyz=tuple(b[6:]),
                attribute_tokens=self.attribute_sets[attrs],
                visibility_token=self.visibility_tokens[vis] if vis >= 0 else "",
                num_lidar_pts=lidar,
                num_radar_pts=radar,
                prev=prev.decode(),
                next=nxt.decode(),
            )
            for token, sample, instance, b, attrs, vis, lidar, radar, prev, nxt in zip(
                c["token"].tolist(),
                c["sample"].tolist(),
                c["instance"].tolist(),
                box,
                c["attributes"].tolist(),
                c["visibility"].tolist(),
                c["num_lidar_pts"].tolist(),
                c["num_radar_pts"].tolist(),
                c["prev"].tolist(),
                c["next"].tolist(),
                strict=True,
            )
        ]


@dataclass(frozen=True, slots=True, kw_only=True)
class NuScenesOptions(ConverterOptions):
    """Options of the nuScenes converter."""

    version: str | None = field(default=None, metadata={
        "help": "table folder under SRC, e.g. v1.0-mini, v1.0-trainval, v1.01-train (default: the only one present)"})


class NuScenesConverter(Converter):
    """nuScenes / Lyft Level 5 (nuScenes schema): every sample_data, ego pose, calibration and box."""

    name = "nuscenes"
    source = "nuscenes"
    licence = "CC BY-NC-SA 4.0 (nuScenes / Lyft Level 5 terms of use)"
    Options = NuScenesOptions

    def __init__(self, config: ConvertConfig):
        super().__init__(config)
        self._tables: NuScenesTables | None = None

    def __getstate__(self) -> dict[str, Any]:
        return {"config": self.config, "_tables": None}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.config = state["config"]
        self._tables = None

    def release(self) -> None:
        """Drops the parsed tables (tens of MB on trainval) before the index is built."""
        self._tables = None

    def source_files(self, scene: str) -> list[Path]:
        """Every table of the version folder (each scene reads several) and the scene's sensor files."""
        tables = self.tables()
        rows = tables.sample_data_rows(tables.scene_by_name[scene])
        return sorted(tables.table_dir.glob("*.json")) + [Path(self.config.src) / row.filename for row in rows]

    def source_version(self) -> str:
        return self.table_dir().name

    def table_dir(self) -> Path:
        """``SRC/<version>``; with no version given, the one sub-folder of SRC holding ``scene.json``."""
        src = Path(self.config.src)
        version = self.options.version
        if version:
            path = src / version
            if not path.is_dir():
                raise InputError(f"{src}: expected a table folder {version!r}, got none")
            return path
        found = sorted(p for p in src.iterdir() if (p / "scene.json").is_file()) if src.is_dir() else []
        if len(found) != 1:
            raise InputError(
                f"{src}: expected one version folder holding scene.json (pass --version), got {[p.name for p in found]}"
            )
        return found[0]

    def tables(self) -> NuScenesTables:
        """The lookups, built once per process."""
        if self._tables is None:
            self._tables = NuScenesTables(self.table_dir())
        return self._tables

    def list_scenes(self) -> list[str]:
        return sorted(self.tables().scene_by_name)

    def convert_scene(self, scene: str, writer: DatasetWriter, report: Report) -> None:
        tables = self.tables()
        if scene == self.list_scenes()[0]:
            for file, message in tables.orphans:
                report.error(file, message)
        _SceneConversion(tables, Path(self.config.src), scene, report).write(writer)


class _SceneConversion:
    """Converts one scene (kept as one object so its lookups die with it)."""

    def __init__(self, tables: NuScenesTables, dataroot: Path, name: str, report: Report):
        self.tables = tables
        self.dataroot = dataroot
        self.name = name
        self.report = report
        self.scene_token = tables.scene_by_name[name]
        self.scene = tables.scene[self.scene_token]
        self.version = tables.table_dir.name

    def metadata(self) -> dict[str, Any]:
        log = self.tables.log.get(self.scene["log_token"])
        if log is None:
            self.report.error("scene.json", f"scene {self.scene_token}: dangling log_token {self.scene['log_token']}")
            log = {}
        map_row = self.tables.map_of_log.get(self.scene["log_token"], {})
        return {
            "scene_token": self.scene_token,
            "description": self.scene.get("description", ""),
            "log": log.get("logfile", ""),
            "log_token": self.scene["log_token"],
            "vehicle": log.get("vehicle", ""),
            "location": log.get("location", ""),
            "date_captured": log.get("date_captured", ""),
            "map": map_row.get("filename", ""),
            "map_token": map_row.get("token", ""),
            "split": self.version,
            "world": "the nuScenes global (map) frame of this log, z up; not re-centred",
            "ego_origin": "midpoint of the rear axle (nuScenes ego_pose; Lyft uses the same schema)",
            "time": "UTC epoch (nuScenes / Lyft microseconds x 1000)",
        }

    def write(self, writer: DatasetWriter) -> None:
        tables = self.tables
        metadata = self.metadata()
        for file, message in tables.problems.get(self.scene_token, []):
            self.report.error(file, message)
        samples = self._samples()
        sample_index = {self.tables.sample_tokens[row]: i for i, row in enumerate(samples)}
        data_rows = self._valid_sample_data()
        channels = self._sensors(data_rows)
        data_rows = [row for row in data_rows if row.calibrated_sensor_token in channels]
        with writer.scene(self.name, metadata) as scene:
            scene.add_agent("ego", "vehicle", metadata["ego_origin"])
            first_time: dict[str, int] = {}
            for row in data_rows:
                first_time.setdefault(row.calibrated_sensor_token, row.timestamp_ns)
            for cs_token, (frame, modality, channel) in channels.items():
                calibration = tables.calibrated_sensor[cs_token]
                scene.add_sensor(
                    frame,
                    modality,
                    channel=channel,
                    sensor_token=calibration["sensor_token"],
                    calibrated_sensor_token=cs_token,
                )
                ego_T_sensor = Transform.from_quat_wxyz(
                    np.asarray(calibration["rotation"], dtype=np.float64),
                    np.asarray(calibration["translation"], dtype=np.float64),
                )
                scene.add_static_transform("ego", frame, ego_T_sensor)
                if modality == "camera" and cs_token in first_time:
                    size = next(r for r in data_rows if r.calibrated_sensor_token == cs_token)
                    scene.add_camera_calibration(
                        frame,
                        first_time[cs_token],
                        np.asarray(calibration["camera_intrinsic"], dtype=np.float64),
                        size.width,
                        size.height,
                        D=np.zeros(0),
                    )
            self._write_poses(scene, data_rows)
            for row in data_rows:
                frame, modality, _ = channels[row.calibrated_sensor_token]
                self._write_sensor_data(scene, row, frame, modality)
            key_times: dict[str, dict[str, int]] = defaultdict(dict)
            for row in data_rows:
                if row.is_key_frame:
                    key_times[row.sample_token][channels[row.calibrated_sensor_token][0]] = row.timestamp_ns
            labels = self._labels(samples, sample_index)
            for i, sample_row in enumerate(samples):
                scene.add_frame(
                    i,
                    int(tables.sample_ns[sample_row]),
                    labels[i],
                    sensor_timestamps_ns=dict(sorted(key_times[tables.sample_tokens[sample_row]].items())),
                    annotated=True,
                )

    def _samples(self) -> list[int]:
        """The scene's sample rows (indexes into the sample columns) in time order."""
        rows = np.flatnonzero(self.tables.sample_scene == self.tables.scene_tokens.index(self.scene_token))
        if not len(rows):
            raise InputError(f"scene {self.name} ({self.scene_token}): expected samples, got none in sample.json")
        return rows[np.argsort(self.tables.sample_ns[rows], kind="stable")].tolist()

    def _valid_sample_data(self) -> list[SampleDataRow]:
        """The scene's sample_data in time order, without rows whose sensor dangles."""
        rows = []
        for row in self.tables.sample_data_rows(self.scene_token):
            calibration = self.tables.calibrated_sensor[row.calibrated_sensor_token]
            if calibration["sensor_token"] not in self.tables.sensor:
                self.report.error(
                    "calibrated_sensor.json",
                    f"calibrated_sensor {row.calibrated_sensor_token}: dangling sensor_token {calibration['sensor_token']}",
                )
                continue
            rows.append(row)
        rows.sort(key=lambda r: (r.timestamp_ns, r.token))
        return rows

    def _sensors(self, rows: list[SampleDataRow]) -> dict[str, tuple[str, str, str]]:
        """calibrated_sensor token -> (sensor frame, modality, channel); one calibration per channel."""
        channels: dict[str, tuple[str, str, str]] = {}
        token_of_channel: dict[str, str] = {}
        for row in rows:
            cs_token = row.calibrated_sensor_token
            if cs_token in channels:
                continue
            calibration = self.tables.calibrated_sensor[cs_token]
            sensor = self.tables.sensor[calibration["sensor_token"]]
            channel = sensor["channel"]
            first = token_of_channel.setdefault(channel, cs_token)
            if first != cs_token:
                old = self.tables.calibrated_sensor[first]
                same = all(np.allclose(old[key], calibration[key]) for key in ("rotation", "translation")) and (
                    np.asarray(old.get("camera_intrinsic") or []).tolist()
                    == np.asarray(calibration.get("camera_intrinsic") or []).tolist()
                )
                if not same:
                    self.report.error(
                        "calibrated_sensor.json",
                        f"channel {channel}: calibration changes within the scene "
                        f"({first} then {cs_token}); sample_data of the second is skipped",
                    )
                    continue
            channels[cs_token] = (f"ego/{channel.lower()}", sensor["modality"], channel)
        return channels

    def _write_poses(self, scene: Any, rows: list[SampleDataRow]) -> None:
        """``world -> ego`` at every sample_data time, each pose stamped with its sample_data's time.

        One entry per distinct (time, ego_pose) pair; two different poses at one time keep the first
        (by pose row) and warn.
        """
        if not rows:
            return
        stamped = np.asarray(sorted({(row.timestamp_ns, row.ego_pose_row) for row in rows}), dtype=np.int64)
        times_ns, pose_rows = stamped.reshape(-1, 2).T
        repeated = np.flatnonzero(times_ns[1:] == times_ns[:-1]) + 1
        for k in repeated:
            kept, dropped = self.tables.ego_pose[pose_rows[k - 1]], self.tables.ego_pose[pose_rows[k]]
            if not np.array_equal(kept, dropped):
                self.report.warn("ego_pose.json", f"two different ego poses at {times_ns[k]} ns (row {pose_rows[k]} dropped)")
        keep = np.ones(len(times_ns), dtype=bool)
        keep[repeated] = False
        poses = self.tables.ego_pose[pose_rows[keep]]
        world_T_ego = Transform.from_quat_wxyz(poses[:, :4], poses[:, 4:])
        for j, time_ns in enumerate(times_ns[keep].tolist()):
            scene.add_transform("world", "ego", time_ns, world_T_ego[j])

    def _write_sensor_data(self, scene: Any, row: SampleDataRow, frame: str, modality: str) -> None:
        path = self.dataroot / row.filename
        if not path.is_file():
            self.report.warn(row.filename, f"sensor file missing (sample_data {row.token})")
            return
        data = path.read_bytes()
        try:
            if modality == "camera":
                scene.add_image(frame, row.timestamp_ns, data, "jpeg")
            elif modality == "radar" or row.filename.endswith(".pcd"):
                scene.add_point_cloud(frame, row.timestamp_ns, read_pcd(data, row.filename))
            else:
                scene.add_point_cloud(frame, row.timestamp_ns, read_lidar_bin(data, row.filename))
        except InputError as error:
            self.report.warn(row.filename, f"unreadable sensor file (sample_data {row.token}): {error}")

    def _labels(self, samples: list[int], sample_index: dict[str, int]) -> list[ObjectLabels]:
        """Each sample's objects in ``world``, velocities as the devkit's ``box_velocity`` computes them.

        Args:
            samples: the scene's sample rows in time order.
            sample_index: sample token -> frame index.
        """
        tables, report = self.tables, self.report
        self.sample_us = {tables.sample_tokens[row]: float(tables.sample_us[row]) for row in samples}
        annotations = tables.annotation_rows(self.scene_token)
        by_token = {a.token: a for a in annotations}
        per_sample: list[list[AnnotationRow]] = [[] for _ in samples]
        dangling_links: list[str] = []
        for a in annotations:
            instance = tables.instance[a.instance_token]
            if instance["category_token"] not in tables.category:
                report.error(
                    "instance.json",
                    f"instance {a.instance_token}: dangling category_token {instance['category_token']}",
                )
                continue
            dangling_links.extend(t for t in (a.prev, a.next) if t and t not in by_token)
            per_sample[sample_index[a.sample_token]].append(a)
        if dangling_links:
            report.warn(
                "sample_annotation.json",
                f"{len(dangling_links)} prev/next links point outside the "
                f"tables (e.g. {dangling_links[0]}); velocities use the neighbours present",
            )
        return [self._objects(rows, by_token) for rows in per_sample]

    def _objects(self, rows: list[AnnotationRow], by_token: dict[str, AnnotationRow]) -> ObjectLabels:
        tables = self.tables
        if not rows:
            return ObjectLabels.empty("world")
        categories = [tables.category[tables.instance[a.instance_token]["category_token"]]["name"] for a in rows]
        boxes = Boxes3D.from_nuscenes(
            np.asarray([a.translation for a in rows], dtype=np.float64),
            np.asarray([a.size_wlh for a in rows], dtype=np.float64),
            np.asarray([a.rotation_wxyz for a in rows], dtype=np.float64),
            "world",
            ids=np.asarray([a.instance_token for a in rows]),
            classes=np.asarray([unified_class(c) for c in categories]),
            velocity=np.asarray([self._velocity(a, by_token) for a in rows], dtype=np.float64),
        )
        attributes = []
        extras = []
        for a in rows:
            attrs = {tables.attribute[t]["name"]: "true" for t in a.attribute_tokens}
            attrs["annotation_token"] = a.token
            if a.visibility_token:
                attrs["visibility_token"] = a.visibility_token
                attrs["visibility"] = tables.visibility[a.visibility_token]["level"]
            attributes.append(attrs)
            extras.append({"num_lidar_pts": float(a.num_lidar_pts), "num_radar_pts": float(a.num_radar_pts)})
        return ObjectLabels(boxes=boxes, source_classes=np.asarray(categories), attributes=attributes, extras=extras)

    def _velocity(self, current: AnnotationRow, by_token: dict[str, AnnotationRow]) -> tuple[float, float, float]:
        """The devkit's ``NuScenes.box_velocity(token)``, operation for operation (NaN when unknown)."""
        prev = by_token.get(current.prev) if current.prev else None
        nxt = by_token.get(current.next) if current.next else None
        if prev is None and nxt is None:
            return (math.nan, math.nan, math.nan)
        first = prev if prev is not None else current
        last = nxt if nxt is not None else current
        pos_diff = np.asarray(last.translation) - np.asarray(first.translation)
        time_last = 1e-6 * self.sample_us[last.sample_token]
        time_first = 1e-6 * self.sample_us[first.sample_token]
        time_diff = time_last - time_first
        max_time_diff = MAX_VELOCITY_TIME_DIFF_S * (2 if prev is not None and nxt is not None else 1)
        if time_diff > max_time_diff:
            return (math.nan, math.nan, math.nan)
        velocity = pos_diff / time_diff
        return (float(velocity[0]), float(velocity[1]), float(velocity[2]))
