"""Honest resume: a scene counts as complete only if its recorded fingerprint equals this run's.

The fingerprint (scene metadata key ``resume``) holds what the scene was made from: the task ("kitti-object",
"generate", ...), its options, the major avdata version, a digest of every source file the scene reads,
and the number of errors reported while writing it. A rerun skips a scene only when all of these match
and the error count is 0; anything else (a fixed label, another ``--scene-size``, an upgrade, a scene
written with errors) rewrites it.

Source files are fingerprinted by path relative to the source root plus size, and by content
(SHA-256) when at most :data:`HASH_MAX_BYTES` (labels, calibrations: the files people edit by hand,
where an edit can keep size and a coarse mtime), by mtime in nanoseconds otherwise (sensor data). In an
object store the mtime is the object's last-modified time (a new upload changes it), and one listing per
folder gives every size and time (no request per file).
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from stat import S_ISREG
from typing import Any

from avdata import __version__
from avdata.errors import InputError
from avdata.schema import DatasetWriter, SceneReader, SceneWriter, scene_path
from avdata.storage import FILE, MISSING, Location, ObjectInfo

RESUME_KEY = "resume"
HASH_MAX_BYTES = 1 << 16


def source_digest(paths: Iterable[Path | Location], root: Path | Location) -> tuple[str, int]:
    """(SHA-256 hex digest, number of files) over the given source files.

    Args:
        paths: the files a scene reads; duplicates count once, order does not matter. A path that
            does not exist is recorded as missing (so its later appearance changes the digest).
        root: paths are recorded relative to it (so the digest does not depend on where SRC is mounted).
    """
    if isinstance(root, Location):
        return _store_digest([p for p in paths if isinstance(p, Location)], root)
    root = Path(root)
    prefix = f"{root}/"
    digest = hashlib.sha256()
    # Sorted as Paths sort (by parts); a key of tuples and names sliced from the strings, as
    # ``relative_to`` would give them, cost a third of Path comparisons and ``relative_to`` per file.
    unique = sorted({p if isinstance(p, Path) else Path(p) for p in paths}, key=lambda p: p.parts)
    for path in unique:
        text = str(path)
        if text.startswith(prefix):
            name = text[len(prefix):]
        else:
            try:
                name = str(path.relative_to(root))
            except ValueError:
                name = text
        try:
            stat = os.stat(text)
        except OSError:
            digest.update(f"{name}\0missing\n".encode())
            continue
        if not S_ISREG(stat.st_mode):
            # Never read (a FIFO would wait for a writer forever); the converter reports it as the file it is
            # in, so it costs what that file costs, not the whole scene.
            digest.update(f"{name}\0not a regular file {stat.st_mode:o}\n".encode())
            continue
        if stat.st_size <= HASH_MAX_BYTES:
            try:
                content = hashlib.sha256(path.read_bytes()).hexdigest()
            except OSError as error:
                raise InputError(f"{path}: cannot read the source file ({error.strerror})") from error
            digest.update(f"{name}\0{stat.st_size}\0{content}\n".encode())
        else:
            digest.update(f"{name}\0{stat.st_size}\0{stat.st_mtime_ns}\n".encode())
    return digest.hexdigest(), len(unique)


def _store_digest(paths: list[Location], root: Location) -> tuple[str, int]:
    """:func:`source_digest` of objects in a store: one listing per folder, small objects read whole."""
    prefix = f"{root.uri.rstrip('/')}/"
    unique = sorted({p.uri: p for p in paths}.items(), key=lambda item: tuple(item[0].split("/")))
    listings: dict[str, dict[str, ObjectInfo]] = {}
    digest = hashlib.sha256()
    for uri, path in unique:
        name = uri.removeprefix(prefix)
        folder = path.parent
        if folder.uri not in listings:
            listings[folder.uri] = folder.listing()
        info = listings[folder.uri].get(path.name, ObjectInfo(MISSING))
        if info.kind == MISSING:
            digest.update(f"{name}\0missing\n".encode())
        elif info.kind != FILE:
            digest.update(f"{name}\0not a regular file\n".encode())
        elif info.size <= HASH_MAX_BYTES:
            digest.update(f"{name}\0{info.size}\0{hashlib.sha256(path.read_bytes()).hexdigest()}\n".encode())
        else:
            digest.update(f"{name}\0{info.size}\0{info.mtime_ns}\n".encode())
    return digest.hexdigest(), len(unique)


def resume_fingerprint(task: str, options: Mapping[str, Any], sources: tuple[str, int] | None = None) -> dict[str, Any]:
    """The fingerprint a scene is written with (``errors`` starts at 0 and counts up while writing).

    Args:
        task: what wrote the scene, e.g. "kitti-object" or "generate".
        options: every option that can change the scene's bytes (JSON-serialisable).
        sources: ``source_digest`` of the files the scene reads (None for generated scenes).
    """
    fingerprint: dict[str, Any] = {
        "task": task,
        # Through JSON, as the scene metadata stores it (tuples become lists), so the two compare equal.
        "options": json.loads(json.dumps(dict(options), sort_keys=True)),
        "avdata_major": __version__.split(".")[0],
        "errors": 0,
    }
    if sources is not None:
        fingerprint["sources_sha256"], fingerprint["n_sources"] = sources
    return fingerprint


def recorded_fingerprint(path: Path) -> dict[str, Any] | None:
    """The fingerprint stored in scene file ``path``; None if the file is missing, unreadable or has none."""
    if not path.is_file():
        return None
    try:
        reader = SceneReader(path)
    except InputError:
        return None
    try:
        recorded = reader.metadata.get(RESUME_KEY)
    finally:
        reader.close()
    return recorded if isinstance(recorded, dict) else None


class ResumableWriter(DatasetWriter):
    """The dataset writer one scene task uses: its scene carries ``fingerprint``; complete means it matches.

    ``fingerprint`` is the live dict the task's error counter updates; the scene writer serialises its
    metadata when the scene's ``with`` block ends, so the recorded ``errors`` is the final count.

    Args:
        writer: the run's dataset writer (root, source, compression ... are taken from it).
        fingerprint: from :func:`resume_fingerprint`.
        force: never count a scene as complete (``--force``).
        store: the dataset's folder in an object store, when it is there: complete means its scene object
            carries the fingerprint (the scene is written locally under ``root``, then published).
        root: the local folder the scene is written in (default: ``writer``'s).
    """

    def __init__(self, writer: DatasetWriter, fingerprint: dict[str, Any], force: bool = False,
                 store: Location | None = None, root: Path | None = None):
        super().__init__(root or writer.root, source=writer.source, source_version=writer.source_version,
                         licence=writer.licence, compression=writer.compression, description=writer.description)
        self.share_written_index(writer)
        self.fingerprint = fingerprint
        self.force = force
        self.store = store
        #: names :meth:`is_complete` found complete (the task skipped them)
        self.found_complete: set[str] = set()

    def is_complete(self, name: str) -> bool:
        """Whether scene ``name`` exists with this run's fingerprint and was written without errors."""
        if self.force:
            return False
        if self.store is not None:
            from avdata.executors.store import recorded_fingerprint as stored_fingerprint

            recorded = stored_fingerprint(self.store / "scenes" / f"{name}.mcap", RESUME_KEY)
        else:
            recorded = recorded_fingerprint(scene_path(self.root, name))
        complete = recorded is not None and recorded.get("errors") == 0 and recorded == {**self.fingerprint, "errors": 0}
        if complete:
            self.found_complete.add(name)
        return complete

    def scene(self, name: str, metadata: Mapping[str, Any] | None = None) -> SceneWriter:
        """A writer for scene ``name`` whose metadata records the fingerprint."""
        return super().scene(name, {**dict(metadata or {}), RESUME_KEY: self.fingerprint})


def remove_stale_scenes(root: Path, keep: Iterable[str]) -> list[str]:
    """Deletes the scene files of ``root`` that this run does not produce.

    Called by a run over every scene of its source, under the dataset lock: a scene file outside the
    run's scene list (another ``--scene-size``, fewer ``--scenes``) would otherwise stay in the index.

    Returns:
        The names of the removed scenes.
    """
    scenes_dir = Path(root) / "scenes"
    if not scenes_dir.is_dir():
        return []
    keep = set(keep)
    removed = []
    for path in sorted(scenes_dir.glob("*.mcap")):
        if path.stem not in keep:
            os.unlink(path)
            removed.append(path.stem)
    return removed

