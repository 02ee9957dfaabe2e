"""The :class:`Exporter` interface and its run: the scene-run pipeline with per-scene resume markers.

An exporter plans one task per scene, exports one scene per task and finishes the run (tables, image sets)
from the scene outcomes; :func:`run_export` does the rest through :mod:`avdata.executors.pipeline`. An export
run holds DST's writer lock (:func:`avdata.executors.dataset_lock`) from planning to the finishing step.
Each scene task writes its files under unique temporary names, renames them, and then records a marker
``DST/.avdata-export/scenes/<scene>.json``: the scene's resume fingerprint (the dataset scene file's identity,
the export options, the plan of the scene and the major avdata version), the files it wrote with their size
and mtime, its problems and the data the finishing step needs (samples written, table rows). A rerun skips a
scene whose marker matches and whose files are all still there as recorded; anything else (another option, a
changed scene file, a scene written with errors, ``--force``) rewrites it. Files no scene of this run produces
are removed, so nothing of an earlier export with other options survives. ``DST/.avdata-export/export.json``
names the format (and nuScenes table folder) of the last run.

DATASET and DST may each be a local folder or a prefix in an object store (``s3://``, ``gs://``). Every file goes
through the run's :class:`~avdata.executors.folder.OutputFolder`: on a disk written under a temporary name and
renamed; in a store put under a temporary key, copied server-side to its key and the temporary key deleted, so each
exported file appears whole or not at all. A scene's marker is written after its files, and the finishing step's
files (KITTI: ``ImageSets/`` then ``avdata_export.json``; nuScenes: the map, the tables, then
``avdata_channels.json``) and ``errors.jsonl`` after every scene's; a file's identity in a marker is its size and
modification time (in a store: the object's, one HEAD each). The lock is the store's lock object.
"""

from __future__ import annotations

import json
from abc import ABC, abstractmethod
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, ClassVar, Generic, TypeVar

from avdata.errors import InputError
from avdata.executors.folder import OutputFolder
from avdata.executors.lock import LOCK_NAME
from avdata.executors.pipeline import EngineConfig, SceneRun, SceneRunResult, scene_run
from avdata.executors.resume import resume_fingerprint, source_digest
from avdata.executors.scenes import COMPLETE, FAILED, Problem, SceneOutcome
from avdata.outputs import checked_name, refuse_output_in_input
from avdata.schema import DatasetReader, SceneReader, scene_path
from avdata.schema.dataset import dataset_root, open_scene
from avdata.storage import Location

#: Folder of the per-scene markers and the run state, inside DST.
STATE_DIR = ".avdata-export"
_RUN_STATE = "export.json"


@dataclass(frozen=True, slots=True, kw_only=True)
class ExportConfig:
    """How to run an export.

    Args:
        dataset: the unified dataset folder (a ``Path``, or a :class:`~avdata.storage.Location` in a store).
        dst: the folder to write (a ``Path``, or a :class:`~avdata.storage.Location` in a store).
        scenes: only these scenes (all when None); the export then holds only them.
        executor: "local" (a process pool of ``workers``) or "ray".
        workers: scenes exported in parallel processes (``executor`` "local").
        ray_address: the Ray cluster to join (``executor`` "ray"; None starts a local Ray instance).
        force: rewrite every scene, also those complete from an earlier run.
        quiet: no progress bar.
    """

    dataset: Path | Location
    dst: Path | Location
    scenes: tuple[str, ...] | None = None
    executor: str = "local"
    workers: int = 1
    ray_address: str | None = None
    force: bool = False
    quiet: bool = True


@dataclass(frozen=True, slots=True, kw_only=True)
class SceneJob:
    """What one scene task needs besides its format's own plan: where, and the fingerprint to match."""

    dataset: str
    dst: str
    scene: str
    fingerprint: dict[str, Any]
    force: bool
    #: problems found while planning (e.g. frames without sensor data), reported with the scene
    problems: tuple[Problem, ...] = ()


def export_config(config: ExportConfig | None, dataset: str | Path | Location, dst: str | Path | Location,
                  scenes: Sequence[str] | None) -> ExportConfig:
    """``config`` (default: the calling process, quiet) with the dataset, DST (paths or store URIs) and scenes given."""
    dataset, dst = dataset_root(dataset), dataset_root(dst)
    return replace(config or ExportConfig(dataset=dataset, dst=dst), dataset=dataset, dst=dst,
                   scenes=tuple(scenes) if scenes else None)


def select_scenes(dataset: DatasetReader, scenes: Sequence[str] | None) -> list[str]:
    """The scenes to export, in dataset order; InputError names unknown ones."""
    if not scenes:
        return list(dataset.scenes)
    unknown = sorted(set(scenes) - set(dataset.scenes))
    if unknown:
        raise InputError(f"{dataset.root}: expected scenes of the dataset, got unknown {unknown}")
    wanted = set(scenes)
    return [s for s in dataset.scenes if s in wanted]


def scene_fingerprint(dataset: DatasetReader, scene: str, export_format: str, options: Mapping[str, Any]) -> dict[str, Any]:
    """The resume fingerprint of one exported scene: its scene file, the options and the avdata major version."""
    sources = source_digest([scene_path(dataset.root, scene)], dataset.root)
    return resume_fingerprint(f"export-{export_format}", {"dataset": dataset_id(dataset.root), **options}, sources)


def dataset_id(root: Path | Location) -> str:
    """The dataset's identity in a fingerprint and the run state: its resolved path, or its URI."""
    return root.uri if isinstance(root, Location) else str(Path(root).resolve())


def open_dataset_scene(job: SceneJob) -> tuple[SceneReader, Path | Location]:
    """(the reader of ``job``'s scene with every chunk's CRC checked, its path or URI for messages)."""
    root = dataset_root(job.dataset)
    return open_scene(root, job.scene, verify=True), scene_path(root, job.scene)


ResultT = TypeVar("ResultT", bound=SceneRunResult)


class Exporter(ABC, Generic[ResultT]):
    """Base of every exporter (unified -> another format). Subclasses set ``format`` and implement three methods.

    Attributes:
        format: the command-line name, e.g. "kitti-object"; recorded in the run state.
        config: this run's :class:`ExportConfig`.
        out: DST as the files are written into it (:class:`~avdata.executors.folder.OutputFolder`).
        tables: the folder of the format's tables inside DST (nuScenes ``--version``), or None.
        table_files: the file names of that folder, removed when a rerun names another folder.
    """

    format: ClassVar[str]
    table_files: ClassVar[tuple[str, ...]] = ()

    def __init__(self, config: ExportConfig, tables: str | None = None):
        self.config = config
        self.tables = tables
        self.out = OutputFolder(config.dst)

    @abstractmethod
    def plan(self, dataset: DatasetReader, scenes: list[str]) -> tuple[list[Any], list[SceneOutcome]]:
        """(one task per scene to export, outcomes of scenes that fail before any task: cannot be planned).

        Each task is handed to :meth:`export_scene` in a worker; it has a ``job`` (:class:`SceneJob`).
        """

    @abstractmethod
    def export_scene(self, task: Any) -> SceneOutcome:
        """Exports one scene: skip it if :func:`completed`, else write its files and :func:`record` them.

        Input errors are returned as a failed outcome (its files removed), never raised.
        """

    @abstractmethod
    def finish(self, dataset: DatasetReader, outcomes: list[SceneOutcome]) -> ResultT:
        """Writes what the whole export shares (tables, image sets) from the outcomes in scene order; its result."""


def run_export(exporter: Exporter[ResultT]) -> ResultT:
    """Runs ``exporter``: plans, exports every scene on the configured executor, finishes (see the module docstring).

    Raises:
        InputError: the dataset is missing or unreadable, a scene is unknown, DST holds something other than
            this export, cannot be written, or another process holds its lock.
    """
    config = exporter.config
    if exporter.tables is not None:
        checked_name(exporter.tables, "--version")
    dataset = DatasetReader(config.dataset)
    # Both checked before DST is touched, so a missing dataset or an unknown scene leaves no DST behind.
    names = select_scenes(dataset, config.scenes)
    refuse_output_in_input(config.dst, [dataset.root], "DATASET")  # before DST is created
    engine = EngineConfig(executor=config.executor, workers=config.workers, ray_address=config.ray_address,
                          quiet=config.quiet)
    with scene_run(config.dst, engine, [config.dataset, config.dst], kept=_exported_scenes) as run:
        _claim(run, exporter, dataset)
        tasks, planned = exporter.plan(dataset, names)
        ran = run.run(_export_task, [(exporter, task) for task in tasks], [t.job.scene for t in tasks],
                      f"export {exporter.format}")
        by_scene = {o.scene: o for o in [*ran, *planned]}
        outcomes = [by_scene[name] for name in names]
        result = exporter.finish(dataset, outcomes)
        _forget_failed(run.folder, outcomes)
        run.log(outcomes, exists=lambda scene: scene in by_scene)
        run.publish_log()
    return result


def _export_task(task: tuple[Exporter[Any], Any]) -> SceneOutcome:
    """One scene task in a worker (a module-level function: Ray takes functions, not bound methods)."""
    exporter, scene_task = task
    return exporter.export_scene(scene_task)


def _claim(run: SceneRun, exporter: Exporter[Any], dataset: DatasetReader) -> None:
    """Refuses a DST that holds anything but this export; cleans it and records the run state.

    DST must be empty, or hold an earlier export of the same format from the same dataset (recorded in the run
    state, which is written before any scene so that a crashed first run can be resumed): another format,
    another dataset's export, or any other content (a real nuScenes or KITTI folder, whose files the stale-file
    pass would delete and whose tables the export would replace) is refused, as ``convert`` refuses a folder
    holding another source's dataset.
    """
    dst, export_format, version = run.folder, exporter.format, exporter.tables
    source = dataset_id(dataset.root)
    previous = _run_state(dst)
    if previous and previous.get("format") != export_format:
        raise InputError(f"{dst}: expected an empty folder or a {export_format} export, got a "
                         f"{previous.get('format')} export (write into another folder)")
    if previous.get("dataset") not in (None, source):
        raise InputError(f"{dst}: expected an empty folder or an export of {source}, got an export of "
                         f"{previous['dataset']} (write into another folder)")
    if not previous:
        other = [name for name in dst.top_names() if name != LOCK_NAME]
        if other:
            raise InputError(f"{dst}: expected an empty folder or an earlier avdata export, got a folder holding "
                             f"{', '.join(other[:3])}{' ...' if len(other) > 3 else ''} (write into another folder)")
    if version is not None and previous.get("tables") not in (None, version):
        _remove_tables(dst, str(previous["tables"]), exporter.table_files)
    run.clean()
    _write_json(dst, f"{STATE_DIR}/{_RUN_STATE}", {"format": export_format, "tables": version, "dataset": source})


def _forget_failed(dst: OutputFolder, outcomes: Sequence[SceneOutcome]) -> None:
    """Removes the markers of scenes outside this run or failed in it."""
    kept = {f"{STATE_DIR}/scenes/{o.scene}.json" for o in outcomes if o.status != FAILED}
    dst.remove([name for name in dst.files_under(f"{STATE_DIR}/scenes") if name.endswith(".json") and name not in kept])


def completed(job: SceneJob) -> SceneOutcome | None:
    """The outcome stored by an earlier run of ``job``'s scene if it is complete, else None.

    Complete: the marker's fingerprint equals this run's, it recorded no errors, and every file it
    lists still has the recorded size and mtime. Otherwise the marker is removed (the scene is redone).
    """
    dst, marker = OutputFolder.of(job.dst), _marker_name(job.scene)
    if job.force:
        dst.remove([marker])
        return None
    found = dst.read_bytes(marker)
    if found is None:
        return None
    try:
        stored = json.loads(found)
        files = stored["files"]
        intact = stored["fingerprint"] == {**job.fingerprint, "errors": 0} and dst.identities(files) == {
            name: list(identity) if identity is not None else None for name, identity in files.items()}
        problems = [Problem(**p) for p in stored["problems"]]
    except (ValueError, KeyError, TypeError, AttributeError):
        intact = False
    if not intact:
        dst.remove([marker])
        return None
    return SceneOutcome(scene=job.scene, status=COMPLETE, problems=problems, data=stored["data"])


def record(job: SceneJob, outcome: SceneOutcome, files: Iterable[str]) -> SceneOutcome:
    """Writes the marker of a finished scene task (its errors make the scene incomplete for a rerun)."""
    dst = OutputFolder.of(job.dst)
    errors = sum(p.severity == "error" for p in outcome.problems)
    _write_json(dst, _marker_name(job.scene), {
        "fingerprint": {**job.fingerprint, "errors": errors},
        "files": dst.identities(sorted(files)),
        "problems": [asdict(p) for p in outcome.problems],
        "data": outcome.data,
    })
    return outcome


def problem(scene: str, path: Path | Location, error: Exception, context: str = "") -> Problem:
    """The error of ``scene`` in file ``path``: ``context``, then the message naming the file only once."""
    message = str(error).removeprefix(f"{path}: ")  # readers' messages start with their file
    return Problem(severity="error", scene=scene, file=str(path), message=context + message)


def prune(dst: OutputFolder, folders: Iterable[str], keep: set[str]) -> int:
    """Deletes the files under ``dst/<folder>`` whose path relative to ``dst`` is not in ``keep``.

    Returns:
        The number of files removed.
    """
    stale = [name for folder in folders for name in dst.files_under(folder) if name not in keep]
    dst.remove(stale)
    return len(stale)


def _exported_scenes(dst: Path) -> str:
    """What an export folder keeps: the scenes whose files and marker are complete."""
    markers = Path(dst) / STATE_DIR / "scenes"
    n = len(list(markers.glob("*.json"))) if markers.is_dir() else 0
    return f"{n} exported scene(s) (their markers in {markers})"


def _marker_name(scene: str) -> str:
    return f"{STATE_DIR}/scenes/{scene}.json"


def _run_state(dst: OutputFolder) -> dict[str, Any]:
    try:
        state = json.loads(dst.read_bytes(f"{STATE_DIR}/{_RUN_STATE}") or b"")
    except ValueError:
        return {}
    return state if isinstance(state, dict) else {}


def _remove_tables(dst: OutputFolder, folder: str, files: Iterable[str]) -> None:
    """Deletes the tables of an earlier export with another ``--version`` (on a disk, the folder if then empty)."""
    dst.remove(f"{folder}/{name}" for name in files)
    if isinstance(dst.root, Path) and (dst.root / folder).is_dir() and not any((dst.root / folder).iterdir()):
        (dst.root / folder).rmdir()


def _write_json(dst: OutputFolder, name: str, value: Any) -> None:
    # Key order kept: the stored table rows are written out again as they are.
    dst.write(name, json.dumps(value).encode())
