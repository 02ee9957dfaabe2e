"""``generate`` as scene tasks: one task per scene on an executor, under the dataset lock, with honest resume.

A scene's resume fingerprint is the whole scenario (as the scene metadata records it), the scene's
index and the generator's version; the same seed gives the same bytes on any executor, so a scene
whose fingerprint matches is skipped and any change (``--frames``, ``--seed``, a YAML edit) rewrites it.
Scenes of an earlier run that this scenario does not produce (fewer ``--scenes``) are removed.
"""

from __future__ import annotations

from pathlib import Path

from avdata.errors import AvdataError
from avdata.executors import resume_fingerprint
from avdata.executors.folder import scene_task_writer
from avdata.executors.pipeline import EngineConfig, SceneRunResult, run_result, scene_run
from avdata.executors.scenes import COMPLETE, FAILED, WRITTEN, Problem, SceneOutcome
from avdata.generators.config import ScenarioConfig
from avdata.outputs import name_full_disk
from avdata.schema import DatasetWriter, scene_path
from avdata.schema.dataset import dataset_root
from avdata.storage import Location


def _generate_task(task: tuple[ScenarioConfig, int, DatasetWriter, Path | Location, bool, bool]) -> SceneOutcome:
    from avdata.generators.scenario import GENERATOR_VERSION, scene_name, write_scene

    config, scene_index, writer, dst, force, frame_progress = task
    fingerprint = resume_fingerprint("generate", {"scenario": config.to_dict(), "scene_index": scene_index,
                                                  "generator_version": GENERATOR_VERSION})
    name = scene_name(config, scene_index)
    scene_file = scene_path(writer.root, name)
    try:
        with scene_task_writer(writer, fingerprint, dst, force=force) as scene_writer:
            scene_file = scene_path(scene_writer.root, name)
            write_scene(config, scene_index, scene_writer, frame_progress)
    except OSError as error:  # a full disk stops the run (avdata.executors.lock), naming the scene file
        raise name_full_disk(error, scene_file) from None
    except AvdataError as error:
        return SceneOutcome(scene=name, status=FAILED,
                            problems=[Problem(severity="error", scene=name, file="", message=str(error))])
    return SceneOutcome(scene=name, status=COMPLETE if name in scene_writer.found_complete else WRITTEN, problems=[])


def generate_scenes(config: ScenarioConfig, dst: str | Path | Location, *, executor: str = "local", workers: int = 1,
                    ray_address: str | None = None, force: bool = False, quiet: bool = False) -> SceneRunResult:
    """Generates every scene of ``config`` into the dataset folder ``dst`` (see the module docstring).

    Args:
        config: the scenario.
        dst: the dataset folder (created), or its prefix in an object store (``s3://...``, ``gs://...``): each scene
            is then published whole, the index and manifest last (:mod:`avdata.executors.folder`).
        executor: "local" (``workers`` processes) or "ray" (``ray_address``, or a local Ray instance).
        workers: processes of the local executor.
        ray_address: the Ray cluster to join.
        force: rewrite every scene.
        quiet: no progress bar.
    """
    dst = dataset_root(dst)
    engine = EngineConfig(executor=executor, workers=workers, ray_address=ray_address, quiet=quiet)
    with scene_run(dst, engine, [dst]) as run:
        # Imported only now: pybullet prints a banner on import, which should not precede a DST or Ray error.
        from avdata.generators.scenario import GENERATOR_VERSION, scene_name

        names = [scene_name(config, k) for k in range(config.scenes)]
        writer = DatasetWriter(run.root, source="avdata-generator", source_version=GENERATOR_VERSION,
                               licence="CC0-1.0 (simulated)", description="simulated V2I scenes (avdata.generators)",
                               scene_files=run.scene_files())
        with writer:
            removed = run.clean(names)
            # A per-frame bar only in this process: bars of parallel workers would overwrite each other.
            frame_progress = not quiet and executor == "local" and workers <= 1
            tasks = [(config, k, writer, dst, force, frame_progress) for k in range(config.scenes)]
            outcomes = run.run(_generate_task, tasks, names, "generate")
            run.log(outcomes)
        run.publish()
    return run_result(outcomes, removed)


def generate(config: ScenarioConfig, dst: str | Path, workers: int = 1, progress: bool = True) -> list[str]:
    """Generates every scene of a scenario into the dataset folder ``dst``, on the local executor.

    The same run as ``avdata generate`` (:func:`generate_scenes`: dataset lock, honest resume, stale scenes
    removed), for library callers that want the scene names or an error.

    Args:
        config: the scenario.
        dst: dataset folder (created; scenes already written by the same scenario are skipped).
        workers: processes generating scenes in parallel.
        progress: a progress bar on a terminal.

    Returns:
        The scene names.

    Raises:
        AvdataError: a scene failed (the others are written).
    """
    from avdata.generators.scenario import scene_name

    result = generate_scenes(config, dst, workers=workers, quiet=not progress)
    if result.failed:
        raise AvdataError(str(result.problems[0]))
    return [scene_name(config, k) for k in range(config.scenes)]
