"""The one scene-run pipeline that convert, generate and export share.

A run holds the output folder's lock (:mod:`avdata.executors.lock`) for its whole length, starts its executor
and checks that the workers see its folders, removes what an interrupted run left (temporary files, and with
a scene list the scenes this run no longer produces), runs one task per scene, writes ``errors.jsonl`` and
sums the outcomes into one :class:`SceneRunResult`. Each task returns a
:class:`~avdata.executors.scenes.SceneOutcome` whose status is one of :data:`OUTCOMES`.

An output folder in an object store (:mod:`avdata.executors.store`) gets the same run: its lock is a lock
object, the run's folder is a local staging folder (where the index, manifest and problem log are built), tasks
publish their files to the store through :attr:`SceneRun.folder` (:mod:`avdata.executors.folder`: scene files by
:func:`~avdata.executors.folder.scene_task_writer`, other files by :meth:`~avdata.executors.folder.OutputFolder.write`),
and :meth:`SceneRun.publish` uploads the index, the problem log and the manifest last (:meth:`SceneRun.publish_log`:
the problem log alone, for runs that write no dataset).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from avdata.executors.base import Executor, make_executor
from avdata.executors.folder import OutputFolder, folder_lock
from avdata.executors.lock import complete_scenes
from avdata.executors.resume import remove_stale_scenes
from avdata.executors.scenes import (
    COMPLETE,
    ERROR_LOG,
    FAILED,
    WRITTEN,
    Problem,
    SceneOutcome,
    run_scene_tasks,
    write_error_log,
)
from avdata.executors.store import (
    StoreScenes,
    mirror_state,
    scene_names,
    staging_folder,
    upload_outputs,
)
from avdata.executors.store import remove_stale_scenes as remove_stale_objects
from avdata.schema.index import INDEX_TABLES
from avdata.schema.manifest import MANIFEST
from avdata.storage import Location


@dataclass(frozen=True, slots=True, kw_only=True)
class EngineConfig:
    """Where the scene tasks run.

    Attributes:
        executor: "local" (a process pool of ``workers``) or "ray".
        workers: scenes run in parallel processes (``executor`` "local").
        ray_address: the Ray cluster to join (``executor`` "ray"; None starts a local Ray instance).
        quiet: no progress bar.
    """

    executor: str = "local"
    workers: int = 1
    ray_address: str | None = None
    quiet: bool = False


@dataclass(frozen=True, slots=True, kw_only=True)
class SceneRunResult:
    """What a scene run did, by scene name: written, complete from an earlier run, failed, removed as stale.

    ``problems`` are those of the scenes this run wrote or failed (a complete scene's were reported when it
    was written). Exporters add their own counts in a subclass.
    """

    written: list[str]
    complete: list[str]
    failed: list[str]
    problems: list[Problem]
    removed: list[str] = field(default_factory=list)

    @property
    def n_errors(self) -> int:
        """The number of problems of severity "error"."""
        return sum(p.severity == "error" for p in self.problems)


def outcome_fields(outcomes: Sequence[SceneOutcome], removed: Iterable[str] = ()) -> dict[str, Any]:
    """The :class:`SceneRunResult` fields of ``outcomes`` (for a subclass's constructor too)."""
    return {
        "written": [o.scene for o in outcomes if o.status == WRITTEN],
        "complete": [o.scene for o in outcomes if o.status == COMPLETE],
        "failed": [o.scene for o in outcomes if o.status == FAILED],
        "problems": [p for o in outcomes if o.status != COMPLETE for p in o.problems],
        "removed": list(removed),
    }


def run_result(outcomes: Sequence[SceneOutcome], removed: Iterable[str] = ()) -> SceneRunResult:
    """The :class:`SceneRunResult` of ``outcomes``."""
    return SceneRunResult(**outcome_fields(outcomes, removed))


class SceneRun:
    """One run over an output folder, inside :func:`scene_run`: cleans the folder, runs the tasks, logs problems."""

    def __init__(self, root: Path, executor: Executor, quiet: bool, store: Location | None = None):
        self.root = Path(root)
        self.executor = executor
        self.quiet = quiet
        #: the output folder in an object store (``root`` is then the local staging folder), else None
        self.store = store

    def clean(self, keep: Sequence[str] | None = None) -> list[str]:
        """Removes an interrupted run's temporary files and, given the scenes this run makes, every other scene file.

        Returns:
            The names of the removed scenes.
        """
        self.folder.remove_temporary()
        if self.store is not None:
            return [] if keep is None else remove_stale_objects(self.store, keep)
        return [] if keep is None else remove_stale_scenes(self.root, keep)

    def run(self, fn: Callable[[Any], SceneOutcome], tasks: Sequence[Any], scenes: Sequence[str],
            desc: str) -> list[SceneOutcome]:
        """One task per scene on the run's executor, with progress; outcomes in scene order."""
        return run_scene_tasks(fn, tasks, scenes, self.executor, desc, self.quiet)

    def log(self, outcomes: Sequence[SceneOutcome], exists: Callable[[Any], bool] | None = None) -> None:
        """Writes ``errors.jsonl`` (see :func:`~avdata.executors.scenes.write_error_log`).

        In a store, a scene exists when its object does.
        """
        if self.store is not None and exists is None:
            on_store = set(scene_names(self.store))
            exists = on_store.__contains__
        write_error_log(self.root, outcomes, exists)

    @property
    def folder(self) -> OutputFolder:
        """The output folder the tasks write into: the run's folder on a disk, the store's prefix otherwise."""
        return OutputFolder(self.store if self.store is not None else self.root)

    def scene_files(self) -> StoreScenes | None:
        """Where the dataset writer finds the finished scenes for the index: None for the run's own folder."""
        return None if self.store is None else StoreScenes(self.store, self.root)

    def publish(self) -> None:
        """In a store: uploads the index tables, the problem log and the manifest (last); nothing on a disk."""
        if self.store is not None:
            upload_outputs(self.root, self.store, INDEX_TABLES, ERROR_LOG, MANIFEST)

    def publish_log(self) -> None:
        """In a store: uploads the problem log (deletes it when the run has none); nothing on a disk."""
        if self.store is not None:
            upload_outputs(self.root, self.store, (), ERROR_LOG, None)


@contextmanager
def scene_run(root: str | Path | Location, engine: EngineConfig, visible: Sequence[Path | Location],
              kept: Callable[[Path], str] = complete_scenes) -> Iterator[SceneRun]:
    """Holds ``root``'s lock and an executor whose workers see ``visible`` for the ``with`` block.

    Args:
        root: the output folder (created), or its URI in an object store.
        engine: where the tasks run.
        visible: the folders every worker must see (SRC, DST); those in an object store are reached by URI.
        kept: describes what ``root`` holds complete, for the message of a full disk.
    """
    local = [Path(p) for p in visible if not isinstance(p, Location)]
    with folder_lock(root, kept) as folder, make_executor(engine.executor, workers=engine.workers,
                                                          ray_address=engine.ray_address) as executor:
        executor.check_visible(local)
        if folder.store is None:
            yield SceneRun(Path(folder.root), executor, engine.quiet)
            return
        with staging_folder() as staging:
            mirror_state(folder.store, staging, (MANIFEST, ERROR_LOG))
            yield SceneRun(staging, executor, engine.quiet, store=folder.store)
