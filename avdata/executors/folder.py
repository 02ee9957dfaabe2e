"""A run's output folder as every writing command sees it: a local folder, or a prefix in an object store.

The one way convert, generate, export and track put their files under the same trust rules on a disk and in a store
(``s3://``, ``gs://``):

- **A file appears whole.** On a disk it is written under a temporary name beside its final one and renamed
  (:func:`avdata.outputs.write_atomically`). In a store it is put under a temporary key of the same naming scheme,
  copied server-side to its final key and the temporary key deleted (:func:`avdata.executors.store.publish`).
- **A scene file** is written by the dataset writer into a local folder (the output folder on a disk; on a store a
  folder of the task's own, gone with it) and published from there (:func:`scene_task_writer`).
- **What marks a run complete is written last** by the run's driver (the manifest; an export's summary files; the
  tracks table), after every task has published its files.

An :class:`OutputFolder` holds only a path or a URI, so a task in another process or on another node rebuilds it
(a :class:`~avdata.storage.Location` travels as its URI, never with a credential).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from avdata.errors import InputError
from avdata.executors.lock import complete_scenes, dataset_lock
from avdata.executors.resume import ResumableWriter
from avdata.executors.store import publish, publish_bytes, remove_temporary_keys, store_lock
from avdata.outputs import remove_temporary_files, write_atomically
from avdata.schema import DatasetWriter
from avdata.storage import FILE, Location, path_or_location


@dataclass(frozen=True, slots=True)
class OutputFolder:
    """The output folder ``root`` of a run: a local ``Path``, or a :class:`~avdata.storage.Location` in a store.

    Names given to its methods are paths relative to ``root`` with ``/`` separators (``training/calib/000000.txt``).
    """

    root: Path | Location

    @classmethod
    def of(cls, root: str | Path | Location) -> OutputFolder:
        """The folder of a path, a URI or a location (a task gets its folder's text and rebuilds it)."""
        return cls(root if isinstance(root, Location) and not root.is_local else path_or_location(str(root)))

    @property
    def store(self) -> Location | None:
        """The folder in an object store, None on a disk."""
        return self.root if isinstance(self.root, Location) else None

    def __str__(self) -> str:
        return str(self.root)

    def write(self, name: str, data: bytes) -> None:
        """Writes the file ``name`` whole: renamed into place on a disk, published (temporary key, copy) in a store."""
        if isinstance(self.root, Location):
            publish_bytes(data, self.root.join(name))
        else:
            write_atomically(self.root / name, data)

    def read_bytes(self, name: str) -> bytes | None:
        """The file ``name``, None when it is not there."""
        if isinstance(self.root, Location):
            target = self.root.join(name)
            return target.read_bytes() if target.is_file() else None
        try:
            return (self.root / name).read_bytes()
        except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
            return None

    def identities(self, names: Iterable[str]) -> dict[str, list[int] | None]:
        """Name -> [size, modification time in ns] of each file, None for a missing one.

        In a store: one metadata request (HEAD) per object; the time is the object's last-modified time, which a
        new upload or copy changes.
        """
        identities: dict[str, list[int] | None] = {}
        for name in names:
            if isinstance(self.root, Location):
                info = self.root.join(name).info()
                identities[name] = [info.size, info.mtime_ns] if info.kind == FILE else None
                continue
            try:
                stat = os.stat(self.root / name)
            except OSError:
                identities[name] = None
                continue
            identities[name] = [stat.st_size, stat.st_mtime_ns]
        return identities

    def remove(self, names: Iterable[str]) -> None:
        """Deletes the files ``names`` that are there (a folder in a file's place on a disk is the user's: kept)."""
        for name in names:
            if isinstance(self.root, Location):
                self.root.join(name).delete()
                continue
            path = self.root / name
            if not path.is_dir() or path.is_symlink():
                path.unlink(missing_ok=True)

    def files_under(self, folder: str) -> list[str]:
        """The names of every file under ``folder`` (recursively), sorted; none when it is missing."""
        if isinstance(self.root, Location):
            listed = self.root.join(folder).listing(recursive=True)
            return sorted(f"{folder}/{name}" for name, info in listed.items() if info.kind == FILE)
        base = self.root / folder
        if not base.is_dir():
            return []
        return sorted(p.relative_to(self.root).as_posix() for p in base.rglob("*") if p.is_file())

    def remove_temporary(self) -> None:
        """Deletes the temporary files (keys) an interrupted run left anywhere in the folder (only under its lock)."""
        if isinstance(self.root, Location):
            remove_temporary_keys(self.root)
        else:
            remove_temporary_files(self.root)

    def top_names(self) -> list[str]:
        """The names directly in the folder (files and folders), sorted."""
        if isinstance(self.root, Location):
            return sorted(self.root.listing())
        return sorted(p.name for p in self.root.iterdir()) if self.root.is_dir() else []


@contextmanager
def folder_lock(root: str | Path | Location, kept: Callable[[Path], str] = complete_scenes) -> Iterator[OutputFolder]:
    """Holds the writer lock of the output folder ``root`` for the ``with`` block: one writer, on a disk or in a store.

    On a disk the ``flock`` of :func:`~avdata.executors.lock.dataset_lock` (the folder is created; ``kept`` describes
    what it holds complete, for the message of a full disk); in a store the lock object of
    :func:`~avdata.executors.store.store_lock`.
    """
    folder = OutputFolder.of(root)
    if folder.store is not None:
        if folder.store.is_file():  # as on a disk: keys under an object's name would hide behind it in every listing
            raise InputError(f"{folder.store}: expected a folder (prefix) to write into, got an object")
        with store_lock(folder.store):
            yield folder
        return
    with dataset_lock(Path(folder.root), kept=kept):
        yield folder


@contextmanager
def scene_task_writer(writer: DatasetWriter, fingerprint: dict[str, Any], dst: Path | Location,
                      force: bool = False) -> Iterator[ResumableWriter]:
    """The writer of one scene task into the dataset ``dst`` (see :class:`~avdata.executors.resume.ResumableWriter`).

    On a disk it writes into ``dst`` itself. In a store it writes into a local folder of this task, and when the
    ``with`` block ends without an exception, publishes the scene files written there (then gone with the folder);
    the scene's completeness is read from its object.
    """
    if not isinstance(dst, Location):
        yield ResumableWriter(writer, fingerprint, force=force)
        return
    with tempfile.TemporaryDirectory(prefix="avdata-scene-") as local:
        yield ResumableWriter(writer, fingerprint, force=force, store=dst, root=Path(local))
        for path in sorted((Path(local) / "scenes").glob("*.mcap")):
            publish(path, dst / "scenes" / path.name)
