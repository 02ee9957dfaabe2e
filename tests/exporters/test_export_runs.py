"""``avdata export`` as one task per scene: byte-identical to the single-process export it replaced, the same
with any number of workers, a damaged scene costs its own samples only, honest resume after a kill, and no
stale file of an earlier export survives. Real KITTI files (converted), the demo and a generated V2I scene."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from avdata.cli import main
from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.kitti import KittiObjectConverter
from avdata.demo import write_demo
from avdata.errors import InputError
from avdata.exporters.kitti import export_kitti_object
from avdata.exporters.nuscenes import export_nuscenes
from tests.exporters.export_files import export_digest, export_files
from tests.realdata import REALDATA

ROOT = Path(__file__).resolve().parents[2]
REAL = REALDATA / "kitti" / "object"
SCENES = ["training_000000", "training_000001", "training_000002"]

#: export_digest of what the exporters write for these datasets, pinned from the single-process exporters: a run
#: through the executor must write the same bytes. The generated_v2i pair is of the generator's fixture scene, whose
#: bytes do not depend on the CPU (avdata.portable_math, docs/determinism.md: the same digests with numpy's AVX-512
#: and AVX2 loops turned off, which is how CI runs this file a second time). The nuScenes exports name channels as
#: nuScenes does (kitti3: VELODYNE -> LIDAR_TOP, CAM2 -> CAM_FRONT) and write their channel mapping
#: (avdata_channels.json).
SINGLE_PROCESS_DIGESTS = {
    ("demo", "kitti-object"): "2afa153913aeaceb86ac80f1bbd7428d71e61cdcc37669121544cc0fa14c0138",
    ("demo", "nuscenes"): "537f373ae36d69893b3566929fbf7c9eb2deb22222eca412b20564671cf2222a",
    ("kitti3", "kitti-object"): "6a33cad1e4022ccf29d4797eb2e343ce37b19c4a9a46d947c08ea2ba14d95248",
    ("kitti3", "nuscenes"): "0401f7898251d6724ad6eb4e36f198137f8159c0c255cc225b83f16eac3ddb98",
    ("generated_v2i", "kitti-object"): "2f77f68b6e5e75b7c940758277b9041bcf6518ac6f8eb0b51823fe09af50ed17",
    ("generated_v2i", "nuscenes"): "1c5785fbb7ad89e17acdedae36951b583b99ae05d98e33f6961d3f7fd06cd859",
}


@pytest.fixture(scope="module")
def kitti3(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The real KITTI object samples converted one scene per sample (three scenes)."""
    root = tmp_path_factory.mktemp("kitti3") / "unified"
    run_conversion(KittiObjectConverter(ConvertConfig(src=REAL, dst=root, quiet=True, options={"scene_size": 1})))
    return root


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_demo(tmp_path_factory.mktemp("demo") / "demo")


def export(fmt: str, dataset: Path, dst: Path, *options: str) -> int:
    return main(["export", fmt, str(dataset), str(dst), "--quiet", *options])


@pytest.mark.parametrize("fmt", ["kitti-object", "nuscenes"])
@pytest.mark.parametrize("name", ["demo", "kitti3", "generated_v2i"])
def test_export_is_byte_identical_to_the_single_process_export(name: str, fmt: str, request: pytest.FixtureRequest,
                                                               tmp_path: Path) -> None:
    dataset = request.getfixturevalue(name)
    assert export(fmt, dataset, tmp_path / "out") == 0
    assert export_digest(tmp_path / "out", dataset) == SINGLE_PROCESS_DIGESTS[(name, fmt)]


@pytest.mark.parametrize("fmt", ["kitti-object", "nuscenes"])
def test_two_workers_write_the_same_files_as_one(fmt: str, kitti3: Path, tmp_path: Path) -> None:
    assert export(fmt, kitti3, tmp_path / "one", "--workers", "1") == 0
    assert export(fmt, kitti3, tmp_path / "two", "--workers", "2") == 0
    assert export_files(tmp_path / "two") == export_files(tmp_path / "one")
    assert sorted(p.name for p in (tmp_path / "two" / ".avdata-export").iterdir()) == ["export.json", "scenes"]
    assert sorted(p.name for p in (tmp_path / "two" / ".avdata-export" / "scenes").iterdir()) == [f"{s}.json" for s in SCENES]


def damaged_copy(kitti3: Path, root: Path) -> Path:
    """kitti3 with one bit flipped inside the point cloud of scene training_000001 (a chunk's CRC no longer matches)."""
    import shutil

    shutil.copytree(kitti3, root)
    scene = root / "scenes" / "training_000001.mcap"
    data = bytearray(scene.read_bytes())
    position = data.find((REAL / "training" / "velodyne" / "000001.bin").read_bytes()[:64])
    assert position > 0
    data[position + 1000] ^= 0x10
    scene.write_bytes(bytes(data))
    return root


def test_a_damaged_chunk_costs_its_own_sample_and_the_other_scenes_are_written(kitti3: Path, tmp_path: Path,
                                                                             capsys: pytest.CaptureFixture) -> None:
    dataset = damaged_copy(kitti3, tmp_path / "damaged")
    out = tmp_path / "kitti"
    assert export("kitti-object", dataset, out) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "Traceback" not in err[0]
    assert err[0].startswith(f"error: training_000001: {dataset}/scenes/training_000001.mcap: frame 0 "
                             f"(sample training/000001) not written: byte ")
    assert "chunk CRC mismatch" in err[0] and err[0].count(str(dataset)) == 1
    log = [json.loads(line) for line in (out / "errors.jsonl").read_text().splitlines()]
    assert [(e["scene"], e["severity"]) for e in log] == [("training_000001", "error")]
    assert (out / "ImageSets" / "train.txt").read_text().split() == ["000000", "000002"]
    assert sorted(p.name for p in (out / "training" / "velodyne").iterdir()) == ["000000.bin", "000002.bin"]
    for sample in ("000000", "000002"):  # the others are the clean export's bytes
        assert (out / "training" / "velodyne" / f"{sample}.bin").read_bytes() == \
            (REAL / "training" / "velodyne" / f"{sample}.bin").read_bytes()
    # A rerun does not take the scene with an error for complete: it tries it again (and reports it again).
    assert export("kitti-object", dataset, out) == 1
    assert "training_000001" in capsys.readouterr().err

    nusc = tmp_path / "nusc"
    assert export("nuscenes", dataset, nusc) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: training_000001: {dataset}/scenes/training_000001.mcap: byte ")
    scenes = [r["name"] for r in json.loads((nusc / "v1.0-avdata" / "scene.json").read_text())]
    assert scenes == ["training_000000", "training_000002"]
    files = {r["filename"] for r in json.loads((nusc / "v1.0-avdata" / "sample_data.json").read_text())}
    assert {p.relative_to(nusc).as_posix() for p in (nusc / "samples").rglob("*") if p.is_file()} == files
    assert len(files) == 4 and not any("training_000001" in f for f in files)


KILL_AFTER_TWO_SCENES = """
import os, signal, sys
import avdata.exporters.{module} as exporter
from avdata.cli import main

recorded = []
record = exporter.record


def record_then_die(job, outcome, files):
    result = record(job, outcome, files)
    recorded.append(job.scene)
    if len(recorded) == 2:
        os.kill(os.getpid(), signal.SIGKILL)
    return result


exporter.record = record_then_die
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize(("fmt", "module"), [("kitti-object", "kitti"), ("nuscenes", "nuscenes")])
def test_a_rerun_after_a_kill_redoes_only_the_missing_scene(fmt: str, module: str, kitti3: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-c", KILL_AFTER_TWO_SCENES.format(module=module), "export", fmt,
                           str(kitti3), str(out), "--quiet"], env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == -9, proc.stderr
    # The run state claims the folder before any scene (so the rerun is taken as the same export), no more.
    assert sorted(p.name for p in (out / ".avdata-export").iterdir()) == ["export.json", "scenes"]
    assert sorted(p.name for p in (out / ".avdata-export" / "scenes").iterdir()) == [f"{s}.json" for s in SCENES[:2]]
    result = (export_kitti_object if fmt == "kitti-object" else export_nuscenes)(kitti3, out)
    assert (result.complete, result.written) == (SCENES[:2], SCENES[2:])
    assert export(fmt, kitti3, tmp_path / "clean") == 0
    assert export_files(out) == export_files(tmp_path / "clean")


def test_resume_is_honest(kitti3: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    assert export_kitti_object(kitti3, out).written == SCENES
    assert export_kitti_object(kitti3, out).complete == SCENES
    # Another option: every scene is redone.
    assert export_kitti_object(kitti3, out, camera="ego/cam3").written == SCENES
    assert export_kitti_object(kitti3, out).written == SCENES
    # A changed scene file, a removed or changed output file: that scene is redone, the others are not.
    scene = kitti3 / "scenes" / "training_000001.mcap"
    stat = scene.stat()
    os.utime(scene, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1))
    (out / "training" / "label_2" / "000002.txt").unlink()
    result = export_kitti_object(kitti3, out)
    assert (result.complete, result.written) == (SCENES[:1], SCENES[1:])
    (out / "training" / "calib" / "000000.txt").write_text("edited\n")
    assert export_kitti_object(kitti3, out).written == SCENES[:1]
    assert export_kitti_object(kitti3, out).complete == SCENES
    assert main(["export", "kitti-object", str(kitti3), str(out), "--quiet", "--force"]) == 0
    assert export_files(out) == export_files(_clean(kitti3, tmp_path / "clean"))


def _clean(dataset: Path, out: Path) -> Path:
    export_kitti_object(dataset, out)
    return out


def test_no_stale_file_of_an_earlier_export_survives(kitti3: Path, tmp_path: Path) -> None:
    out = tmp_path / "kitti"
    export_kitti_object(kitti3, out)
    (out / "training" / "velodyne" / ".000000.bin.4242.tmp").write_bytes(b"left by a killed run")
    result = export_kitti_object(kitti3, out, scenes=["training_000001"])
    # Numbered from 0 again: training_000001 is redone as sample 000000, the others' samples are gone.
    assert (result.written, result.training) == (["training_000001"], 1)
    assert export_files(out) == export_files(_export_one(kitti3, tmp_path / "only-1"))
    assert [p.name for p in (out / ".avdata-export" / "scenes").iterdir()] == ["training_000001.json"]

    nusc = tmp_path / "nusc"
    export_nuscenes(kitti3, nusc, version="v1.0-old")
    result = export_nuscenes(kitti3, nusc, scenes=["training_000002"])
    assert (result.complete, result.scenes) == (["training_000002"], 1)
    clean = tmp_path / "nusc-clean"
    export_nuscenes(kitti3, clean, scenes=["training_000002"])
    assert export_files(nusc) == export_files(clean)  # no v1.0-old/, no sample file of the other scenes


def _export_one(dataset: Path, out: Path) -> Path:
    export_kitti_object(dataset, out, scenes=["training_000001"])
    return out


def test_bad_options_and_folders_are_one_line_errors(kitti3: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    export_kitti_object(kitti3, tmp_path / "out")
    assert export("kitti-object", kitti3, tmp_path / "out", "--camera", "ego/nowhere") == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 3 and all("expected a camera among" in line and "got 'ego/nowhere'" in line for line in err)
    assert not any("velodyne" in line for line in err)  # the cameras are listed, not every sensor
    # Nothing of the earlier good export passes for this one's.
    assert not list((tmp_path / "out" / ".avdata-export" / "scenes").iterdir())
    assert not [p for p in (tmp_path / "out" / "training").rglob("*") if p.is_file()]
    assert (tmp_path / "out" / "ImageSets" / "train.txt").read_text() == ""
    assert export("nuscenes", kitti3, tmp_path / "out") == 1
    assert capsys.readouterr().err.strip() == (f"avdata: error: {tmp_path / 'out'}: expected an empty folder or a "
                                               f"nuscenes export, got a kitti-object export (write into another folder)")
    assert export("kitti-object", kitti3, tmp_path / "other", "--scenes", "nope") == 1
    assert "expected scenes of the dataset, got unknown ['nope']" in capsys.readouterr().err
    assert export("nuscenes", kitti3, kitti3) == 1
    assert "expected an output outside DATASET, got DATASET itself" in capsys.readouterr().err
    # Under the dataset's folder too (it was written there), refused before DST is created.
    assert export("kitti-object", kitti3, kitti3 / "scenes" / "kitti") == 1
    assert capsys.readouterr().err == (f"avdata: error: {kitti3 / 'scenes' / 'kitti'}: expected an output outside "
                                       f"DATASET, got a path inside DATASET {kitti3}\n")
    assert not (kitti3 / "scenes" / "kitti").exists()
    with pytest.raises(InputError, match="dataset folder does not exist"):
        export_kitti_object(tmp_path / "missing", tmp_path / "never")
    assert not (tmp_path / "never").exists()


@pytest.mark.parametrize("fmt", ["kitti-object", "nuscenes"])
def test_a_folder_where_an_output_file_goes_costs_that_file_only(fmt: str, demo: Path, tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    # Was an IsADirectoryError traceback from the rename, then another from removing the failed sample's files.
    dst = tmp_path / "out"
    assert export(fmt, demo, dst) == 0
    prefix = "training/label_2/" if fmt == "kitti-object" else "samples/"
    target = dst / next(name for name in export_files(dst) if name.startswith(prefix))
    target.unlink()
    target.mkdir()
    capsys.readouterr()
    assert export(fmt, demo, dst, "--force") == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.count("\n") == 1
    assert f"{target}: cannot write this file (Is a directory)" in err
    assert target.is_dir() and not list(target.iterdir())  # the user's folder is left as it was
