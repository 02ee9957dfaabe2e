"""What every scene-per-task job shares: per-scene outcomes and problems, the task loop, ``errors.jsonl``."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from avdata.errors import AvdataError, one_line
from avdata.executors.base import Executor, TaskFailure
from avdata.outputs import write_atomically
from avdata.progress import Progress
from avdata.schema import scene_path

#: Per-scene problems of the dataset, one JSON object per line (scene, severity, file, message).
ERROR_LOG = "errors.jsonl"

#: A scene task's outcomes: written by this run, complete from an earlier run (left as it is), failed.
WRITTEN, COMPLETE, FAILED = "written", "complete", "failed"
OUTCOMES = (WRITTEN, COMPLETE, FAILED)


@dataclass(frozen=True, slots=True, kw_only=True)
class Problem:
    """One thing wrong with the input: where (file, and line or field) and what."""

    severity: str
    scene: str
    file: str
    message: str

    def __str__(self) -> str:
        return f"{self.severity}: {self.scene}: {self.file}: {one_line(self.message)}"


@dataclass(frozen=True, slots=True, kw_only=True)
class SceneOutcome:
    """What one scene task did: ``status`` one of :data:`OUTCOMES`, and its problems.

    ``data`` is what the task hands to the run's finishing step (export: the scene's samples or table
    rows); None for tasks whose scene file is the whole result (convert, generate).
    """

    scene: str
    status: str
    problems: list[Problem]
    data: Any = None


def run_scene_tasks(fn: Callable[[Any], SceneOutcome], tasks: Sequence[Any], scenes: Sequence[str],
                    executor: Executor, desc: str, quiet: bool) -> list[SceneOutcome]:
    """Runs one task per scene on ``executor`` with progress (a bar, or a line per scene); outcomes in scene order."""
    with Progress(len(tasks), desc, "scene", quiet) as progress:
        results = executor.map(fn, tasks, on_done=lambda i, _r: progress.update(scenes[i]))
    return [
        SceneOutcome(scene=scene, status=FAILED,
                     problems=[Problem(severity="error", scene=scene, file="", message=result.message)])
        if isinstance(result, TaskFailure) else result
        for scene, result in zip(scenes, results, strict=True)
    ]


def write_error_log(root: Path, outcomes: Sequence[SceneOutcome],
                    exists: Callable[[Any], bool] | None = None) -> None:
    """Writes ``root/errors.jsonl``: one JSON line per problem of every scene in the dataset.

    Problems of scenes this run wrote or failed replace the earlier ones; those of scenes it skipped as
    complete (warnings only) and of scenes it did not touch (``--scenes``) are kept while the scene
    still exists: ``exists(scene)``, by default whether its scene file does. No problems: no file.
    """
    exists = exists or (lambda scene: scene_path_exists(root, scene))
    path = Path(root) / ERROR_LOG
    ran = {o.scene for o in outcomes if o.status != COMPLETE}
    kept: list[dict[str, Any]] = []
    if path.is_file():
        for line in path.read_text(errors="replace").splitlines():
            try:
                entry = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(entry, dict) and entry.get("scene") not in ran and exists(entry.get("scene")):
                kept.append(entry)
    entries = [asdict(p) for o in outcomes if o.status != COMPLETE for p in o.problems]
    order = {o.scene: i for i, o in enumerate(outcomes)}
    entries = sorted(kept + entries, key=lambda e: (order.get(e["scene"], len(order)), str(e["scene"])))
    if not entries:
        path.unlink(missing_ok=True)
        return
    write_atomically(path, "".join(json.dumps(e, sort_keys=True) + "\n" for e in entries))


def scene_path_exists(root: Path, scene: Any) -> bool:
    """Whether ``scene`` names a scene file that exists under ``root`` (False for a bad name)."""
    try:
        return isinstance(scene, str) and scene_path(Path(root), scene).is_file()
    except AvdataError:
        return False
