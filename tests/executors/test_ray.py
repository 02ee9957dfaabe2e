"""``--executor ray`` on a real local Ray instance: byte-identical to local, retries a killed worker,
reports a bad scene and writes the others, checks that workers see SRC. Real KITTI files throughout."""

from __future__ import annotations

import contextlib
import os
import signal
from pathlib import Path

import pytest

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.base import StrictError
from avdata.converters.kitti import KittiObjectConverter
from avdata.errors import InputError
from avdata.generators.config import scenario_from_dict
from avdata.generators.driver import generate_scenes
from avdata.schema import DatasetReader
from avdata.schema.validate import validate_dataset
from tests.realdata import REALDATA

ray = pytest.importorskip("ray")

ROOT = Path(__file__).resolve().parents[2]
REAL = REALDATA / "kitti" / "object"
FOLDERS = {"calib": ".txt", "label_2": ".txt", "velodyne": ".bin", "image_2": ".png"}
SMALL = {
    "scenes": 2,
    "frames": 2,
    "seed": 5,
    "town": {"grid": [2, 2], "block_pitch_m": 70},
    "traffic": {"vehicles": 6, "pedestrians": 4, "warmup_s": 2.0},
    "egos": [{"name": "ego", "sensors": [
        {"name": "lidar_top", "kind": "lidar", "mount_xyz_m": [0, 0, 1.73],
         "lidar": {"model": "vlp32c", "azimuth_steps": 360, "max_range_m": 50}},
        {"name": "cam_front", "kind": "camera", "mount_xyz_m": [2.0, 0, 1.65],
         "camera": {"width": 160, "height": 80, "horizontal_fov_deg": 81}}]}],
    "infrastructure": {"count": 1, "sensors": [{"name": "lidar", "kind": "lidar", "lidar": {
        "model": "vlp32c", "azimuth_steps": 256, "horizontal_fov_deg": 180, "max_range_m": 60}}]},
}


pytestmark = pytest.mark.usefixtures("local_ray")


def dataset_files(root: Path) -> dict[str, bytes]:
    """Every file of a dataset but the lock (which holds the writer's PID)."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.name != ".avdata.lock"}


def convert(src: Path, dst: Path, executor: str, cls: type = KittiObjectConverter, **options):
    return run_conversion(cls(ConvertConfig(src=src, dst=dst, quiet=True, executor=executor,
                                            options={"scene_size": 1, **options})))


class KillsItsWorkerOnce(KittiObjectConverter):
    """KITTI object, but the first attempt at scene training_000001 SIGKILLs its own worker process."""

    def convert_scene(self, scene, writer, report):
        marker = Path(self.config.dst).parent / "killed-once"
        if scene == "training_000001" and not marker.exists():
            marker.write_text(str(os.getpid()))
            os.kill(os.getpid(), signal.SIGKILL)
        super().convert_scene(scene, writer, report)


def test_kitti_object_on_ray_is_byte_identical_to_local(tmp_path: Path) -> None:
    on_ray = convert(REAL, tmp_path / "ray", "ray")
    local = convert(REAL, tmp_path / "local", "local")
    assert on_ray.written == local.written == ["training_000000", "training_000001", "training_000002"]
    assert dataset_files(tmp_path / "ray") == dataset_files(tmp_path / "local")
    assert validate_dataset(tmp_path / "ray") == []
    assert convert(REAL, tmp_path / "ray", "ray").complete == on_ray.written  # resume on Ray too


def test_generate_two_scenes_on_ray_is_byte_identical_to_local(tmp_path: Path) -> None:
    config = scenario_from_dict(SMALL, "test")
    on_ray = generate_scenes(config, tmp_path / "ray", executor="ray", quiet=True)
    local = generate_scenes(config, tmp_path / "local", workers=2, quiet=True)
    assert on_ray.written == local.written == ["scene_000005_0000", "scene_000005_0001"]
    assert dataset_files(tmp_path / "ray") == dataset_files(tmp_path / "local")
    assert validate_dataset(tmp_path / "ray") == []


def test_a_killed_worker_is_retried_and_the_run_completes(tmp_path: Path) -> None:
    result = convert(REAL, tmp_path / "out", "ray", cls=KillsItsWorkerOnce)
    assert (tmp_path / "killed-once").exists()  # the worker really died mid-run
    assert result.written == ["training_000000", "training_000001", "training_000002"] and not result.failed
    assert validate_dataset(tmp_path / "out") == []
    convert(REAL, tmp_path / "local", "local")
    assert dataset_files(tmp_path / "out") == dataset_files(tmp_path / "local")


def layout_without_calib_1(src: Path) -> Path:
    for folder, suffix in FOLDERS.items():
        (src / "training" / folder).mkdir(parents=True)
        for sample in ("000000", "000001", "000002"):
            if (folder, sample) != ("calib", "000001"):
                (src / "training" / folder / f"{sample}{suffix}").symlink_to(REAL / "training" / folder / f"{sample}{suffix}")
    return src


def test_a_bad_scene_is_reported_and_the_others_written(tmp_path: Path) -> None:
    src = layout_without_calib_1(tmp_path / "src")
    result = convert(src, tmp_path / "out", "ray")
    assert result.failed == ["training_000001"] and result.written == ["training_000000", "training_000002"]
    assert any("calib/000001.txt" in p.file for p in result.problems)
    log = (tmp_path / "out" / "errors.jsonl").read_text()
    assert "training_000001" in log and "no readable sample" in log
    assert DatasetReader(tmp_path / "out").scenes == ["training_000000", "training_000002"]


def test_workers_must_see_src(tmp_path: Path) -> None:
    from avdata.executors.base import RayExecutor

    with RayExecutor() as executor:
        executor.check_visible([REAL])
        with pytest.raises(InputError, match="cannot see .*/nowhere; SRC and DST must be on a filesystem every node"):
            executor.check_visible([REAL, tmp_path / "nowhere"])


def test_strict_on_ray_raises_avdatas_own_one_line_error(tmp_path: Path) -> None:
    src = layout_without_calib_1(tmp_path / "src")
    with pytest.raises(StrictError) as caught:
        run_conversion(KittiObjectConverter(ConvertConfig(src=src, dst=tmp_path / "out", quiet=True, executor="ray",
                                                          strict=True, options={"scene_size": 1})))
    assert type(caught.value) is StrictError and "\n" not in str(caught.value)
    assert "calib/000001.txt" in str(caught.value)


def test_export_on_ray_is_byte_identical_to_local(tmp_path: Path) -> None:
    """Both export formats, and a scene with a damaged chunk (reported, the others written), as on the local pool."""
    from avdata.exporters.driver import ExportConfig
    from avdata.exporters.kitti import export_kitti_object
    from avdata.exporters.nuscenes import export_nuscenes
    from tests.exporters.export_files import export_files
    from tests.exporters.test_export_runs import damaged_copy

    convert(REAL, tmp_path / "unified", "local")
    damaged = damaged_copy(tmp_path / "unified", tmp_path / "damaged")
    for name, dataset, fn in (("kitti", tmp_path / "unified", export_kitti_object),
                              ("nusc", tmp_path / "unified", export_nuscenes),
                              ("damaged", damaged, export_kitti_object)):
        outputs = {}
        for executor in ("ray", "local"):
            out = tmp_path / f"{name}-{executor}"
            result = fn(dataset, out, config=ExportConfig(dataset=dataset, dst=out, executor=executor, workers=2))
            assert result.written == ["training_000000", "training_000001", "training_000002"]
            assert result.n_errors == (name == "damaged")
            outputs[executor] = export_files(out)
        assert outputs["ray"] == outputs["local"]
    assert "training_000001" in (tmp_path / "damaged-ray" / "errors.jsonl").read_text()


def _fails_once_the_other_started(task: tuple[Path, int]) -> None:
    """Task 0 fails once task 1 has started; task 1 marks its start, works 2 s and marks its end."""
    import time

    folder, i = task
    if i == 0:
        deadline = time.monotonic() + 60
        while not (folder / "started").exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        raise InputError("task 0 fails")
    (folder / "started").write_text("x")
    time.sleep(2.0)
    (folder / "finished").write_text("x")


def test_a_run_that_ends_early_lets_a_started_task_end_on_its_own(tmp_path: Path) -> None:
    """``ray.cancel`` raised KeyboardInterrupt at any line of a running task: a full disk once left a scene's
    ``.tmp`` file behind. Only tasks not yet started are dropped, as on the local pool."""
    from avdata.errors import AvdataError
    from avdata.executors.base import RayExecutor

    with RayExecutor() as executor, pytest.raises(AvdataError, match="^task 0 fails$"):
        executor.map(_fails_once_the_other_started, [(tmp_path, 0), (tmp_path, 1)])
    assert (tmp_path / "started").exists() and (tmp_path / "finished").exists()


def test_a_full_disk_on_ray_is_one_line_and_a_rerun_completes(small_disk, tmp_path: Path) -> None:
    from avdata.errors import DiskFullError
    from avdata.schema.dataset import is_complete_scene

    dst = small_disk.root / "ray"
    small_disk.fill(leave=4 << 20)  # one of the three ~2.7 MB scenes fits
    with pytest.raises(DiskFullError) as raised:
        convert(REAL, dst, "ray")
    message = str(raised.value)
    assert message.startswith(f"{dst}/scenes/training_0000") and "(No space left on device); the run stopped, keeping" in message
    assert not [p for p in dst.rglob("*") if p.name.endswith(".tmp")]
    assert all(is_complete_scene(p) for p in (dst / "scenes").glob("*.mcap"))
    small_disk.free()
    assert convert(REAL, dst, "ray").failed == []
    assert validate_dataset(dst) == []


def test_a_dead_check_task_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The pre-scan (which paths each node sees) was a traceback when its worker died."""
    from avdata.errors import AvdataError
    from avdata.executors.base import RayExecutor

    def worker_died(refs, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003 - ray.get's signature
        raise ray.exceptions.WorkerCrashedError()

    executor = RayExecutor()
    monkeypatch.setattr(ray, "get", worker_died)
    with pytest.raises(AvdataError, match=r"^Ray: the task that checks what the nodes see died 4 times "
                                          r"\(WorkerCrashedError\); nothing was written$"):
        executor.check_visible([tmp_path])


def test_a_failed_ray_start_is_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    """A Ray start-up whose raylet or GCS dies (here: ray.init raising what Ray raises then) was a traceback."""
    from avdata.errors import AvdataError
    from avdata.executors.base import RayExecutor
    from avdata.executors.reaper import ray_processes

    def init(**kwargs):  # noqa: ANN003
        raise TimeoutError("The raylet did not start within 30 s")

    module_ray = ray_processes(os.getpid(), os.path.dirname(ray.__file__))
    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", init)
    monkeypatch.setattr(ray, "shutdown", lambda: None)  # the module's instance stays up for the other tests
    with pytest.raises(AvdataError, match=r"^cannot start Ray here \(TimeoutError: The raylet did not start within 30 s\)$"):
        RayExecutor()
    # The executor's reaper looked below this process, where the module's Ray instance runs: it was not its to end
    # (it was, and the test process crashed a few tests later when its raylet's death was noticed).
    assert len(module_ray) >= 3 and _running(module_ray) == module_ray


#: A driver whose Ray task runs for minutes; it starts a child of its own first and marks the task's start.
SLOW_RAY_DRIVER = """
import subprocess, sys, time
from pathlib import Path
from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.kitti import KittiObjectConverter

class Slow(KittiObjectConverter):
    def convert_scene(self, scene, writer, report):
        Path(str(self.config.dst) + ".started").write_text("x")
        time.sleep(300)

Path(sys.argv[2] + ".child").write_text(str(subprocess.Popen(["sleep", "300"]).pid))
run_conversion(Slow(ConvertConfig(src=Path(sys.argv[1]), dst=Path(sys.argv[2]), quiet=True, executor="ray",
                                  options={"scene_size": 1})))
"""


def _running(processes: dict[int, int]) -> dict[int, int]:
    from avdata.executors.reaper import _running

    return {pid: start for pid, start in processes.items() if _running(pid, start)}


def test_no_ray_process_outlives_a_killed_driver_and_the_drivers_own_child_is_left_alone(tmp_path: Path) -> None:
    """``kill -9`` of a driver that started its own Ray: Ray's DashboardAgent and RuntimeEnvAgent stayed alive."""
    import json
    import subprocess
    import sys
    import time

    from avdata.executors.reaper import _stat, ray_processes

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    driver = subprocess.Popen([sys.executable, "-c", SLOW_RAY_DRIVER, str(REAL), str(tmp_path / "out")], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not (tmp_path / "out.started").exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        assert (tmp_path / "out.started").exists()
        ours = ray_processes(driver.pid, os.path.dirname(ray.__file__))
        assert len(ours) >= 4  # GCS, raylet, agents, the task's worker ...
        child = int((tmp_path / "out.child").read_text())
        child_stat = _stat(child)
        assert child_stat is not None and child not in ours
    finally:
        driver.kill()
        driver.wait()
    try:
        deadline = time.monotonic() + 60
        alive = ours
        while alive and time.monotonic() < deadline:
            time.sleep(1)
            alive = _running(ours)
        left = json.dumps({pid: Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace")[:80] for pid in alive})
        for pid in alive:  # leave nothing behind even when the test fails
            os.kill(pid, signal.SIGKILL)
        assert alive == {}, left
        assert _running({child: child_stat[2]}), "the reaper killed a process that is not Ray's"
    finally:
        with contextlib.suppress(ProcessLookupError):  # gone already: the assertion above says why
            os.kill(child, signal.SIGKILL)


#: A driver that runs tasks on its own Ray, one of which leaves a child in a session of its own, closes the
#: executor and prints which of Ray's processes still run.
CLOSING_RAY_DRIVER = """
import json, os, sys
import ray
from avdata.executors.base import RayExecutor
from avdata.executors.reaper import _running, _stat, ray_processes

def spawn(own_session):
    import subprocess
    return subprocess.Popen(["sleep", "300"], start_new_session=own_session).pid

executor = RayExecutor(num_cpus=1)
children = executor.map(spawn, [False, True])
ours = ray_processes(os.getpid(), os.path.dirname(ray.__file__))
starts = {pid: _stat(pid)[2] for pid in children}
executor.close()
print(json.dumps({"ray": len(ours), "children_noted": all(pid in ours for pid in children),
                  "running": [pid for pid, start in {**ours, **starts}.items() if _running(pid, start)]}))
"""


def test_close_returns_when_rays_processes_have_ended(tmp_path: Path) -> None:
    """A task's child in a session of its own outlived ``ray.shutdown()`` for good; on a loaded machine one of
    Ray's own processes outlived an interrupted driver by 0.5 s."""
    import json
    import subprocess
    import sys

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    result = subprocess.run([sys.executable, "-c", CLOSING_RAY_DRIVER], env=env, capture_output=True, text=True,
                            timeout=300, check=True)
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["ray"] >= 4 and report["children_noted"]
    for pid in report["running"]:  # leave nothing behind even when the test fails
        os.kill(pid, signal.SIGKILL)
    assert report["running"] == []
