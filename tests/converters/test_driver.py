"""The converter driver's trust promises on real KITTI files: honest resume, one writer, errors.jsonl.

Layouts are the real samples of ``../shared/realdata/kitti/object`` symlinked into a temporary
folder, with one file replaced per case.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.kitti import KittiObjectConverter
from avdata.errors import AvdataError, InputError
from avdata.executors import dataset_lock
from avdata.executors.resume import HASH_MAX_BYTES
from avdata.schema import DatasetReader, SceneReader
from avdata.schema.validate import validate_dataset
from tests.realdata import REALDATA

REAL = REALDATA / "kitti" / "object"
FOLDERS = {"calib": ".txt", "label_2": ".txt", "velodyne": ".bin", "image_2": ".png"}
ROOT = Path(__file__).resolve().parents[2]


def object_layout(root: Path) -> Path:
    for folder, suffix in FOLDERS.items():
        (root / "training" / folder).mkdir(parents=True)
        for sample in ("000000", "000001", "000002"):
            (root / "training" / folder / f"{sample}{suffix}").symlink_to(REAL / "training" / folder / f"{sample}{suffix}")
    return root


def replace(root: Path, folder: str, name: str, data: bytes) -> Path:
    path = root / "training" / folder / name
    path.unlink()
    path.write_bytes(data)
    return path


def convert(src: Path, dst: Path, **kwargs):
    options = kwargs.pop("options", None)
    return run_conversion(KittiObjectConverter(ConvertConfig(src=src, dst=dst, quiet=True, options=options, **kwargs)))


def samples(dst: Path, scene: str = "training_000000") -> list[int]:
    return SceneReader(dst / "scenes" / f"{scene}.mcap").metadata["kitti_sample_ids"]


def objects_in(dst: Path, frame_index: int, scene: str = "training_000000") -> int:
    return len(SceneReader(dst / "scenes" / f"{scene}.mcap").labels(frame_index)[1].boxes)


def run_cli(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "avdata.cli", *args], capture_output=True, text=True, timeout=300, env=env)


def test_unchanged_rerun_skips_and_force_rewrites_byte_identical(tmp_path: Path) -> None:
    src, dst = object_layout(tmp_path / "src"), tmp_path / "out"
    first = convert(src, dst)
    assert (first.written, first.complete) == (["training_000000"], [])
    scene = dst / "scenes" / "training_000000.mcap"
    before = scene.read_bytes()
    recorded = SceneReader(scene).metadata["resume"]
    # five files per listed sample (calib, label_2, velodyne, image_2, image_3), missing ones included
    assert recorded["task"] == "kitti-object" and recorded["errors"] == 0 and recorded["n_sources"] == 3 * 5
    assert recorded["options"] == {"compression": "none", "decode_images": False, "scene_size": 100}
    again = convert(src, dst)
    assert (again.written, again.complete) == ([], ["training_000000"])
    forced = convert(src, dst, force=True)
    assert forced.written == ["training_000000"]
    assert scene.read_bytes() == before
    assert not (dst / "errors.jsonl").exists()


def test_rerun_after_fixing_a_bad_label_rewrites_the_scene(tmp_path: Path) -> None:
    src, dst = object_layout(tmp_path / "src"), tmp_path / "out"
    good = (REAL / "training" / "label_2" / "000001.txt").read_bytes()
    fields = good.split(b"\n")[0].split(b" ")
    fields[11] = b"nan"  # costs that object only: the sample and the scene are written without it
    replace(src, "label_2", "000001.txt", b" ".join(fields) + b"\n" + b"\n".join(good.split(b"\n")[1:]))
    broken = convert(src, dst)
    assert broken.n_errors >= 1 and samples(dst) == [0, 1, 2]
    n_broken = objects_in(dst, 1)
    assert SceneReader(dst / "scenes" / "training_000000.mcap").metadata["resume"]["errors"] == broken.n_errors
    log = [json.loads(line) for line in (dst / "errors.jsonl").read_text().splitlines()]
    assert log and all(e["scene"] == "training_000000" and e["severity"] == "error" for e in log)
    assert any(e["file"].endswith("label_2/000001.txt") for e in log)
    # Written with errors: never complete, so an unchanged rerun tries again.
    assert convert(src, dst).written == ["training_000000"]
    replace(src, "label_2", "000001.txt", good)
    fixed = convert(src, dst)
    assert fixed.written == ["training_000000"] and fixed.n_errors == 0
    assert samples(dst) == [0, 1, 2] and objects_in(dst, 1) == n_broken + 1
    assert not (dst / "errors.jsonl").exists()
    assert convert(src, dst).complete == ["training_000000"]


def test_small_file_edit_with_same_size_and_mtime_and_large_file_touch_both_rewrite(tmp_path: Path) -> None:
    src, dst = object_layout(tmp_path / "src"), tmp_path / "out"
    label = replace(src, "label_2", "000002.txt", (REAL / "training" / "label_2" / "000002.txt").read_bytes())
    convert(src, dst)
    stat = label.stat()
    text = label.read_bytes()
    label.write_bytes(text.replace(b" 1.63 ", b" 1.64 ", 1))  # a box height edited, same size
    os.utime(label, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert label.stat().st_size == stat.st_size and label.stat().st_mtime_ns == stat.st_mtime_ns
    assert convert(src, dst).written == ["training_000000"]
    velodyne = replace(src, "velodyne", "000000.bin", (REAL / "training" / "velodyne" / "000000.bin").read_bytes())
    assert velodyne.stat().st_size > HASH_MAX_BYTES  # fingerprinted by size and mtime
    assert convert(src, dst).written == ["training_000000"]
    assert convert(src, dst).complete == ["training_000000"]


def test_changing_scene_size_rewrites_and_removes_stale_scenes(tmp_path: Path) -> None:
    src, dst = object_layout(tmp_path / "src"), tmp_path / "out"
    assert convert(src, dst, options={"scene_size": 1}).written == ["training_000000", "training_000001",
                                                                    "training_000002"]
    result = convert(src, dst, options={"scene_size": 2})
    # training_000000 existed with scene_size 1 (one sample): rewritten, not trusted.
    assert result.written == ["training_000000", "training_000002"] and result.complete == []
    assert result.removed == ["training_000001"]
    assert samples(dst) == [0, 1]
    assert DatasetReader(dst).scenes == ["training_000000", "training_000002"]
    assert validate_dataset(dst) == []


def test_a_huge_scene_size_fingerprints_the_listed_samples_only(tmp_path: Path) -> None:
    # --scene-size 2**31 made range(2**31) source paths per scene: 1.6 GB in a minute, a hang.
    src, dst = object_layout(tmp_path / "src"), tmp_path / "out"
    converter = KittiObjectConverter(ConvertConfig(src=src, dst=dst, quiet=True, options={"scene_size": 2**70}))
    assert converter.list_scenes() == ["training_000000"]
    files = converter.source_files("training_000000")
    assert sorted(p.name for p in files if p.parent.name == "calib") == ["000000.txt", "000001.txt", "000002.txt"]
    assert len(files) == 3 * 5  # calib, label_2, velodyne, image_2, image_3 per listed sample
    assert run_conversion(converter).written == ["training_000000"]
    # A sample added to the scene later is still seen by the resume fingerprint.
    for folder, suffix in FOLDERS.items():
        (src / "training" / folder / f"000007{suffix}").symlink_to(REAL / "training" / folder / f"000002{suffix}")
    assert run_conversion(converter).written == ["training_000000"]
    assert samples(dst) == [0, 1, 2, 7]


@pytest.mark.parametrize("dst", ["src", "src/out", "src/training/.."])
def test_dst_at_or_under_src_is_refused_before_anything_is_written(tmp_path: Path, dst: str) -> None:
    # It was converted: DST's files mixed into the source layout (and read back by the default source_files).
    src = object_layout(tmp_path / "src")
    before = sorted(src.rglob("*"))
    where = "SRC itself" if dst != "src/out" else f"a path inside SRC {src}"
    with pytest.raises(InputError, match=f"expected an output outside SRC, got {where}$"):
        convert(src, tmp_path / dst)
    assert sorted(src.rglob("*")) == before


def test_a_failed_scene_loses_its_old_file(tmp_path: Path) -> None:
    src, dst = object_layout(tmp_path / "src"), tmp_path / "out"
    convert(src, dst, options={"scene_size": 2})
    (src / "training" / "calib" / "000002.txt").unlink()
    result = convert(src, dst, options={"scene_size": 2})
    assert result.failed == ["training_000002"]
    assert not (dst / "scenes" / "training_000002.mcap").exists()
    assert DatasetReader(dst).scenes == ["training_000000"]


def test_typed_options_reject_unknown_names_and_bad_values(tmp_path: Path) -> None:
    with pytest.raises(AvdataError, match="expected options among .*got 'scenesize'"):
        KittiObjectConverter(ConvertConfig(src=REAL, dst=tmp_path / "o", options={"scenesize": 2}))
    with pytest.raises(InputError, match="expected --scene-size >= 1, got 0"):
        KittiObjectConverter(ConvertConfig(src=REAL, dst=tmp_path / "o", options={"scene_size": 0}))
    options = KittiObjectConverter.Options(scene_size=7)
    assert KittiObjectConverter(ConvertConfig(src=REAL, dst=tmp_path / "o", options=options)).options is options


def test_a_second_writer_fails_with_the_holders_pid(tmp_path: Path) -> None:
    dst = tmp_path / "out"
    with dataset_lock(dst):
        result = run_cli("convert", "kitti-object", str(REAL), str(dst), "--quiet")
        with pytest.raises(InputError, match=f"PID {os.getpid()}"):
            convert(REAL, dst)
    assert result.returncode == 1
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
    assert result.stderr.startswith("avdata: error: ") and f"(PID {os.getpid()}) is writing this folder" in result.stderr
    assert not (dst / "scenes").exists()
    assert convert(REAL, dst).written == ["training_000000"]  # released at the end of the block


def test_two_concurrent_converts_never_leave_a_corrupt_scene(tmp_path: Path) -> None:
    dst = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    argv = [sys.executable, "-m", "avdata.cli", "convert", "kitti-object", str(REAL), str(dst), "--quiet",
            "--scene-size", "1", "--force"]
    runs = [subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env) for _ in range(2)]
    outputs = [(p.wait(timeout=300), *p.communicate()) for p in runs]
    assert any(code == 0 for code, _, _ in outputs)
    for code, _out, err in outputs:
        if code:
            assert err.count("\n") == 1 and "is writing this folder" in err and "PID " in err
    assert validate_dataset(dst) == []
    assert DatasetReader(dst).scenes == ["training_000000", "training_000001", "training_000002"]
    assert not list((dst / "scenes").glob("*.tmp"))


@pytest.mark.parametrize("case", ["file", "under-a-file", "unwritable", "fifo", "broken link", "link loop"])
def test_unusable_dst_is_one_line(tmp_path: Path, case: str) -> None:
    # A FIFO was called "a file", a broken link and a link loop "File exists".
    blocker = tmp_path / "blocker"
    blocker.write_text("not a folder")
    dst = {"file": blocker, "under-a-file": blocker / "out", "unwritable": tmp_path / "ro" / "out"}.get(case, tmp_path / "dst")
    if case == "unwritable":
        if os.geteuid() == 0:
            pytest.skip("root writes into read-only folders")
        (tmp_path / "ro").mkdir(mode=0o555)
    elif case == "fifo":
        os.mkfifo(dst)
    elif case == "broken link":
        dst.symlink_to(tmp_path / "nowhere")
    elif case == "link loop":
        dst.symlink_to(dst)
    expected = {"file": "expected a folder to write into, got a file",
                "under-a-file": "cannot create the output folder (Not a directory)",
                "unwritable": "cannot create the output folder (Permission denied)",
                "fifo": "expected a folder to write into, got a FIFO",
                "broken link": "expected a folder to write into, got a broken symbolic link",
                "link loop": "cannot create the output folder (Too many levels of symbolic links)"}[case]
    for argv in (["convert", "kitti-object", str(REAL), str(dst)], ["generate", "--preset", "v2i-intersection", str(dst)]):
        result = run_cli(*argv, "--quiet")
        assert result.returncode == 1 and "Traceback" not in result.stderr
        assert result.stderr.count("\n") == 1 and result.stderr.startswith("avdata: error: "), result.stderr
        assert expected in result.stderr


@pytest.mark.parametrize(
    ("yaml_text", "extra", "expected"),
    [
        ("scenes: 1\nframes: 2\n", ["--seed", "-1"], "field seed: expected an integer >= 0, got -1"),
        ("scenes: 'two'\n", [], "field scenes: expected an integer, got 'two'"),
        ("frames: 2\ntown: {grid: [3, 'x']}\n", [], "field town.grid[1]: expected an integer, got 'x'"),
        ("frame_rate_hz: .nan\n", [], "field frame_rate_hz: expected a finite number, got nan"),
        ("egos: 5\n", [], "field egos: expected a list, got 5"),
    ],
)
def test_bad_generate_input_is_one_line(tmp_path: Path, yaml_text: str, extra: list[str], expected: str) -> None:
    config = tmp_path / "scenario.yaml"
    config.write_text(yaml_text)
    result = run_cli("generate", str(config), str(tmp_path / "out"), "--quiet", *extra)
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("avdata: error: "), result.stderr
    assert expected in result.stderr
    assert not (tmp_path / "out").exists()


def test_stale_temporary_files_are_cleaned_under_the_lock(tmp_path: Path) -> None:
    dst = tmp_path / "out"
    convert(REAL, dst)
    leftover = dst / "scenes" / ".training_000000.mcap.4242.deadbeef.tmp"
    leftover.write_bytes(b"half a scene")
    assert convert(REAL, dst).complete == ["training_000000"]
    assert not leftover.exists()
    shutil.rmtree(dst / "scenes")
    assert convert(REAL, dst).written == ["training_000000"]


def test_command_line_options_come_from_the_options_dataclass() -> None:
    import argparse
    from dataclasses import dataclass, field

    from avdata.converters.base import Converter, ConverterOptions

    @dataclass(frozen=True, slots=True, kw_only=True)
    class Options(ConverterOptions):
        decode_images: bool = field(default=False, metadata={"help": "check harder"})
        scene_size: int = 100
        version: str | None = None
        variant: str = field(default="a", metadata={"choices": ("a", "b")})

    class Probe(Converter):
        name = source = "probe"

    Probe.Options = Options
    parser = argparse.ArgumentParser()
    Probe.add_arguments(parser)
    args = parser.parse_args(["--decode-images", "--scene-size", "7", "--version", "v1.0-mini"])
    assert (args.decode_images, args.scene_size, args.version, args.variant) == (True, 7, "v1.0-mini", "a")
    assert parser.parse_args([]).version is None and parser.parse_args([]).scene_size == 100
    with pytest.raises(SystemExit):
        parser.parse_args(["--variant", "c"])


def test_kitti_tracking_and_raw_fingerprint_their_own_files(tmp_path: Path) -> None:
    from avdata.converters.kitti import KittiRawConverter, KittiTrackingConverter
    from tests.converters.test_kitti_raw import DRIVE, assemble_drive

    tracking = REAL.parent / "tracking"
    dst = tmp_path / "tracking"
    first = run_conversion(KittiTrackingConverter(ConvertConfig(src=tracking, dst=dst, quiet=True)))
    assert first.written == ["training_0001"]
    # calib, oxts, label_02 + two velodyne sweeps and two stereo pairs
    assert SceneReader(dst / "scenes" / "training_0001.mcap").metadata["resume"]["n_sources"] == 9
    assert run_conversion(KittiTrackingConverter(ConvertConfig(src=tracking, dst=dst, quiet=True))).complete == first.written

    src = tmp_path / "raw"
    assemble_drive(src)
    converter = KittiRawConverter(ConvertConfig(src=src, dst=tmp_path / "out", quiet=True))
    files = converter.source_files(DRIVE)
    assert {p.name for p in files} >= {"calib_cam_to_cam.txt", "calib_imu_to_velo.txt", "calib_velo_to_cam.txt"}
    assert all(p.is_file() for p in files) and any(p.suffix == ".bin" for p in files)
    first_raw = run_conversion(converter)
    assert first_raw.written == [DRIVE] and first_raw.n_errors == 0
    assert run_conversion(converter).complete == [DRIVE]
    timestamps = src / "2011_09_26" / DRIVE / "oxts" / "timestamps.txt"
    timestamps.write_text(timestamps.read_text())  # rewritten with the same content: a small file, hashed
    assert run_conversion(converter).complete == [DRIVE]
