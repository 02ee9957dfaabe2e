"""The one interface every converter implements, and the driver that runs them.

A converter lists its source's scenes, names the source files each scene reads, and converts one
scene at a time into a SceneWriter; it translates its source's conventions inside itself and writes
only the unified ones. Its options are a typed frozen dataclass (``Converter.Options``).

The driver holds the dataset folder's lock, runs one task per scene on an executor (a local process
pool or Ray), skips a scene only when its resume fingerprint matches (same source files, options,
major avdata version, written without errors; see :mod:`avdata.executors.resume`), collects problems
per scene into the result and ``DST/errors.jsonl`` (a bad scene is reported, the others convert),
and stops at the first error with ``strict``.
"""

from __future__ import annotations

import argparse
import importlib
import json
import types
import typing
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, ClassVar

from avdata.errors import AvdataError, InputError
from avdata.executors.folder import OutputFolder, scene_task_writer
from avdata.executors.pipeline import EngineConfig, SceneRunResult, run_result, scene_run
from avdata.executors.resume import resume_fingerprint, source_digest
from avdata.executors.scenes import COMPLETE, FAILED, WRITTEN, Problem, SceneOutcome
from avdata.inputs import files_under
from avdata.outputs import name_full_disk, refuse_output_in_input
from avdata.schema import DatasetWriter, scene_path
from avdata.schema.manifest import MANIFEST
from avdata.storage import Location


@dataclass(frozen=True, slots=True, kw_only=True)
class ConverterOptions:
    """Base of each converter's typed options (a frozen keyword-only dataclass; none by default).

    Each field becomes a command-line option ``--field-name`` (``bool``: a flag; ``X | None``: type X,
    default None) whose help is the field's ``metadata["help"]`` and whose allowed values are
    ``metadata["choices"]`` if given. Checks of values go in ``__post_init__`` and raise ``InputError``
    naming the option.
    """


@dataclass(frozen=True, slots=True, kw_only=True)
class ConvertConfig:
    """Options common to every converter.

    Attributes:
        src: the source dataset folder, in its published layout: a ``Path``, or a
            :class:`~avdata.storage.Location` in an object store (converters whose ``reads_stores`` is True).
        dst: the unified dataset folder to write: a ``Path``, or a :class:`~avdata.storage.Location` in an
            object store (every converter).
        strict: stop at the first error instead of skipping the bad frame or scene.
        workers: scenes converted in parallel processes (``executor`` "local").
        quiet: no progress bars.
        compression: MCAP chunk compression, "none" | "zstd" | "lz4".
        scenes: convert only these scenes (all when empty).
        options: the converter's ``Options`` instance, or a mapping of its field values (None: defaults).
        force: rewrite every scene, complete or not.
        executor: "local" (a process pool of ``workers``) or "ray".
        ray_address: the Ray cluster to join (``executor`` "ray"; None starts a local Ray instance).
    """

    src: Path | Location
    dst: Path | Location
    strict: bool = False
    workers: int = 1
    quiet: bool = False
    compression: str = "none"
    scenes: tuple[str, ...] = ()
    options: ConverterOptions | Mapping[str, Any] | None = None
    force: bool = False
    executor: str = "local"
    ray_address: str | None = None


class StrictError(AvdataError):
    """Raised in strict mode at the first error."""


class Report:
    """Collects the warnings and errors of one scene's conversion.

    Args:
        scene: the scene's name.
        strict: raise at the first error.
        fingerprint: the scene's resume fingerprint; its ``errors`` counts the errors reported, so a
            scene written with errors is never taken as complete by a rerun.
    """

    def __init__(self, scene: str, strict: bool, fingerprint: dict[str, Any] | None = None):
        self.scene = scene
        self.strict = strict
        self.problems: list[Problem] = []
        self._fingerprint = fingerprint

    def warn(self, file: str | Path | Location, message: str) -> None:
        """Something missing or odd that does not stop the scene (e.g. a missing sensor file)."""
        message = message.removeprefix(f"{file}: ")  # the file is named once, by the Problem
        self.problems.append(Problem(severity="warning", scene=self.scene, file=str(file), message=message))

    def error(self, file: str | Path | Location, message: str) -> None:
        """Bad input: the frame is skipped; in strict mode the conversion stops here."""
        message = message.removeprefix(f"{file}: ")  # the file is named once, by the Problem
        problem = Problem(severity="error", scene=self.scene, file=str(file), message=message)
        if self.strict:
            raise StrictError(str(problem))
        self.problems.append(problem)
        if self._fingerprint is not None:
            self._fingerprint["errors"] += 1


class Converter(ABC):
    """Base of every converter. Subclasses set the class attributes and implement three methods.

    Attributes:
        name: the command-line name, e.g. "kitti-object".
        source: the source dataset's name written into the manifest.
        licence: the source data's licence.
        Options: the converter's typed options (a :class:`ConverterOptions` dataclass); ``self.options``
            holds this run's instance.
        reads_stores: SRC may be in an object store (its reading goes through :mod:`avdata.inputs` only).
    """

    name: ClassVar[str]
    source: ClassVar[str]
    licence: ClassVar[str] = ""
    Options: ClassVar[type[ConverterOptions]] = ConverterOptions
    reads_stores: ClassVar[bool] = False

    def __init__(self, config: ConvertConfig):
        self.config = config
        make_options(self.Options, config.options)  # bad options fail here, not in the first worker
        if isinstance(config.src, Location) and not self.reads_stores:
            readers = sorted(name for name in CONVERTERS if converter_class(name).reads_stores)
            raise InputError(f"{config.src}: {self.name} reads its source from a local folder only (from an object "
                             f"store: {', '.join(readers)}); copy it to a disk first")

    @property
    def options(self) -> Any:
        """This run's ``Options`` instance (derived from the config, so it survives any pickling)."""
        return make_options(self.Options, self.config.options)

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        """Adds one command-line option per field of ``Options`` (see :class:`ConverterOptions`)."""
        hints = typing.get_type_hints(cls.Options)
        for option in fields(cls.Options):
            flag = "--" + option.name.replace("_", "-")
            help_text = option.metadata.get("help")
            if option.default not in (None, False):
                help_text = f"{help_text} (default: {option.default})"
            kind = hints[option.name]
            if kind is bool:
                parser.add_argument(flag, action="store_true", help=help_text)
                continue
            if typing.get_origin(kind) in (typing.Union, types.UnionType):
                kind = next(arg for arg in typing.get_args(kind) if arg is not type(None))
            parser.add_argument(flag, type=kind, default=option.default, choices=option.metadata.get("choices"),
                                help=help_text)

    def source_version(self) -> str:
        """The source's version string for the manifest."""
        return ""

    def release(self) -> None:  # noqa: B027 - an optional hook
        """Drops what the converter cached about its source (parsed tables), before the index is built."""

    def source_files(self, scene: str) -> Sequence[Path | Location]:
        """Every source file scene ``scene`` is made from (its resume fingerprint covers them).

        The default is every file under SRC: always honest, but slow for big sources and a change to
        any file rewrites every scene; converters list exactly the files a scene reads.
        """
        return files_under(self.config.src)

    def fingerprint_options(self) -> dict[str, Any]:
        """The options that shape a scene's bytes, recorded in its resume fingerprint."""
        return {**asdict(self.options), "compression": self.config.compression}

    @abstractmethod
    def list_scenes(self) -> list[str]:
        """Every scene name in the source, in a stable order; raises InputError if SRC is unusable."""

    @abstractmethod
    def convert_scene(self, scene: str, writer: DatasetWriter, report: Report) -> None:
        """Converts one scene: ``with writer.scene(name, metadata) as scene_writer: ...``.

        Raise InputError for a problem that makes the whole scene unusable (the scene file is then
        not written); call ``report.error`` / ``report.warn`` for per-frame problems and go on.
        """


def make_options(cls: type[ConverterOptions], given: ConverterOptions | Mapping[str, Any] | None) -> ConverterOptions:
    """``given`` as an instance of the converter's options class ``cls`` (defaults for None)."""
    if isinstance(given, cls):
        return given
    if given is None:
        return cls()
    if not isinstance(given, Mapping):
        raise AvdataError(f"expected options of type {cls.__name__} or a mapping, got {type(given).__name__}")
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(given) - known)
    if unknown:
        raise AvdataError(f"expected options among {sorted(known)}, got {unknown[0]!r}")
    return cls(**given)


#: name -> "module:Class"; imported only when asked for, so ``avdata --help`` stays fast.
CONVERTERS: dict[str, str] = {
    "kitti-object": "avdata.converters.kitti:KittiObjectConverter",
    "kitti-tracking": "avdata.converters.kitti:KittiTrackingConverter",
    "kitti-raw": "avdata.converters.kitti:KittiRawConverter",
    "nuscenes": "avdata.converters.nuscenes:NuScenesConverter",
    "opv2v": "avdata.converters.opv2v:Opv2vConverter",
    "dair-v2x": "avdata.converters.dair_v2x:DairV2xConverter",
    "argoverse2": "avdata.converters.argoverse2:Argoverse2Converter",
    "waymo": "avdata.converters.waymo:WaymoConverter",
}


def converter_class(name: str) -> type[Converter]:
    """The converter class registered under ``name``."""
    if name not in CONVERTERS:
        raise AvdataError(f"expected a converter of {sorted(CONVERTERS)}, got {name!r}")
    module_name, class_name = CONVERTERS[name].split(":")
    cls: type[Converter] = getattr(importlib.import_module(module_name), class_name)
    return cls


#: What a conversion did (the one result of every scene run).
ConversionResult = SceneRunResult


def _convert_task(task: tuple[Converter, DatasetWriter, str]) -> SceneOutcome:
    """One scene: skip it if complete, else convert it; input errors are returned, never raised.

    The scene is written and (DST in a store) published by :func:`~avdata.executors.folder.scene_task_writer`.
    """
    converter, writer, scene = task
    config = converter.config
    try:
        scene_file = scene_path(writer.root, scene)
    except AvdataError as error:  # a source folder named 'a b' costs that scene (it has no file yet), not the run
        return SceneOutcome(scene=scene, status=FAILED, problems=[
            Problem(severity="error", scene=scene, file=str(config.src), message=str(error))])
    try:
        sources = source_digest(converter.source_files(scene), config.src)
    except AvdataError as error:
        return _failed(scene, [], str(config.src), str(error), config.dst)
    fingerprint = resume_fingerprint(converter.name, converter.fingerprint_options(), sources)
    report = Report(scene, config.strict, fingerprint)
    try:
        with scene_task_writer(writer, fingerprint, config.dst, force=config.force) as scene_writer:
            scene_file = scene_path(scene_writer.root, scene)
            if scene_writer.is_complete(scene):
                return SceneOutcome(scene=scene, status=COMPLETE, problems=[])
            converter.convert_scene(scene, scene_writer, report)
    except OSError as error:  # a full disk stops the run (avdata.executors.lock), naming the scene file
        raise name_full_disk(error, scene_file) from None
    except StrictError:
        raise
    except AvdataError as error:
        if config.strict:
            raise
        return _failed(scene, report.problems, str(config.src), str(error), config.dst)
    return SceneOutcome(scene=scene, status=WRITTEN, problems=report.problems)


def _failed(scene: str, problems: list[Problem], file: str, message: str,
            dst: Path | Location) -> SceneOutcome:
    # A scene file from an earlier run no longer matches the source that now fails: it goes.
    OutputFolder(dst).remove([scene_path(".", scene).as_posix()])
    problem = Problem(severity="error", scene=scene, file=file, message=message)
    return SceneOutcome(scene=scene, status=FAILED, problems=[*problems, problem])


def check_source(root: Path, source: str) -> None:
    """Refuses to write a ``source`` dataset into a folder that holds another source's dataset."""
    manifest = Path(root) / MANIFEST
    try:
        existing = json.loads(manifest.read_text()).get("source", {}).get("name")
    except (OSError, ValueError, AttributeError):
        return
    if existing and existing != source:
        raise InputError(f"{root}: expected an empty folder or a {source} dataset, got a {existing} dataset "
                         f"(write into another folder)")


def run_conversion(converter: Converter) -> SceneRunResult:
    """Converts every (selected) scene not yet complete, then builds the index and manifest.

    Holds the dataset lock for the whole run; a run over all scenes removes scene files of earlier
    runs that this one does not produce (another ``--scene-size``).
    """
    config = converter.config
    # DST under SRC: a converter's default source_files (every file under SRC) read each run's scenes back.
    refuse_output_in_input(config.dst, [config.src], "SRC")
    # The source is read first, so a wrong SRC leaves no DST folder behind.
    scenes = converter.list_scenes()
    if config.scenes:
        unknown = sorted(set(config.scenes) - set(scenes))
        if unknown:
            raise AvdataError(f"{config.src}: expected scenes among {scenes[:10]}..., got unknown {unknown}")
        scenes = [s for s in scenes if s in set(config.scenes)]
    engine = EngineConfig(executor=config.executor, workers=config.workers, ray_address=config.ray_address,
                          quiet=config.quiet)
    with scene_run(config.dst, engine, [config.src, config.dst]) as run:
        check_source(run.root, converter.source)
        writer = DatasetWriter(
            run.root,
            source=converter.source,
            source_version=converter.source_version(),
            licence=converter.licence,
            compression=config.compression,
            scene_files=run.scene_files(),
        )
        with writer:
            removed = run.clean(None if config.scenes else scenes)
            outcomes = run.run(_convert_task, [(converter, writer, s) for s in scenes], scenes, f"convert {converter.name}")
            run.log(outcomes)
            # The index is built when the writer's block ends; the source's tables are not needed for it.
            converter.release()
        run.publish()
    return run_result(outcomes, removed)
