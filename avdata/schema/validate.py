"""Checks a unified dataset: frames resolvable, times monotonic, finite geometry, index consistent.

Messages are read with the stock ``mcap`` reader and ``mcap-protobuf-support`` decoder in file
order, so validation also proves the files decode without avdata's own reader.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from avdata.errors import AvdataError
from avdata.schema import topics
from avdata.schema.dataset import MANIFEST, DatasetReader, is_complete_scene
from avdata.schema.index import INDEX_TABLES, scene_index
from avdata.schema.scene_reader import SceneReader

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
        return f"{self.scene}: {self.topic} @ {at} ns: {self.message}"


def validate_dataset(root: str | Path) -> list[ValidationProblem]:
    """Every problem found in dataset ``root`` (empty when clean)."""
    dataset = DatasetReader(root)
    problems: list[ValidationProblem] = []
    listed = set(dataset.scenes)
    on_disk = {p.stem for p in (dataset.root / "scenes").glob("*.mcap")}
    for name in sorted(on_disk - listed):
        problems.append(ValidationProblem(scene=name, topic="-", time_ns=None,
                                          message=f"scene file not listed in {MANIFEST}; run 'avdata index'"))
    indexed = {name: pq.read_table(dataset.root / "index" / f"{name}.parquet") for name in INDEX_TABLES
               if (dataset.root / "index" / f"{name}.parquet").is_file()}
    for name in INDEX_TABLES:
        if name not in indexed:
            problems.append(ValidationProblem(scene="-", topic=f"index/{name}.parquet", time_ns=None,
                                              message="index table missing; run 'avdata index'"))
    for name in dataset.scenes:
        path = dataset.root / "scenes" / f"{name}.mcap"
        if not is_complete_scene(path):
            problems.append(ValidationProblem(scene=name, topic="-", time_ns=None,
                                              message=f"scene file {path} missing or incomplete"))
            continue
        try:
            scene = SceneReader(path)
        except AvdataError as error:
            problems.append(ValidationProblem(scene=name, topic="-", time_ns=None, message=str(error)))
            continue
        problems.extend(_validate_messages(scene))
        problems.extend(_validate_index(scene, indexed))
        scene.close()
    return problems


def _validate_messages(scene: SceneReader) -> list[ValidationProblem]:
    problems: list[ValidationProblem] = []
    graph = scene.graph
    last_time: dict[str, int] = {}

    def problem(topic: str, time_ns: int | None, message: str) -> None:
        problems.append(ValidationProblem(scene=scene.name, topic=topic, time_ns=time_ns, message=message))

    def check_frame(topic: str, frame_id: str, time_ns: int) -> None:
        try:
            graph.lookup("world", frame_id, time_ns)
        except AvdataError as error:
            problem(topic, time_ns, f"frame {frame_id!r} not resolvable to 'world': {error}")

    try:
        with open(scene.path, "rb") as stream:
            reader = make_reader(stream, decoder_factories=[DecoderFactory()])
            for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
                topic, t = channel.topic, message.log_time
                if t < last_time.get(topic, t):
                    problem(topic, t, f"time goes backwards (previous message at {last_time[topic]} ns)")
                last_time[topic] = max(t, last_time.get(topic, t))
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
                    if not np.all(np.isfinite(geometry)):
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
                    check_frame(topic, decoded.frame_id, t)
                elif hasattr(decoded, "sensor_frame"):
                    check_frame(topic, decoded.sensor_frame, t)
    except (McapError, OSError, ValueError) as error:
        problem("-", None, f"cannot decode with the stock mcap reader: {error}")
    return problems


def _validate_index(scene: SceneReader, indexed: dict) -> list[ValidationProblem]:
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


def _same(a: list, b: list) -> bool:
    for x, y in zip(a, b):
        if isinstance(x, float) and isinstance(y, float):
            if not (x == y or (math.isnan(x) and math.isnan(y)) or abs(x - y) <= 1e-9 * max(1.0, abs(x))):
                return False
        elif x != y:
            return False
    return True
