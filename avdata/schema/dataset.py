"""A unified dataset on disk: manifest, one MCAP per scene, and the derived Parquet index.

::

    DATASET/
      avdata.json              manifest: format version, source, licence, scenes, sensors, classes
      scenes/<scene>.mcap      one self-contained MCAP per scene
      index/*.parquet          derived from the MCAP files; rebuilt by ``avdata index DATASET``

:class:`DatasetReader` also reads a dataset in an object store (``s3://bucket/prefix``, ``gs://...``, through
:mod:`avdata.storage`): the manifest and index tables whole, each scene by ranged requests
(:class:`~avdata.schema.mcap.fileio.RangedFile`).
"""

from __future__ import annotations

import contextlib
import functools
import os
import secrets
import tempfile
import zlib
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Any, BinaryIO, Protocol

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from avdata import __version__
from avdata.errors import AvdataError, InputError, one_line
from avdata.frames import FrameGraph
from avdata.inputs import require_file
from avdata.outputs import write_atomically
from avdata.schema import topics
from avdata.schema.index import INDEX_TABLES, SCHEMAS, IndexWriter, index_tables, scene_index, written_scene_labels
from avdata.schema.manifest import (
    MANIFEST,
    dataset_size_bytes,
    manifest_text,
    open_manifest,
    read_manifest,
    scene_file,
    scene_path,
)
from avdata.schema.mcap.fileio import RangedFile, WrittenBytes
from avdata.schema.scene_reader import SceneReader
from avdata.schema.scene_writer import SceneWriter, WrittenScene
from avdata.storage import Location, path_or_location


def is_complete_scene(path: Path) -> bool:
    """Whether ``path`` is a finished MCAP file (both magics present; its summary is checked on read)."""
    if not path.is_file() or path.stat().st_size < 16:
        return False
    with open(path, "rb") as stream:
        head = stream.read(8)
        stream.seek(-8, os.SEEK_END)
        tail = stream.read(8)
    return head == tail == b"\x89MCAP0\r\n"


#: In a worker process, each parent dataset writer's tally of the bytes written into it (its copies
#: arrive one per scene task; one small entry per parent writer).
_WORKER_WRITTEN_BYTES: dict[str, WrittenBytes] = {}


class DatasetWriter:
    """Writes a unified dataset; finalises the manifest and index when its ``with`` block ends.

    Holds no open resources between scenes, so it can be pickled into worker processes that each
    write their own scenes; only the parent's ``__exit__`` (or :meth:`finalize`) builds the index.
    The index rows of scenes written in the parent itself come from what it wrote (see
    :class:`~avdata.schema.scene_writer.WrittenScene`); other scenes' files are read.

    Args:
        root: the dataset folder (created if missing).
        source: source dataset name, e.g. "kitti-object", "nuscenes", "avdata-generator".
        source_version: the source's version string, e.g. "v1.0-mini".
        licence: the source data's licence.
        compression: MCAP chunk compression, "none" | "zstd" | "lz4".
        description: free text for the manifest.
        scene_files: where the finished scene files are when not under ``root/scenes`` (a dataset in an object
            store, built in a local staging folder).
    """

    def __init__(
        self,
        root: str | Path,
        *,
        source: str,
        source_version: str = "",
        licence: str = "",
        compression: str = "none",
        description: str = "",
        scene_files: SceneFiles | None = None,
    ):
        self.root = Path(root)
        #: where the finished scene files are when not under ``root/scenes`` (see :func:`build_index`)
        self.scene_files = scene_files
        self.source = source
        self.source_version = source_version
        self.licence = licence
        self.compression = compression
        self.description = description
        manifest = self.root / MANIFEST
        if manifest.is_file():
            topics.check_version(read_manifest(manifest).get("format_version", "0"), str(manifest))
        self._fresh: _WrittenIndex | None = _WrittenIndex()
        # Bytes this process wrote into the dataset: past a tenth of memory its files leave the page
        # cache as they are written back (a large conversion writes more than memory holds). Copies
        # in a worker process (one per scene task) add to that process's tally of this writer.
        self._writes_id = secrets.token_hex(8)
        self._written_bytes = WrittenBytes()

    def __getstate__(self) -> dict[str, Any]:
        # A copy in a worker process keeps no index rows: only the parent builds the index.
        return {**self.__dict__, "_fresh": None, "_written_bytes": None}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._written_bytes = _WORKER_WRITTEN_BYTES.setdefault(self._writes_id, WrittenBytes())

    def share_written_index(self, parent: DatasetWriter) -> None:
        """Hands this writer's index rows to ``parent`` (its :meth:`finalize` uses them), and its bytes to its tally."""
        self._fresh = parent._fresh
        self._writes_id, self._written_bytes = parent._writes_id, parent._written_bytes

    def __enter__(self) -> DatasetWriter:
        (self.root / "scenes").mkdir(parents=True, exist_ok=True)
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if exc_type is None:
            self.finalize()

    def is_complete(self, name: str) -> bool:
        """Whether scene ``name`` was already written completely (a rerun skips it)."""
        return is_complete_scene(scene_path(self.root, name))

    def scene(self, name: str, metadata: Mapping[str, Any] | None = None) -> SceneWriter:
        """A writer for scene ``name``; use it as a context manager."""
        meta = {"source": self.source, "source_version": self.source_version, **dict(metadata or {})}
        return SceneWriter(scene_path(self.root, name), name, meta, compression=self.compression,
                           on_written=None if self._fresh is None else self._fresh.add, require_frames=True,
                           written=self._written_bytes)

    def finalize(self) -> None:
        """Builds the Parquet index and the manifest from every complete scene file."""
        build_index(self.root, manifest_fields={
            "source": {"name": self.source, "version": self.source_version},
            "licence": self.licence,
            "description": self.description,
        }, written=None if self._fresh is None else self._fresh.parts, scenes=self.scene_files)
        if self._fresh is not None:
            self._fresh.clear()


#: What :func:`build_index` gets of a scene this process wrote: its stat when written, metadata, and
#: a loader of its index tables.
WrittenPart = tuple[tuple[int, int, int], dict[str, Any], Callable[[], dict[str, pa.Table]]]


class _WrittenIndex:
    """The index tables of scenes written by this process, kept on disk until :func:`build_index` uses them.

    Kept in memory they would grow with the dataset, and so would a conversion's peak memory. Each scene's tables
    are appended as an Arrow IPC stream to one unnamed temporary file in the dataset folder (no name, so nothing
    is left behind when the process dies), and read back one scene at a time: writing and reading IPC is a copy
    each way.
    """

    def __init__(self) -> None:
        #: scene file -> (its stat when written, metadata, loader of its index tables)
        self.parts: dict[Path, WrittenPart] = {}
        self._spill: BinaryIO | None = None

    def add(self, written: WrittenScene) -> None:
        """Keeps the index rows of a scene just written, unless the reader would object."""
        try:
            part = index_tables(written_scene_labels(written), split=str(written.metadata.get("split", "")))
        except (AvdataError, ValueError, TypeError, KeyError):
            return  # build_index reads the file, and reports the problem as it always has
        if self._spill is None:
            self._spill = tempfile.TemporaryFile(dir=written.path.parent)
        sink = pa.BufferOutputStream()
        for name in INDEX_TABLES:
            with pa.ipc.new_stream(sink, part[name].schema) as stream:
                stream.write_table(part[name])
        data = sink.getvalue()
        offset = self._spill.seek(0, os.SEEK_END)
        self._spill.write(data)
        self.parts[written.path] = (_stat_key(written.path), written.metadata,
                                    functools.partial(_read_spilled, self._spill, offset, data.size))

    def clear(self) -> None:
        """Forgets every scene (after the index was built)."""
        self.parts.clear()
        if self._spill is not None:
            self._spill.close()
            self._spill = None


def _read_spilled(spill: BinaryIO, offset: int, size: int) -> dict[str, pa.Table]:
    """The index tables :meth:`_WrittenIndex.add` appended to ``spill`` at ``offset`` (``size`` bytes)."""
    spill.flush()
    reader = pa.BufferReader(pa.py_buffer(os.pread(spill.fileno(), size, offset)))
    options = pa.ipc.IpcReadOptions(use_threads=False)  # Python-owned bytes: see read_index_table
    return {name: pa.ipc.open_stream(reader, options=options).read_all() for name in INDEX_TABLES}


class SceneFiles(Protocol):
    """Scene files that are not all in the dataset folder (a dataset in an object store): listed, fetched one by one."""

    def names(self) -> list[str]:
        """The names of the complete scenes."""

    def fetched(self, name: str) -> AbstractContextManager[Path]:
        """Holds scene ``name``'s file at a local path for the ``with`` block."""


def build_index(root: Path, manifest_fields: Mapping[str, Any] | None = None, progress: bool = False,
                written: Mapping[Path, WrittenPart] | None = None, scenes: SceneFiles | None = None) -> None:
    """(Re)builds ``index/`` and the manifest of dataset ``root`` from its scene files.

    Args:
        root: the dataset folder.
        manifest_fields: source, licence and description; when None the existing manifest's are kept.
        progress: show a tqdm bar.
        written: scene file -> (its stat when written, metadata, loader of its index tables) of scenes
            this process wrote; used instead of reading a file that is still the one written (same
            inode, size and modification time).
        scenes: where the scene files are when not under ``root/scenes`` (fetched one at a time).
    """
    root = Path(root)
    scenes_dir = root / "scenes"
    if not scenes_dir.is_dir():
        raise InputError(f"{root}: not an avdata dataset (no scenes/ folder)")
    if manifest_fields is None:
        manifest_path = root / MANIFEST
        if not manifest_path.is_file():
            raise InputError(f"{manifest_path}: manifest missing; cannot tell the source of this dataset")
        old = read_manifest(manifest_path)
        topics.check_version(old.get("format_version", "0"), str(manifest_path))
        manifest_fields = {key: old.get(key) for key in ("source", "licence", "description")}
    if scenes is None:
        paths = sorted(p for p in scenes_dir.glob("*.mcap") if is_complete_scene(p))
        fetched: Callable[[Path], AbstractContextManager[Path]] = contextlib.nullcontext
    else:  # sorted as the paths are: by file name
        paths = sorted(scenes_dir / f"{name}.mcap" for name in scenes.names())
        fetched = functools.partial(_fetched_scene, scenes)
    scenes_meta = []
    sensors: dict[str, dict[str, Any]] = {}
    classes: Counter[str] = Counter()
    from tqdm import tqdm

    with IndexWriter(root / "index") as index:
        for listed in tqdm(paths, desc="index", unit="scene", disable=not progress):
            fresh = (written or {}).get(listed)
            if fresh is not None and fresh[0] == _stat_key(listed):
                _, metadata, load = fresh
                part = load()
            else:
                with fetched(listed) as path:
                    scene = SceneReader(path)
                    metadata = scene.metadata
                    part = scene_index(scene, split=str(metadata.get("split", "")))
                    scene.close()
            index.add(part)
            frame_times = part["frames"].column("timestamp_ns").to_pylist()  # to_numpy() would import pandas
            scenes_meta.append(
                {
                    "name": metadata["name"],
                    "file": str(listed.relative_to(root)),
                    "frames": len(frame_times),
                    "start_ns": min(frame_times) if frame_times else None,
                    "end_ns": max(frame_times) if frame_times else None,
                    "split": metadata.get("split", ""),
                }
            )
            sensors.update(dict(metadata.get("sensors", {})))
            classes.update(part["objects"].column("class").to_pylist())
    manifest = {
        "format": "avdata",
        "format_version": topics.FORMAT_VERSION,
        "written_by": f"avdata {__version__}",
        **dict(manifest_fields),
        "scenes": scenes_meta,
        "sensors": sensors,
        "classes": dict(sorted(classes.items())),
        "index": {name: index_checksum(root / "index" / f"{name}.parquet") for name in INDEX_TABLES},
    }
    write_atomically(root / MANIFEST, manifest_text(manifest))


def _fetched_scene(scenes: SceneFiles, path: Path) -> AbstractContextManager[Path]:
    return scenes.fetched(path.stem)


def _stat_key(path: Path) -> tuple[int, int, int]:
    stat = path.stat()
    return stat.st_ino, stat.st_size, stat.st_mtime_ns


def dataset_root(root: str | Path | Location) -> Path | Location:
    """A dataset folder as a ``Path`` when local, as a :class:`~avdata.storage.Location` in an object store."""
    if isinstance(root, Location):
        return root if not root.is_local else Path(root.path)
    return path_or_location(root)


def open_scene(root: Path | Location, name: str, *, verify: bool = False,
               cache_dir: str | Path | None = None) -> SceneReader:
    """The reader of scene ``name`` of the dataset at ``root``: mapped when local, by ranged requests in a store.

    Args:
        root: the dataset folder (:func:`dataset_root`).
        name: the scene name.
        verify: check each chunk's CRC-32 when first read.
        cache_dir: for a store, the local folder keeping fetched ranges (None: ``$AVDATA_CACHE_DIR``, if set).

    Raises:
        InputError: the scene file is missing or damaged.
    """
    if isinstance(root, Path):
        return SceneReader(scene_file(root, name), verify=verify)
    where = scene_path(root, name)
    return SceneReader(RangedFile(where.fs, where.path, where.uri, cache_dir=cache_dir), verify=verify)


class DatasetReader:
    """Reads a unified dataset: index tables, scenes, frame graphs, and sensor data by frame.

    Args:
        root: the dataset folder, or its prefix in an object store (``s3://bucket/prefix``, ``gs://...``):
            then the manifest and index tables are read whole, and each scene by ranged requests (its
            summary first, then each chunk a message needs).
        verify: check each MCAP chunk's CRC-32 the first time a message in it is read (off by
            default: it is most of a cloud read's cost, see docs/format.md; ``avdata validate``
            checks every byte). The manifest's own CRC-32 and each index table's size and CRC-32
            are always checked, when opening and when the table is loaded: they cost little.
        cache_dir: for a dataset in a store, a local folder keeping the scene bytes fetched, so a later
            reader fetches them no more (None: ``$AVDATA_CACHE_DIR`` if set, else no cache).

    Raises:
        InputError: the folder or its manifest is missing, unreadable or damaged.
        FormatVersionError: the dataset is of a newer major format version.
    """

    def __init__(self, root: str | Path | Location, *, verify: bool = False, cache_dir: str | Path | None = None):
        self.root = dataset_root(root)
        self.verify = verify
        self.cache_dir = cache_dir
        self.manifest: dict[str, Any] = open_manifest(self.root)
        self.scenes: list[str] = [s["name"] for s in self.manifest["scenes"]]
        self._scene_readers: dict[str, SceneReader] = {}
        self._tables: dict[str, pa.Table] = {}
        self._sensor_times: dict[tuple[str, int], dict[str, int]] | None = None

    @property
    def local_root(self) -> Path:
        """The dataset folder, for what reads local datasets only.

        Raises:
            InputError: the dataset is in an object store.
        """
        if not isinstance(self.root, Path):
            raise InputError(f"{self.root}: expected a local dataset folder here, got an object store URI "
                             "(copy the dataset to a local folder first)")
        return self.root

    def scene(self, name: str) -> SceneReader:
        """The reader of scene ``name`` (opened once, then reused)."""
        reader = self._scene_readers.get(name)
        if reader is None:
            if name not in self.scenes:
                raise AvdataError(f"{self.root}: no scene {name!r}; scenes: {', '.join(self.scenes[:10])}")
            reader = open_scene(self.root, name, verify=self.verify, cache_dir=self.cache_dir)
            self._scene_readers[name] = reader
        return reader

    def table(self, name: str) -> pa.Table:
        """Index table ``name`` ("frames" | "objects" | "visibility") as Arrow."""
        if name not in INDEX_TABLES:
            raise AvdataError(f"expected an index table of {INDEX_TABLES}, got {name!r}")
        if name not in self._tables:
            path = self.root / "index" / f"{name}.parquet"
            missing = f"index table missing; rebuild it with 'avdata index {self.root}'"
            if isinstance(path, Path):
                require_file(path, "index table file", missing=missing)
            elif not path.is_file():
                raise InputError(f"{path}: {missing}")
            # Read whole, once (in a store too: one request), and checked against the manifest's size and
            # CRC-32 before it is parsed: a damaged table would otherwise feed wrong boxes to whoever reads it.
            data = read_index_bytes(path)
            check_index_checksum(path, name, self.manifest, data)
            self._tables[name] = read_index_table(path, name, data)
        return self._tables[name]

    def frames(self) -> pa.Table:
        """One row per (scene, frame)."""
        return self.table("frames")

    def objects(self) -> pa.Table:
        """One row per (scene, frame, object)."""
        return self.table("objects")

    def visibility(self) -> pa.Table:
        """One row per (scene, frame, sensor, object)."""
        return self.table("visibility")

    def frame_graph(self, scene: str) -> FrameGraph:
        """The frame tree of ``scene``."""
        return self.scene(scene).graph

    def sensor_time(self, scene: str, frame_index: int, sensor: str) -> int:
        """The time of ``sensor``'s message that belongs to frame ``frame_index`` of ``scene``."""
        if self._sensor_times is None:
            frames = self.frames()
            self._sensor_times = {
                (s, int(i)): dict(times)
                for s, i, times in zip(
                    frames.column("scene").to_pylist(),
                    frames.column("frame_index").to_pylist(),
                    frames.column("sensor_timestamps_ns").to_pylist(), strict=True,
                )
            }
        times = self._sensor_times.get((scene, int(frame_index)))
        if times is None:
            raise AvdataError(f"{self.root}: no frame {frame_index} in scene {scene!r}")
        if sensor not in times:
            raise AvdataError(f"scene {scene!r} frame {frame_index}: no message of sensor {sensor!r}; has {sorted(times)}")
        return times[sensor]

    def points(self, scene: str, frame_index: int, sensor: str) -> np.ndarray:
        """The point cloud (structured array, sensor frame) of ``sensor`` in a frame."""
        return self.scene(scene).points(sensor, self.sensor_time(scene, frame_index, sensor))

    def image(self, scene: str, frame_index: int, sensor: str) -> tuple[bytes, str]:
        """(encoded bytes, format) of ``sensor``'s image in a frame."""
        return self.scene(scene).image(sensor, self.sensor_time(scene, frame_index, sensor))

    def iter_frames(self) -> Iterable[tuple[str, int, int]]:
        """(scene, frame_index, timestamp_ns) of every frame in index order."""
        frames = self.frames()
        return zip(
            frames.column("scene").to_pylist(),
            frames.column("frame_index").to_pylist(),
            frames.column("timestamp_ns").to_pylist(), strict=True,
        )

    def size_bytes(self) -> int:
        """Total size on disk of the dataset folder."""
        return dataset_size_bytes(self.root)


def read_index_bytes(path: Path | Location) -> bytes:
    """The bytes of an index table file, read once for its checksum and its parsing.

    Raises:
        InputError: the file cannot be read.
    """
    try:
        return path.read_bytes()
    except OSError as error:
        raise InputError(f"{path}: unreadable index table ({one_line(error)})") from error


def index_checksum(path: Path | Location, data: bytes | None = None) -> dict[str, int]:
    """Size and CRC-32 of an index table file (of its bytes ``data`` when already read), as the manifest records them."""
    if data is None:
        data = path.read_bytes()
    return {"bytes": len(data), "crc32": zlib.crc32(data)}


def check_index_checksum(path: Path | Location, name: str, manifest: Mapping[str, Any],
                         data: bytes | None = None) -> None:
    """Compares index table ``name`` at ``path`` (its bytes ``data`` when already read) with the size and CRC-32 in the manifest.

    Raises:
        InputError: the manifest has no checksum for the table, or the file differs from it.
    """
    expected = (manifest.get("index") or {}).get(name)
    if not isinstance(expected, dict):
        raise InputError(f"{path}: the manifest records no checksum for this index table; run 'avdata index'")
    actual = index_checksum(path, data)
    if actual != expected:
        raise InputError(f"{path}: expected {expected.get('bytes')} bytes with CRC-32 {expected.get('crc32')} "
                         f"(from {MANIFEST}), got {actual['bytes']} bytes with CRC-32 {actual['crc32']}")


def read_index_table(path: Path | Location, name: str, data: bytes | None = None) -> pa.Table:
    """Index table ``name`` from ``path`` (from its bytes ``data`` when already read), checked against its schema.

    Raises:
        InputError: the file is unreadable, damaged, or its columns differ from the schema.
    """
    try:
        # ParquetFile, not read_table: read_table goes through pyarrow.dataset, which imports pandas (0.3 s of
        # every `avdata info`).
        # Not on Arrow's thread pool: a pool worker that drops the last reference to the Python bytes ``data``
        # after the read returned takes the GIL, which at interpreter exit aborts the process (docs/decisions.md).
        with pq.ParquetFile(pa.BufferReader(data) if data is not None else path) as parquet:
            table = parquet.read(use_threads=False)
        # Full validation decodes every value once (UTF-8 of strings, offsets, map keys), so damage
        # surfaces here, naming the file, and not later inside whoever reads a column.
        table.validate(full=True)
    except (OSError, pa.ArrowException, ValueError, TypeError, MemoryError) as error:
        raise InputError(f"{path}: unreadable index table ({type(error).__name__}: {one_line(error)[:200]})") from error
    expected = SCHEMAS[name]
    for field in expected:
        index = table.schema.get_field_index(field.name)
        if index < 0:
            raise InputError(f"{path}: expected column {field.name!r} of type {field.type}, got no such column; "
                             f"rebuild the index with 'avdata index'")
        if not table.schema.field(index).type.equals(field.type):
            raise InputError(f"{path}: column {field.name!r}: expected type {field.type}, got "
                             f"{table.schema.field(index).type}")
    return table
