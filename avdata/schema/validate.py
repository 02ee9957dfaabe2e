"""Checks a unified dataset: every byte's checksum, every message decoded, frames, times, index.

For each scene file: the summary CRC, the data-section CRC and every chunk's CRC (which together
cover every byte), then every message is decoded with the protobuf schema embedded in the file
(through ``mcap-protobuf-support``, so the file also decodes without avdata's own classes), then
the contents are checked (monotonic times, unit quaternions, finite boxes, frames resolvable) and
the scene's rows of the Parquet index are compared with what the MCAP file gives.

A dataset in an object store (``s3://``, ``gs://``) is checked the same way over the network: the manifest and
index tables are fetched into a temporary folder, then each scene object in turn (every byte must be read to
check every CRC), checked and deleted, so the local disk holds one scene at a time; messages name the URI.
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from mcap.records import Schema
from mcap_protobuf.decoder import DecoderFactory

from avdata.errors import AvdataError, InputError, one_line
from avdata.schema import topics
from avdata.schema.dataset import check_index_checksum, read_index_bytes, read_index_table
from avdata.schema.index import INDEX_TABLES, scene_index
from avdata.schema.manifest import MANIFEST, check_manifest_checksum, open_manifest
from avdata.schema.mcap.reader import McapReader
from avdata.schema.scene_reader import SceneReader, point_dtype
from avdata.storage import Location, is_remote, location

_QUAT_TOLERANCE = 1e-6


@dataclass(frozen=True, slots=True, kw_only=True)
class ValidationProblem:
    """One problem: the scene, topic and time it is at, and what is wrong."""

    scene: str
    topic: str
    time_ns: int | None
    message: str

    def __str__(self) -> str:
        at = "-" if self.time_ns is None else f"{self.time_ns}"
        return f"{self.scene}: {self.topic} @ {at} ns: {one_line(self.message)}"


def validate_dataset(root: str | Path) -> list[ValidationProblem]:
    """Every problem found in dataset ``root`` (a folder, or a URI in an object store; empty when clean).

    Raises:
        InputError: the folder or its manifest is missing or unreadable (nothing else to check).
    """
    if is_remote(str(root)):
        return _validate_store(location(str(root)))
    scenes = Path(root) / "scenes"
    # isdir first: glob passes over a missing folder but raises for a name too long (a traceback)
    on_disk = {p.stem for p in scenes.glob("*.mcap")} if os.path.isdir(scenes) else set()
    return _validate(Path(root), on_disk, lambda _scene: contextlib.nullcontext())


def _validate_store(root: Location) -> list[ValidationProblem]:
    """:func:`validate_dataset` of a dataset in an object store (see the module docstring)."""
    from avdata.storage import FILE

    with tempfile.TemporaryDirectory(prefix="avdata-validate-") as folder:
        local = Path(folder)
        (local / "scenes").mkdir()
        if not (root / MANIFEST).is_file():
            raise InputError(f"{root / MANIFEST}: manifest missing (not an avdata dataset, or conversion unfinished)")
        for name in [MANIFEST, *(f"index/{table}.parquet" for table in INDEX_TABLES)]:
            if (root / name).is_file():
                (root / name).download(local / name)
        on_store = {name[:-len(".mcap")] for name, info in (root / "scenes").listing().items()
                    if info.kind == FILE and name.endswith(".mcap") and not name.startswith(".")}

        @contextlib.contextmanager
        def fetched(name: str) -> Iterator[None]:
            path = local / "scenes" / f"{name}.mcap"
            if name in on_store:
                (root / "scenes" / f"{name}.mcap").download(path)
            try:
                yield
            finally:
                path.unlink(missing_ok=True)

        problems = _validate(local, on_store, fetched)
    prefix = str(local)
    return [replace(p, message=p.message.replace(prefix, root.uri)) for p in problems]


def _validate(root: Path, on_disk: set[str], fetched: Callable[[str], AbstractContextManager[None]]) -> list[ValidationProblem]:
    """:func:`validate_dataset` of the folder ``root``; ``fetched(scene)`` holds its file there while it is checked."""
    # Read unchecked: a damaged manifest is one problem here, reported with the rest.
    manifest = open_manifest(root, checksum=False)
    scenes = [scene["name"] for scene in manifest["scenes"]]
    problems: list[ValidationProblem] = []
    try:
        check_manifest_checksum(root / MANIFEST, manifest)
    except InputError as error:
        problems.append(ValidationProblem(scene="-", topic=MANIFEST, time_ns=None, message=str(error)))
    listed = set(scenes)
    for name in sorted(on_disk - listed):
        problems.append(ValidationProblem(scene=name, topic="-", time_ns=None,
                                          message=f"scene file not listed in {MANIFEST}; run 'avdata index'"))
    indexed: dict[str, pa.Table] = {}
    checksums: dict[str, ValidationProblem] = {}
    for name in INDEX_TABLES:
        path = root / "index" / f"{name}.parquet"
        topic = f"index/{name}.parquet"
        if not path.is_file():
            problems.append(ValidationProblem(scene="-", topic=topic, time_ns=None,
                                              message="index table missing; run 'avdata index'"))
            continue
        try:
            data = read_index_bytes(path)
        except InputError as error:
            problems.append(ValidationProblem(scene="-", topic=topic, time_ns=None, message=str(error)))
            continue
        try:
            check_index_checksum(path, name, manifest, data)
        except InputError as error:
            checksums[topic] = ValidationProblem(scene="-", topic=topic, time_ns=None, message=str(error))
        try:
            indexed[name] = read_index_table(path, name, data)
        except InputError as error:
            problems.append(ValidationProblem(scene="-", topic=topic, time_ns=None, message=str(error)))
            checksums.pop(topic, None)
    for name in scenes:
        with fetched(name):
            problems.extend(_validate_scene(name, root / "scenes" / f"{name}.mcap", indexed))
    # A table whose content differs from the MCAP files is reported by what differs; one whose
    # bytes changed without changing content (statistics, metadata, padding) by its checksum.
    reported = {problem.topic for problem in problems}
    problems.extend(problem for topic, problem in checksums.items() if topic not in reported)
    return problems


def _validate_scene(name: str, path: Path, indexed: dict[str, pa.Table]) -> list[ValidationProblem]:
    def problem(message: str) -> ValidationProblem:
        return ValidationProblem(scene=name, topic="-", time_ns=None, message=message)

    if not path.is_file():
        return [problem(f"scene file {path} missing")]
    try:
        mcap = McapReader(path)
        integrity = mcap.verify_file()
    except InputError as error:
        return [problem(str(error))]
    mcap.close()
    if integrity:
        # Damaged bytes: decoding them would only report the damage again, less precisely.
        return [problem(line) for line in integrity]
    try:
        scene = SceneReader(path)
        if scene.name != name:
            return [problem(f"{path}: scene metadata names the scene {scene.name!r}, the manifest {name!r}")]
        problems = _validate_messages(scene, mcap) + _validate_index(scene, indexed)
        scene.close()
    except AvdataError as error:
        return [problem(str(error))]
    return problems


def _validate_messages(scene: SceneReader, mcap: McapReader) -> list[ValidationProblem]:
    problems: list[ValidationProblem] = []
    graph = scene.graph

    def problem(topic: str, time_ns: int | None, message: str) -> None:
        problems.append(ValidationProblem(scene=scene.name, topic=topic, time_ns=time_ns, message=message))

    def check_frame(topic: str, frame_id: str, time_ns: int) -> None:
        if topic.endswith("/" + topics.CALIBRATION_SUFFIX):
            # Intrinsics hold from their time on and need no pose at that instant (a scene whose first frame
            # lost its pose starts its poses later than its calibrations); the optical frame must be in the tree.
            if frame_id not in graph.frames:
                problem(topic, time_ns, f"frame {frame_id!r} is not in the frame tree")
            return
        try:
            graph.lookup("world", frame_id, time_ns)
        except AvdataError as error:
            problem(topic, time_ns, f"frame {frame_id!r} not resolvable to 'world': {one_line(error)}")

    factory = DecoderFactory()
    for topic in scene.topics:
        channel = mcap.channel_of_topic(topic)
        if channel is None:
            problem(topic, None, "topic without a channel")
            continue
        table = scene.message_table(topic)
        # Time order must be file order within a topic (a streaming reader sees the file order).
        position = table.chunk * (1 << 40) + table.record_offset
        backwards = np.flatnonzero(np.diff(position) < 0)
        if backwards.size:
            problem(topic, int(table.log_time_ns[backwards[0] + 1]), "time goes backwards in file order")
        schema = mcap.schemas[channel.schema_id]
        try:
            decode = factory.decoder_for(channel.message_encoding, Schema(
                id=schema.id, name=schema.name, encoding=schema.encoding, data=schema.data))
        except Exception as error:  # noqa: BLE001 - a bad embedded schema surfaces as any of protobuf's errors
            problem(topic, None, f"embedded schema {schema.name!r} does not load ({type(error).__name__}: "
                          f"{one_line(error)})")
            continue
        if decode is None:
            problem(topic, None, f"no decoder for encoding {channel.message_encoding!r}")
            continue
        for time_ns, raw in scene.messages(topic):
            try:
                decoded = decode(bytes(raw))
            except Exception as error:  # noqa: BLE001 - protobuf's decode errors differ by implementation
                problem(topic, time_ns, f"cannot decode {schema.name} ({type(error).__name__}: {one_line(error)})")
                continue
            _check_message(topic, time_ns, decoded, problem, check_frame)
    return problems


def _check_message(topic: str, t: int, decoded: Any, problem: Any, check_frame: Any) -> None:
    if topic in (topics.TF, topics.TF_STATIC):
        for tf in decoded.transforms:
            q, v = tf.rotation, tf.translation
            values = [q.w, q.x, q.y, q.z, v.x, v.y, v.z]
            if not all(math.isfinite(x) for x in values):
                problem(topic, t, f"non-finite transform {tf.parent_frame_id} -> {tf.child_frame_id}")
            elif abs(math.sqrt(q.w**2 + q.x**2 + q.y**2 + q.z**2) - 1.0) > _QUAT_TOLERANCE:
                problem(topic, t, f"non-unit quaternion {tf.parent_frame_id} -> {tf.child_frame_id}")
    elif topic == topics.OBJECTS:
        n = len(decoded.ids)
        geometry = np.concatenate([np.asarray(decoded.center), np.asarray(decoded.size_lwh),
                                   np.asarray(decoded.quat_wxyz)])
        if len(decoded.center) != 3 * n or len(decoded.size_lwh) != 3 * n or len(decoded.quat_wxyz) != 4 * n:
            problem(topic, t, f"expected 3, 3 and 4 box values per object for {n} objects, got "
                    f"{len(decoded.center)}, {len(decoded.size_lwh)} and {len(decoded.quat_wxyz)}")
        elif not np.all(np.isfinite(geometry)):
            problem(topic, t, "non-finite box centre, size or quaternion")
        elif n and np.any(np.abs(np.linalg.norm(np.asarray(decoded.quat_wxyz).reshape(n, 4), axis=1) - 1)
                          > _QUAT_TOLERANCE):
            problem(topic, t, "non-unit box quaternion")
        if n:
            check_frame(topic, decoded.frame_id, t)
    elif topic == topics.MARKERS:
        for entity in decoded.entities[:1]:
            check_frame(topic, entity.frame_id, t)
    elif hasattr(decoded, "frame_id"):
        if topic.endswith("/" + topics.POINTS_SUFFIX):
            try:
                stride = point_dtype(decoded).itemsize
            except ValueError as error:
                problem(topic, t, f"bad point layout: {error}")
                return
            if len(decoded.data) % stride:
                problem(topic, t, f"{len(decoded.data)} bytes of points is not a multiple of the stride {stride}")
        check_frame(topic, decoded.frame_id, t)
    elif hasattr(decoded, "sensor_frame"):
        check_frame(topic, decoded.sensor_frame, t)


def _validate_index(scene: SceneReader, indexed: dict[str, pa.Table]) -> list[ValidationProblem]:
    problems: list[ValidationProblem] = []
    fresh = scene_index(scene, split=str(scene.metadata.get("split", "")))
    for name, table in indexed.items():
        mask = np.asarray(table.column("scene").to_pylist()) == scene.name
        stored = table.filter(mask)
        expected = fresh[name]
        if stored.num_rows != expected.num_rows:
            problems.append(ValidationProblem(
                scene=scene.name, topic=f"index/{name}.parquet", time_ns=None,
                message=f"expected {expected.num_rows} rows from the MCAP file, index has {stored.num_rows}"))
            continue
        for column in expected.column_names:
            a = expected.column(column).to_pylist()
            b = stored.column(column).to_pylist()
            if not _same(a, b):
                problems.append(ValidationProblem(
                    scene=scene.name, topic=f"index/{name}.parquet", time_ns=None,
                    message=f"column {column!r} differs from what the MCAP file gives; run 'avdata index'"))
                break
    return problems


def _same(a: list[Any], b: list[Any]) -> bool:
    for x, y in zip(a, b, strict=True):
        if isinstance(x, float) and isinstance(y, float):
            if not (x == y or (math.isnan(x) and math.isnan(y)) or abs(x - y) <= 1e-9 * max(1.0, abs(x))):
                return False
        elif x != y:
            return False
    return True
