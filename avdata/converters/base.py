"""The one interface every converter implements, and the driver that runs them.

A converter lists its source's scenes and converts one scene at a time into a SceneWriter; it
translates its source's conventions inside itself and writes only the unified ones. The driver
skips scenes already complete, runs scenes in worker processes, collects problems per scene
(a bad scene is skipped, the others convert), and stops at the first error with ``strict``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from abc import ABC, abstractmethod
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from tqdm import tqdm

from avdata.errors import AvdataError
from avdata.schema import DatasetWriter


@dataclass(frozen=True, slots=True, kw_only=True)
class ConvertConfig:
    """Options common to every converter.

    Attributes:
        src: the source dataset folder, in its published layout.
        dst: the unified dataset folder to write.
        strict: stop at the first error instead of skipping the bad frame or scene.
        workers: scenes converted in parallel processes.
        quiet: no progress bars.
        compression: MCAP chunk compression, "none" | "zstd" | "lz4".
        scenes: convert only these scenes (all when empty).
        options: converter-specific options (e.g. ``version`` for nuScenes).
    """

    src: Path
    dst: Path
    strict: bool = False
    workers: int = 1
    quiet: bool = False
    compression: str = "none"
    scenes: tuple[str, ...] = ()
    options: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, slots=True, kw_only=True)
class Problem:
    """One thing wrong with the input: where (file, and line or field) and what."""

    severity: str
    scene: str
    file: str
    message: str

    def __str__(self) -> str:
        return f"{self.severity}: {self.scene}: {self.file}: {self.message}"


class StrictError(AvdataError):
    """Raised in strict mode at the first error."""


class Report:
    """Collects the warnings and errors of one scene's conversion."""

    def __init__(self, scene: str, strict: bool):
        self.scene = scene
        self.strict = strict
        self.problems: list[Problem] = []

    def warn(self, file: str | Path, message: str) -> None:
        """Something missing or odd that does not stop the scene (e.g. a missing sensor file)."""
        self.problems.append(Problem(severity="warning", scene=self.scene, file=str(file), message=message))

    def error(self, file: str | Path, message: str) -> None:
        """Bad input: the frame is skipped; in strict mode the conversion stops here."""
        problem = Problem(severity="error", scene=self.scene, file=str(file), message=message)
        if self.strict:
            raise StrictError(str(problem))
        self.problems.append(problem)


class Converter(ABC):
    """Base of every converter. Subclasses set the class attributes and implement two methods.

    Attributes:
        name: the command-line name, e.g. "kitti-object".
        source: the source dataset's name written into the manifest.
        licence: the source data's licence.
    """

    name: ClassVar[str]
    source: ClassVar[str]
    licence: ClassVar[str] = ""

    def __init__(self, config: ConvertConfig):
        self.config = config

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:  # noqa: B027 - an optional hook
        """Adds converter-specific command-line options (stored in ``ConvertConfig.options``); none by default."""
        del parser

    def source_version(self) -> str:
        """The source's version string for the manifest."""
        return ""

    def release(self) -> None:  # noqa: B027 - an optional hook
        """Drops what the converter cached about its source (parsed tables), before the index is built."""

    @abstractmethod
    def list_scenes(self) -> list[str]:
        """Every scene name in the source, in a stable order; raises InputError if SRC is unusable."""

    @abstractmethod
    def convert_scene(self, scene: str, writer: DatasetWriter, report: Report) -> None:
        """Converts one scene: ``with writer.scene(name, metadata) as scene_writer: ...``.

        Raise InputError for a problem that makes the whole scene unusable (the scene file is then
        not written); call ``report.error`` / ``report.warn`` for per-frame problems and go on.
        """


#: name -> "module:Class"; imported only when asked for, so ``avdata --help`` stays fast.
CONVERTERS: dict[str, str] = {
    "kitti-object": "avdata.converters.kitti:KittiObjectConverter",
    "kitti-tracking": "avdata.converters.kitti:KittiTrackingConverter",
    "kitti-raw": "avdata.converters.kitti:KittiRawConverter",
    "nuscenes": "avdata.converters.nuscenes:NuScenesConverter",
    "argoverse2": "avdata.converters.argoverse2:Argoverse2Converter",
    "waymo": "avdata.converters.waymo:WaymoConverter",
}


def converter_class(name: str) -> type[Converter]:
    """The converter class registered under ``name``."""
    if name not in CONVERTERS:
        raise AvdataError(f"expected a converter of {sorted(CONVERTERS)}, got {name!r}")
    module_name, class_name = CONVERTERS[name].split(":")
    return getattr(importlib.import_module(module_name), class_name)


@dataclass(frozen=True, slots=True, kw_only=True)
class ConversionResult:
    """What a conversion did: scenes written, skipped as complete, failed; and every problem."""

    written: list[str]
    skipped: list[str]
    failed: list[str]
    problems: list[Problem]

    @property
    def n_errors(self) -> int:
        return sum(p.severity == "error" for p in self.problems)


def _convert_one(converter: Converter, writer: DatasetWriter, scene: str) -> tuple[str, list[Problem], bool]:
    report = Report(scene, converter.config.strict)
    try:
        converter.convert_scene(scene, writer, report)
    except StrictError:
        raise
    except AvdataError as error:
        if converter.config.strict:
            raise
        report.problems.append(Problem(severity="error", scene=scene, file=str(converter.config.src), message=str(error)))
        return scene, report.problems, False
    return scene, report.problems, True


def run_conversion(converter: Converter) -> ConversionResult:
    """Converts every (selected) scene not yet complete, then builds the index and manifest."""
    config = converter.config
    scenes = converter.list_scenes()
    if config.scenes:
        unknown = sorted(set(config.scenes) - set(scenes))
        if unknown:
            raise AvdataError(f"{config.src}: expected scenes among {scenes[:10]}..., got unknown {unknown}")
        scenes = [s for s in scenes if s in set(config.scenes)]
    writer = DatasetWriter(
        config.dst,
        source=converter.source,
        source_version=converter.source_version(),
        licence=converter.licence,
        compression=config.compression,
    )
    written: list[str] = []
    failed: list[str] = []
    problems: list[Problem] = []
    with writer:
        todo = [s for s in scenes if not writer.is_complete(s)]
        skipped = [s for s in scenes if s not in set(todo)]
        progress = tqdm(total=len(todo), desc=f"convert {converter.name}", unit="scene",
                        disable=config.quiet or not sys.stderr.isatty())
        if config.workers > 1 and len(todo) > 1:
            with ProcessPoolExecutor(max_workers=config.workers) as pool:
                futures = [pool.submit(_convert_one, converter, writer, s) for s in todo]
                outcomes = []
                for future in futures:
                    outcomes.append(future.result())
                    progress.update()
        else:
            outcomes = []
            for scene in todo:
                outcomes.append(_convert_one(converter, writer, scene))
                progress.update()
        progress.close()
        for scene, scene_problems, ok in outcomes:
            problems.extend(scene_problems)
            (written if ok else failed).append(scene)
        # The index is built when the writer's block ends; the source's tables are not needed for it.
        converter.release()
    return ConversionResult(written=written, skipped=skipped, failed=failed, problems=problems)
