"""Bad and partial KITTI input: each problem is reported with file and line, that frame is skipped,
the rest converts; ``strict`` stops at the first error. Layouts are built from the real files
(symlinked), with one file broken per case."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.base import StrictError
from avdata.converters.kitti import KittiObjectConverter, KittiTrackingConverter
from avdata.errors import InputError
from avdata.schema import DatasetReader
from avdata.schema.validate import validate_dataset
from tests.realdata import REALDATA

REAL = REALDATA / "kitti"
FOLDERS = {"calib": ".txt", "label_2": ".txt", "velodyne": ".bin", "image_2": ".png"}


def object_layout(root: Path, skip: tuple[str, str] | None = None) -> Path:
    """training/ with the three real samples symlinked, except ``skip`` = (folder, sample)."""
    for folder, suffix in FOLDERS.items():
        (root / "training" / folder).mkdir(parents=True)
        for sample in ("000000", "000001", "000002"):
            if skip != (folder, sample):
                (root / "training" / folder / f"{sample}{suffix}").symlink_to(
                    REAL / "object" / "training" / folder / f"{sample}{suffix}")
    return root


def replace(root: Path, folder: str, name: str, data: bytes) -> Path:
    path = root / "training" / folder / name
    path.unlink()
    path.write_bytes(data)
    return path


def convert(src: Path, dst: Path, **options):
    strict = options.pop("strict", False)
    return valid(run_conversion(KittiObjectConverter(ConvertConfig(src=src, dst=dst, quiet=True, strict=strict,
                                                                   options=options))), dst)


def valid(result, dst: Path):
    """``result``, after checking that what the conversion wrote passes ``avdata validate`` (issue 34)."""
    if (dst / "avdata.json").is_file():
        assert validate_dataset(dst) == []
    return result


def converted_samples(dst: Path) -> list[int]:
    return DatasetReader(dst).scene("training_000000").metadata["kitti_sample_ids"]


def test_frame_without_calib_is_skipped(tmp_path):
    src = object_layout(tmp_path / "src", skip=("calib", "000001"))
    result = convert(src, tmp_path / "out")
    errors = [p for p in result.problems if p.severity == "error"]
    assert len(errors) == 1 and errors[0].file.endswith("calib/000001.txt")
    assert "calibration file missing" in errors[0].message and "sample 000001 skipped" in errors[0].message
    assert converted_samples(tmp_path / "out") == [0, 2]
    assert DatasetReader(tmp_path / "out").frames().num_rows == 2


def test_calib_with_a_short_matrix_names_the_line(tmp_path):
    src = object_layout(tmp_path / "src")
    lines = (REAL / "object" / "training" / "calib" / "000002.txt").read_text().splitlines()
    lines[4] = " ".join(lines[4].split()[:8])
    replace(src, "calib", "000002.txt", "\n".join(lines).encode())
    result = convert(src, tmp_path / "out")
    (error,) = result.problems
    assert "line 5: expected 9 values for R0_rect, got 7" in error.message
    assert converted_samples(tmp_path / "out") == [0, 1]


def test_label_line_with_wrong_field_count(tmp_path):
    src = object_layout(tmp_path / "src")
    lines = (REAL / "object" / "training" / "label_2" / "000001.txt").read_text().splitlines()
    lines[1] = " ".join(lines[1].split()[:12])
    path = replace(src, "label_2", "000001.txt", "\n".join(lines).encode())
    result = convert(src, tmp_path / "out")
    (error,) = result.problems
    assert error.file == str(path)
    assert error.message == ("line 2: expected 15 fields (16 with a score), got 12; object dropped, sample 000001 "
                             "written without it")
    assert result.n_errors == 1 and result.written == ["training_000000"]
    assert converted_samples(tmp_path / "out") == [0, 1, 2]
    ids = DatasetReader(tmp_path / "out").objects().column("object_id").to_pylist()
    # Sample 1: Truck, Car, Cyclist, 4 DontCare; the Car (line 2) is the only object missing, ids stay put.
    assert "000001_1" not in ids and "000001_0" in ids and "000001_2" in ids


@pytest.mark.parametrize(("field", "value", "message"), [
    (4, "1e300", "bbox: expected pixel coordinates within 1e+06, got 1e300 181.54 423.81 203.12"),
    (3, "-1e39", "alpha: expected a value within float32 range, got '-1e39'"),
    (1, "4e38", "truncated: expected a value within float32 range, got '4e38'"),
])
def test_label_value_beyond_what_is_stored_drops_its_object(tmp_path, field, value, message):
    # Visibility fields are float32: these values used to be written as infinity, without a word.
    src = object_layout(tmp_path / "src")
    lines = (REAL / "object" / "training" / "label_2" / "000001.txt").read_text().splitlines()
    fields = lines[1].split()
    fields[field] = value
    lines[1] = " ".join(fields)
    path = replace(src, "label_2", "000001.txt", "\n".join(lines).encode())
    result = convert(src, tmp_path / "out")
    (error,) = result.problems
    assert error.file == str(path)
    assert error.message == f"line 2: {message}; object dropped, sample 000001 written without it"
    scene = DatasetReader(tmp_path / "out").scene("training_000000")
    assert all(np.isfinite(vis.box2d_xyxy).all() and np.isfinite(vis.alpha_rad[vis.in_fov]).all()
               for _, _, _, vis in scene.iter_visibility())


def sensors_of_frames(dst: Path) -> list[list[str]]:
    """Per frame of the one scene, the sensors it lists (what was written for it)."""
    scene = DatasetReader(dst).scene("training_000000")
    return [sorted(info.sensor_timestamps_ns) for info in scene.frame_infos()]


@pytest.mark.parametrize("cut", [5, None])
def test_velodyne_size_not_a_multiple_of_16_or_empty(tmp_path, cut):
    # A damaged scan costs itself, like a missing one: the sample keeps its labels and image. A 0-byte scan was
    # written as an empty cloud without a word.
    src = object_layout(tmp_path / "src")
    data = (REAL / "object" / "training" / "velodyne" / "000000.bin").read_bytes()
    replace(src, "velodyne", "000000.bin", data[:-cut] if cut else b"")
    result = convert(src, tmp_path / "out")
    (error,) = result.problems
    assert error.file.endswith("velodyne/000000.bin")
    got = f"got {len(data) - cut} bytes" if cut else "got an empty file (0 bytes)"
    assert got in error.message and "sample 000000 written without its point cloud" in error.message
    assert converted_samples(tmp_path / "out") == [0, 1, 2]
    assert sensors_of_frames(tmp_path / "out") == [["ego/cam2"], ["ego/cam2", "ego/velodyne"], ["ego/cam2", "ego/velodyne"]]


def test_truncated_image_costs_itself(tmp_path):
    src = object_layout(tmp_path / "src")
    data = (REAL / "object" / "training" / "image_2" / "000002.png").read_bytes()
    replace(src, "image_2", "000002.png", data[: len(data) // 2])
    result = convert(src, tmp_path / "out")
    (error,) = result.problems
    assert error.file.endswith("image_2/000002.png") and "IEND" in error.message
    assert error.message.endswith("sample 000002 written without this image")
    assert converted_samples(tmp_path / "out") == [0, 1, 2]
    assert sensors_of_frames(tmp_path / "out")[2] == ["ego/velodyne"]


def test_corrupted_png_body_is_found_by_its_crcs_without_decoding(tmp_path):
    """Header and trailer intact, body zeroed: the chunk CRCs find it; --decode-images finds it by decoding."""
    src = object_layout(tmp_path / "src")
    data = bytearray((REAL / "object" / "training" / "image_2" / "000002.png").read_bytes())
    data[100:-100] = bytes(len(data) - 200)
    replace(src, "image_2", "000002.png", bytes(data))
    (error,) = convert(src, tmp_path / "cheap").problems
    assert "CRC-32 does not match (damaged bytes); sample 000002 written without it" in error.message
    (error,) = convert(src, tmp_path / "decoded", decode_images=True).problems
    assert "does not decode" in error.message
    for dst in ("cheap", "decoded"):
        assert converted_samples(tmp_path / dst) == [0, 1, 2]
        assert sensors_of_frames(tmp_path / dst)[2] == ["ego/velodyne"]


@pytest.mark.parametrize("make", [Path.mkdir, os.mkfifo])
@pytest.mark.parametrize(("folder", "name", "written"), [
    ("image_2", "000000.png", ["ego/velodyne"]), ("velodyne", "000000.bin", ["ego/cam2"])])
def test_a_folder_where_a_file_should_be_is_an_error_not_a_missing_file(tmp_path, folder, name, written, make):
    # A folder was reported as missing (a warning, "partial download?"), exit 0; a FIFO failed the whole scene.
    src = object_layout(tmp_path / "src")
    (src / "training" / folder / name).unlink()
    make(src / "training" / folder / name)
    result = convert(src, tmp_path / "out")
    (error,) = result.problems
    assert error.severity == "error" and error.file.endswith(f"{folder}/{name}")
    assert error.message.startswith("expected a file, got a folder, a broken link or a special file; sample 000000 written")
    assert converted_samples(tmp_path / "out") == [0, 1, 2]
    assert sensors_of_frames(tmp_path / "out")[0] == written


@pytest.mark.parametrize(("make", "message"), [
    (Path.mkdir, "expected a calibration file, got a folder"), (os.mkfifo, "expected a regular file, got a FIFO")])
def test_a_calibration_that_is_not_a_file_costs_its_sample_and_says_what_it_is(tmp_path, make, message):
    # Both were reported as "calibration file missing"; the FIFO failed the whole scene.
    src = object_layout(tmp_path / "src")
    path = src / "training" / "calib" / "000001.txt"
    path.unlink()
    make(path)
    result = convert(src, tmp_path / "out")
    (error,) = result.problems
    assert error.file == str(path) and error.message == f"{message}; sample 000001 skipped"
    assert converted_samples(tmp_path / "out") == [0, 2]


@pytest.mark.parametrize(("value", "shown"), [(np.nan, "nan"), (1e30, "1.0000000150474662e+30")])
def test_a_scan_value_no_lidar_measures_costs_that_scan(tmp_path, value, shown):
    # A .bin has no checksum: a damaged float (a flipped exponent bit) was written as a point at 1e30 m.
    src = object_layout(tmp_path / "src")
    values = np.fromfile(REAL / "object" / "training" / "velodyne" / "000001.bin", dtype="<f4")
    values[1001] = value  # point 250, y
    path = replace(src, "velodyne", "000001.bin", values.tobytes())
    result = convert(src, tmp_path / "out")
    (error,) = result.problems
    assert error.file == str(path) and error.message == (
        f"point 250, y: expected a finite value within +-1e+07, got {shown} (damaged bytes?); sample 000001 written "
        f"without it")
    assert converted_samples(tmp_path / "out") == [0, 1, 2]
    assert sensors_of_frames(tmp_path / "out")[1] == ["ego/cam2"]


def test_strict_stops_at_the_first_error(tmp_path):
    src = object_layout(tmp_path / "src", skip=("calib", "000000"))
    with pytest.raises(StrictError, match="calib/000000.txt"):
        convert(src, tmp_path / "out", strict=True)
    assert not (tmp_path / "out" / "scenes" / "training_000000.mcap").exists()


def test_partial_download_writes_labels_without_sensor_data(tmp_path):
    src = object_layout(tmp_path / "src", skip=("velodyne", "000001"))
    (src / "training" / "image_2" / "000002.png").unlink()
    result = convert(src, tmp_path / "out")
    assert result.n_errors == 0
    assert sorted(Path(p.file).name for p in result.problems) == ["000001.bin", "000002.png"]
    dataset = DatasetReader(tmp_path / "out")
    times = [dict(t) for t in dataset.frames().column("sensor_timestamps_ns").to_pylist()]
    assert [sorted(t) for t in times] == [["ego/cam2", "ego/velodyne"], ["ego/cam2"], ["ego/velodyne"]]
    assert dataset.objects().num_rows == 6


def test_tracking_bad_label_line_drops_its_object(tmp_path):
    src = tmp_path / "src" / "training"
    tracking = REAL / "tracking" / "training"
    shutil.copytree(tracking, src, symlinks=True, ignore=shutil.ignore_patterns("label_02"))
    (src / "label_02").mkdir()
    lines = (tracking / "label_02" / "0001.txt").read_text().splitlines()
    bad = next(i for i, line in enumerate(lines) if line.startswith("5 "))
    lines[bad] = lines[bad] + " 7.0 8.0"
    (src / "label_02" / "0001.txt").write_text("\n".join(lines) + "\n")
    result = run_conversion(KittiTrackingConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "out",
                                                                 quiet=True)))
    (error,) = [p for p in result.problems if p.severity == "error"]
    assert error.message == (f"line {bad + 1}: expected 17 fields (18 with a score), got 19; object dropped, "
                             f"frame 5 written without it")
    dataset = DatasetReader(tmp_path / "out")
    assert dataset.frames().num_rows == 447
    objects = dataset.objects().to_pydict()
    in_frame_5 = [oid for oid, f in zip(objects["object_id"], objects["frame_index"], strict=True) if f == 5]
    expected = [line.split()[1] for line in lines if line.startswith("5 ") and "DontCare" not in line]
    assert sorted(in_frame_5) == sorted(set(expected) - {lines[bad].split()[1]})


def tracking_with_oxts(tmp_path: Path, lines: list[str]) -> Path:
    """The real tracking sequence 0001 with its oxts file replaced by ``lines``."""
    src = tmp_path / "src" / "training"
    shutil.copytree(REAL / "tracking" / "training", src, symlinks=True, ignore=shutil.ignore_patterns("oxts"))
    (src / "oxts").mkdir()
    (src / "oxts" / "0001.txt").write_text("\n".join(lines) + "\n")
    return src


def convert_tracking(src: Path, dst: Path):
    return valid(run_conversion(KittiTrackingConverter(ConvertConfig(src=src.parent, dst=dst, quiet=True))), dst)


def test_tracking_repeated_oxts_line_refuses_the_sequence(tmp_path):
    # A repeated packet line shifted every later pose by a frame, without a word.
    lines = (REAL / "tracking" / "training" / "oxts" / "0001.txt").read_text().splitlines()
    src = tracking_with_oxts(tmp_path, lines[:100] + [lines[99]] + lines[100:])
    result = convert_tracking(src, tmp_path / "out")
    (error,) = result.problems
    assert error.severity == "error" and error.message.endswith(
        "oxts/0001.txt: packets 100 and 101 (0-based frames 99 and 100) are identical: a repeated line shifts "
        "every later frame's pose by one; the sequence is refused")
    assert result.written == [] and not (tmp_path / "out" / "scenes" / "training_0001.mcap").exists()


def test_tracking_oxts_missing_packets_is_an_error(tmp_path):
    # One packet line fewer than the labelled frames, and a scan of a frame after the last packet: both were
    # warnings (exit 0) or not reported at all.
    lines = (REAL / "tracking" / "training" / "oxts" / "0001.txt").read_text().splitlines()
    src = tracking_with_oxts(tmp_path, lines[:1] + lines[2:])
    scan = src / "velodyne" / "0001" / "000446.bin"
    scan.symlink_to(REAL / "tracking" / "training" / "velodyne" / "0001" / "000001.bin")
    result = convert_tracking(src, tmp_path / "out")
    errors = sorted((Path(p.file).name, p.message) for p in result.problems if p.severity == "error")
    labelled = [line for line in (src / "label_02" / "0001.txt").read_text().splitlines() if line.startswith("446 ")]
    assert len(labelled) == 1 and errors == [
        ("0001.txt", "line 4271: labels for frames up to 446, but the oxts file has 446 packets (frames 0..445); "
                     "1 label line(s) dropped"),
        ("000446.bin", "a file of frame 446, but the oxts file has 446 packets (frames 0..445): frames without a "
                       "pose are not converted (packets missing?)"),
    ]
    assert result.n_errors == 2 and DatasetReader(tmp_path / "out").frames().num_rows == 446


def test_tracking_sequence_without_calib_fails_alone(tmp_path):
    src = tmp_path / "src" / "training"
    shutil.copytree(REAL / "tracking" / "training", src, symlinks=True, ignore=shutil.ignore_patterns("calib"))
    result = run_conversion(KittiTrackingConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "out",
                                                                 quiet=True)))
    assert result.failed == ["training_0001"] and result.n_errors == 1
    assert "calib/0001.txt: calibration file missing" in result.problems[0].message


def test_testing_split_is_converted_unannotated_and_exported_to_testing(tmp_path):
    from avdata.exporters.kitti import export_kitti_object

    for folder, suffix in (("calib", ".txt"), ("velodyne", ".bin"), ("image_2", ".png")):
        (tmp_path / "src" / "testing" / folder).mkdir(parents=True)
        (tmp_path / "src" / "testing" / folder / f"000007{suffix}").symlink_to(
            REAL / "object" / "training" / folder / f"000000{suffix}")
    result = convert(tmp_path / "src", tmp_path / "out")
    assert result.written == ["testing_000000"] and not result.problems
    dataset = DatasetReader(tmp_path / "out")
    assert dataset.frames().column("annotated").to_pylist() == [False]
    assert dataset.scene("testing_000000").metadata["kitti_sample_ids"] == [7]
    exported = export_kitti_object(tmp_path / "out", tmp_path / "kitti")
    assert (exported.training, exported.testing) == (0, 1)
    assert (tmp_path / "kitti" / "testing" / "velodyne" / "000000.bin").read_bytes() == \
        (REAL / "object" / "training" / "velodyne" / "000000.bin").read_bytes()
    assert not (tmp_path / "kitti" / "testing" / "label_2").exists()
    assert (tmp_path / "kitti" / "ImageSets" / "test.txt").read_text() == "000000\n"


def test_convert_command_exit_status(tmp_path, monkeypatch, capsys):
    """``avdata convert kitti-object SRC DST``: 0 when clean, 1 with an error, summary printed."""
    import argparse

    from avdata.converters import cli

    monkeypatch.setattr(cli, "CONVERTERS", {name: cli.CONVERTERS[name] for name in ("kitti-object", "kitti-tracking",
                                                                                    "kitti-raw")})
    parser = argparse.ArgumentParser(prog="avdata")
    cli.add_convert_subparser(parser.add_subparsers())

    def run(*argv: str) -> int:
        args = parser.parse_args(list(argv))
        return args.run(args)

    assert run("convert", "kitti-object", str(REAL / "object"), str(tmp_path / "good"), "--quiet") == 0
    src = object_layout(tmp_path / "src", skip=("calib", "000002"))
    assert run("convert", "kitti-object", str(src), str(tmp_path / "bad"), "--quiet", "--scene-size", "2") == 1
    captured = capsys.readouterr()
    assert "calib/000002.txt" in captured.err
    # Scene training_000002 held only the sample without calib: reported, then the empty scene fails.
    assert "no readable sample with ids in [2, 4)" in captured.err
    assert "kitti-object: 1 scenes written, 0 already complete, 1 failed; 2 errors, 0 warnings" in captured.out
    assert DatasetReader(tmp_path / "bad").scenes == ["training_000000"]


def test_tracking_empty_velodyne_file_costs_that_scan(tmp_path):
    # A 0-byte sweep (an interrupted copy) was written as an empty cloud without a word (issue 34, S24); in a
    # tracking sequence it costs that frame's scan, as in KITTI object.
    src = tmp_path / "src" / "training"
    shutil.copytree(REAL / "tracking" / "training", src, symlinks=True)
    scan = src / "velodyne" / "0001" / "000001.bin"
    scan.unlink()
    scan.write_bytes(b"")
    result = convert_tracking(src, tmp_path / "out")
    (error,) = [p for p in result.problems if p.severity == "error"]
    assert error.file == str(scan) and "got an empty file (0 bytes)" in error.message
    frames = DatasetReader(tmp_path / "out").scene("training_0001").frame_infos()
    assert "ego/velodyne" in frames[0].sensor_timestamps_ns and "ego/velodyne" not in frames[1].sensor_timestamps_ns


def test_a_file_named_by_a_non_ascii_digit_is_not_a_sample(tmp_path):
    # '²'.isdigit() is true and int('²') a ValueError: the listing of sample ids was a traceback.
    src = object_layout(tmp_path / "src")
    (src / "training" / "label_2" / "00000\u00b2.txt").symlink_to(REAL / "object" / "training" / "label_2" / "000001.txt")
    result = convert(src, tmp_path / "out")
    assert result.n_errors == 0 and converted_samples(tmp_path / "out") == [0, 1, 2]


def tracking_without_oxts(tmp_path: Path) -> Path:
    """The real tracking sequence 0001 without its oxts file (frames from the labels and sensor files)."""
    src = tmp_path / "src" / "training"
    shutil.copytree(REAL / "tracking" / "training", src, symlinks=True, ignore=shutil.ignore_patterns("oxts"))
    return src


@pytest.mark.parametrize(("frame", "shown"), [("999999999", "'999999999'"), ("1_0", "'1_0'"), ("\u0663", "'\u0663'")])
def test_tracking_label_frame_that_is_no_frame_costs_its_line(tmp_path, frame, shown):
    # Without oxts the frames come from the labels: frame 999999999 made a sequence of 10^9 frames (a 67 GB
    # allocation, a MemoryError traceback); int() took '1_0' as frame 10 and an Arabic-Indic 3 as frame 3.
    src = tracking_without_oxts(tmp_path)
    lines = (REAL / "tracking" / "training" / "label_02" / "0001.txt").read_text().splitlines()
    lines[6] = " ".join([frame, *lines[6].split()[1:]])
    (src / "label_02" / "0001.txt").unlink()
    (src / "label_02" / "0001.txt").write_text("\n".join(lines) + "\n")
    result = convert_tracking(src, tmp_path / "out")
    (error,) = [p for p in result.problems if p.severity == "error"]
    assert error.message == (f"line 7: expected a frame number in [0, 1000000) (six digits, as KITTI names frames), "
                             f"got {shown}; object dropped")
    assert DatasetReader(tmp_path / "out").frames().num_rows == 447


@pytest.mark.parametrize("name", ["999999999999.bin", "00000\u00b2.bin"])
def test_tracking_scan_name_that_is_no_frame_is_not_a_frame(tmp_path, name):
    # Without oxts, a scan named 999999999999.bin made 10^12 frames; one named 00000².bin was a traceback. Only
    # six-digit names are looked up per frame: such a file is no frame's.
    src = tracking_without_oxts(tmp_path)
    (src / "velodyne" / "0001" / name).symlink_to(REAL / "tracking" / "training" / "velodyne" / "0001" / "000001.bin")
    result = convert_tracking(src, tmp_path / "out")
    assert result.n_errors == 0 and DatasetReader(tmp_path / "out").frames().num_rows == 447


def test_tracking_scans_of_frames_far_beyond_the_oxts_are_an_error(tmp_path):
    # Only a file of frame n_frames (447) was looked for: scans of frames 999 and 1500 were dropped without a word.
    src = tmp_path / "src" / "training"
    shutil.copytree(REAL / "tracking" / "training", src, symlinks=True)
    for frame in (999, 1500):
        (src / "velodyne" / "0001" / f"{frame:06d}.bin").symlink_to(
            REAL / "tracking" / "training" / "velodyne" / "0001" / "000001.bin")
    result = convert_tracking(src, tmp_path / "out")
    (error,) = [p for p in result.problems if p.severity == "error"]
    assert Path(error.file).name == "000999.bin" and error.message == (
        "a file of frame 999 (and 1 more), but the oxts file has 447 packets (frames 0..446): frames without a pose "
        "are not converted (packets missing?)")
    assert DatasetReader(tmp_path / "out").frames().num_rows == 447


@pytest.mark.parametrize("folder", ["label_2", "velodyne"])
def test_a_file_where_a_sample_folder_should_be_is_one_error(tmp_path, folder):
    # Was one "label file missing" error per sample (a warning "partial download?" for the sensor folders, exit 0),
    # then one for the scene left without samples.
    src = object_layout(tmp_path / "src")
    shutil.rmtree(src / "training" / folder)
    (src / "training" / folder).write_text("not a folder\n")
    with pytest.raises(InputError, match=rf"training/{folder}: expected a folder of <sample>\.(txt|bin) files, got a "
                                         rf"file, a broken link or a special file"):
        convert(src, tmp_path / "out")
