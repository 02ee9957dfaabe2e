"""``--executor ray`` on a real local Ray instance: byte-identical to local, retries a killed worker,
reports a bad scene and writes the others, checks that workers see SRC. Real KITTI files throughout."""

from __future__ import annotations

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


@pytest.fixture(scope="module", autouse=True)
def local_ray():
    # Workers import this tree (and this module, for the converter below) like the test process does.
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False,
             runtime_env={"env_vars": {"PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}})
    yield
    ray.shutdown()


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
    assert convert(REAL, tmp_path / "ray", "ray").skipped == on_ray.written  # resume on Ray too


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
