"""Source files replaced by a folder, a FIFO, a broken link, an empty or a half file, built from ``../shared/realdata``.

Each case is one that a sweep of every converter and file kind found wrong (a silent loss, a whole drive or
dataset lost for one file, a damaged file taken for an absent one, one problem reported many times). Each
runs the ``avdata`` command line in-process and checks: exit status 1, one line naming the file, no
traceback, and exactly the record of that file lost.
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

import pytest

from avdata.cli import main
from avdata.schema import DatasetReader
from tests.converters.test_dair_v2x import build_dair
from tests.converters.test_kitti_raw import DRIVE, TRACKLETS, assemble_drive
from tests.converters.test_nuscenes import LIDAR_FILE, build_synthetic_nuscenes
from tests.converters.test_nuscenes_bad_input import VERSION, lyft_copy
from tests.test_hostile_corpus import assert_written_is_valid

DAMAGES = ("folder", "fifo", "dangling", "empty", "half")
#: what each damage makes a whole-file reader say (read_regular_file, then the format's parser)
UNREADABLE = {"folder": "cannot read (Is a directory)", "fifo": "expected a regular file, got a FIFO",
              "dangling": "cannot read (No such file or directory)"}


def run(argv: list, capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str]]:
    """(exit status, stderr lines) of ``avdata argv``; a traceback fails the test."""
    status = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert_written_is_valid(argv)
    return status, err.splitlines()


def errors_naming(err: list[str], path: Path) -> list[str]:
    return [line for line in err if "error:" in line and str(path) in line]


def damage(path: Path, how: str) -> Path:
    """Replaces the file (or link) at ``path`` by a folder, a FIFO, a broken link, an empty or a half file."""
    data = path.read_bytes() if how == "half" else b""
    path.unlink()
    if how == "folder":
        path.mkdir()
    elif how == "fifo":
        os.mkfifo(path)
    elif how == "dangling":
        path.symlink_to(f"/nonexistent/{path.name}")
    else:
        path.write_bytes(data[: len(data) // 2])
    return path


def summary(dst: Path) -> tuple[int, int, int]:
    """(frames, objects, sensor messages listed by the frames) of a converted dataset."""
    reader = DatasetReader(dst)
    frames = reader.frames()
    messages = sum(len(m) for m in frames.column("sensor_timestamps_ns").to_pylist())
    return frames.num_rows, reader.objects().num_rows, messages


# --- KITTI raw ------------------------------------------------------------------------------------------------


@pytest.fixture()
def raw_drive(tmp_path: Path) -> Path:
    """A 108-frame raw drive around the real files, with tracklets (clean: exit 0, 108 frames, 3 boxes, 6 messages)."""
    drive = assemble_drive(tmp_path / "src")
    (drive / "tracklet_labels.xml").write_text(TRACKLETS)
    return drive


@pytest.mark.parametrize("how", DAMAGES)
def test_kitti_raw_damaged_tracklets_cost_the_labels_only(raw_drive: Path, tmp_path: Path, capsys, how) -> None:
    # A folder, FIFO or broken link was taken for "no tracklets": the drive was written unlabelled, exit 0.
    # An empty or half file failed the whole drive (poses and sensor data too).
    path = damage(raw_drive / "tracklet_labels.xml", how)
    status, err = run(["convert", "kitti-raw", tmp_path / "src", tmp_path / "dst", "--quiet"], capsys)
    errors = [line for line in err if "error:" in line]
    assert status == 1 and errors == errors_naming(err, path) and len(errors) == 1
    expected = UNREADABLE.get(how, "unreadable tracklet XML (")
    assert f"{path}: {expected}" in errors[0] and errors[0].endswith("; the drive is written without labels")
    assert summary(tmp_path / "dst") == (108, 0, 6)
    assert DatasetReader(tmp_path / "dst").scene(DRIVE).metadata["annotated"] is False


@pytest.mark.parametrize("how", ["folder", "fifo", "dangling"])
def test_kitti_raw_date_with_a_damaged_calibration_is_named_not_left_out(raw_drive: Path, tmp_path: Path, capsys,
                                                                         how) -> None:
    # The date folder was not recognised as one: with another date beside it, its drives were left out, exit 0.
    other = tmp_path / "src" / "2011_09_29"
    shutil.copytree(raw_drive.parent, other, symlinks=True)
    (other / DRIVE).rename(other / "2011_09_29_drive_0001_sync")
    path = damage(other / "calib_cam_to_cam.txt", how)
    status, err = run(["convert", "kitti-raw", tmp_path / "src", tmp_path / "dst", "--quiet"], capsys)
    errors = [line for line in err if "error:" in line]
    assert status == 1 and len(errors) == 1 and "2011_09_29_drive_0001_sync" in errors[0]
    assert str(path.relative_to(tmp_path / "src")) in errors[0]
    assert DatasetReader(tmp_path / "dst").scenes == [DRIVE]


@pytest.mark.parametrize("how", ["folder", "fifo", "dangling"])
def test_kitti_raw_oxts_packet_that_is_no_file_is_named(raw_drive: Path, tmp_path: Path, capsys, how) -> None:
    # Reported as "frames 1: oxts packet missing" on the folder, as if not downloaded.
    path = damage(raw_drive / "oxts" / "data" / "0000000001.txt", how)
    status, err = run(["convert", "kitti-raw", tmp_path / "src", tmp_path / "dst", "--quiet"], capsys)
    errors = [line for line in err if "error:" in line]
    expected = UNREADABLE[how].replace("cannot read", "unreadable")
    assert status == 1 and errors == [line for line in err if f"{path}: {expected}; frame 1 skipped (no pose)" in line]
    assert len(errors) == 1 and not any("oxts packet missing" in line for line in err)
    assert summary(tmp_path / "dst")[0] == 107


@pytest.mark.parametrize(("lines", "lost"), [(0, "0-1"), (1, "1")])
def test_kitti_raw_scans_without_a_timestamp_line_are_an_error(raw_drive: Path, tmp_path: Path, capsys, lines,
                                                               lost) -> None:
    # A short velodyne timestamps.txt dropped the scans it did not cover with a warning ("partial download?"), exit 0.
    path = raw_drive / "velodyne_points" / "timestamps.txt"
    text = path.read_text().splitlines(keepends=True)[:lines]
    path.unlink()
    path.write_text("".join(text))
    status, err = run(["convert", "kitti-raw", tmp_path / "src", tmp_path / "dst", "--quiet"], capsys)
    errors = [line for line in err if "error:" in line]
    assert status == 1 and len(errors) == 1
    assert f"{path}: expected a time per frame (108), got {lines}; frames {lost} written without this sensor" in errors[0]
    assert summary(tmp_path / "dst") == (108, 3, 6 - len(lost.split("-")))


@pytest.mark.parametrize(("folder", "line", "cost", "expected"), [
    ("oxts", 3, "frame 2 skipped (no time)", (107, 3, 6)),
    ("velodyne_points", 1, "frame 0 written without this sensor", (108, 3, 5)),
])
def test_kitti_raw_malformed_timestamp_line_costs_that_frame(raw_drive: Path, tmp_path: Path, capsys, folder, line,
                                                             cost, expected) -> None:
    # One malformed line was an InputError for the whole timestamps.txt: the drive (oxts) or the sensor was lost.
    path = raw_drive / folder / "timestamps.txt"
    text = path.read_text().splitlines(keepends=True)
    text[line - 1] = "2011-09-26 13:02:2x.967790592\n"
    path.unlink()
    path.write_text("".join(text))
    status, err = run(["convert", "kitti-raw", tmp_path / "src", tmp_path / "dst", "--quiet"], capsys)
    errors = [line for line in err if "error:" in line]
    assert status == 1 and len(errors) == 1
    assert errors[0].endswith(f"{path}: line {line}: expected 'YYYY-MM-DD HH:MM:SS.fffffffff', got "
                              f"'2011-09-26 13:02:2x.967790592'; {cost}")
    assert summary(tmp_path / "dst") == expected


@pytest.mark.parametrize(("folder", "line", "cost", "expected"), [
    ("velodyne_points", 1, "frame 0 written without this sensor", (108, 3, 5)),
    ("oxts", 3, "frame 2 skipped (no time)", (107, 3, 6))])
@pytest.mark.parametrize("time", ["1677-09-21 00:12:43.145224191", "2300-01-01 00:00:00.5"])
def test_kitti_raw_time_beyond_int64_nanoseconds_costs_that_frame(raw_drive: Path, tmp_path: Path, capsys, folder,
                                                                  line, cost, expected, time) -> None:
    # A well-formed time before 1970 or after 2262 overflowed the int64 nanoseconds: an OverflowError traceback.
    path = raw_drive / folder / "timestamps.txt"
    text = path.read_text().splitlines(keepends=True)
    text[line - 1] = time + "\n"
    path.unlink()
    path.write_text("".join(text))
    status, err = run(["convert", "kitti-raw", tmp_path / "src", tmp_path / "dst", "--quiet"], capsys)
    errors = [line for line in err if "error:" in line]
    assert status == 1 and len(errors) == 1
    assert errors[0].endswith(f"{path}: line {line}: expected a time from 1970 to 2262, got '{time}'; {cost}")
    assert summary(tmp_path / "dst") == expected


def test_kitti_raw_tracklet_beyond_the_drive_is_a_warning(raw_drive: Path, tmp_path: Path, capsys) -> None:
    # A tracklet starting after the last frame gave 0 objects without a word.
    path = raw_drive / "tracklet_labels.xml"
    path.write_text(TRACKLETS.replace("<first_frame>1</first_frame>", "<first_frame>5000</first_frame>"))
    status, err = run(["convert", "kitti-raw", tmp_path / "src", tmp_path / "dst", "--quiet"], capsys)
    warnings = [line for line in err if "warning:" in line and str(path) in line]
    assert status == 0 and len(warnings) == 1
    assert "tracklets [1]: expected poses within the drive's 108 frames, got up to frame 5000; 1 box(es) left out" in warnings[0]
    assert summary(tmp_path / "dst")[1] == 2


# --- nuScenes / Lyft ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("how", DAMAGES)
def test_nuscenes_damaged_map_table_costs_the_map_names_only(tmp_path: Path, capsys, how) -> None:
    # A folder, FIFO or broken link was skipped as an absent (optional) map.json, exit 0; an empty or half one
    # lost the whole dataset.
    root = lyft_copy(tmp_path / "src")
    damage(root / VERSION / "map.json", how)
    status, err = run(["convert", "nuscenes", root, tmp_path / "dst", "--quiet"], capsys)
    errors = [line for line in err if "error:" in line]
    assert status == 1 and len(errors) == 1
    expected = {"folder": "unreadable (Is a directory)", "fifo": "expected a regular file, got a FIFO",
                "dangling": "unreadable (No such file or directory)", "empty": "expected a JSON array, got ''",
                "half": "malformed JSON near character "}[how]
    assert f": map.json: {expected}" in errors[0] and errors[0].endswith("; every scene is written without its map")
    assert errors[0].count("map.json") == 1
    reader = DatasetReader(tmp_path / "dst")
    assert reader.objects().num_rows == 4 and reader.scene(reader.scenes[0]).metadata["map"] == ""


@pytest.mark.parametrize("how", ["folder", "fifo", "dangling"])
def test_nuscenes_version_with_a_damaged_scene_table_is_not_passed_over(tmp_path: Path, capsys, how) -> None:
    # Its version folder was not recognised as one: the other version was converted instead, exit 0.
    root = lyft_copy(tmp_path / "src")
    shutil.copytree(root / VERSION, root / "v1.01-other")
    damage(root / VERSION / "scene.json", how)
    status, err = run(["convert", "nuscenes", root, tmp_path / "dst", "--quiet"], capsys)
    assert status == 1 and err == [f"avdata: error: {root}: expected one version folder holding scene.json (pass "
                                   f"--version), got ['v1.01-other', '{VERSION}']"]


@pytest.mark.parametrize(("how", "got"), [("dangling", "a broken symbolic link"),
                                          ("loop", "Too many levels of symbolic links")])
def test_nuscenes_sensor_link_to_nowhere_is_an_error(tmp_path: Path, capsys, how, got) -> None:
    # A broken link was a warning ("sensor file missing", a partial download), exit 0.
    build_synthetic_nuscenes(tmp_path / "src")
    path = tmp_path / "src" / LIDAR_FILE
    path.unlink()
    path.symlink_to(path.name if how == "loop" else "/nonexistent/scan.pcd.bin")
    status, err = run(["convert", "nuscenes", tmp_path / "src", tmp_path / "dst", "--quiet"], capsys)
    errors = [line for line in err if "error:" in line]
    assert status == 1 and errors == [f"error: scene-0061: {LIDAR_FILE}: expected a sensor file, got {got} "
                                      f"(sample_data sd-scene-0061-0-LIDAR_TOP)"]
    assert summary(tmp_path / "dst") == (6, 10, 7)


# --- DAIR-V2X -------------------------------------------------------------------------------------------------


def test_dair_side_label_link_to_nowhere_is_an_error(tmp_path: Path, capsys) -> None:
    # Taken for an absent file: a warning ("per-side label file missing"), exit 0.
    build_dair(tmp_path / "src", skew=0.0)
    path = damage(tmp_path / "src" / "vehicle-side" / "label" / "lidar" / "017314.json", "dangling")
    status, err = run(["convert", "dair-v2x", tmp_path / "src", tmp_path / "dst", "--quiet"], capsys)
    errors = [line for line in err if "error:" in line]
    assert status == 1 and errors == [f"error: coop_017314: {path}: cannot read (No such file or directory)"]
    assert summary(tmp_path / "dst") == (1, 23, 4)


# --- Waymo ----------------------------------------------------------------------------------------------------


@pytest.mark.oracle
@pytest.mark.parametrize(("component", "messages"), [("camera_image", 5), ("camera_calibration", 5)])
@pytest.mark.parametrize("how", ["fifo", "half"])
def test_waymo_unreadable_camera_component_is_one_line(tmp_path: Path, capsys, component, messages, how) -> None:
    # camera_image was reported twice (read for the poses, then for the images); camera_calibration once, then
    # once more per image ("expected a calibrated camera [], got 1", ...).
    sys.path.insert(0, str(Path(__file__).resolve().parent / "oracles"))
    from waymo_fixture import waymo_v2_fixture

    fixture, info = waymo_v2_fixture()
    src = tmp_path / "src"
    for folder in fixture.iterdir():
        if folder.is_dir():
            (src / folder.name).mkdir(parents=True)
            for file in folder.iterdir():
                (src / folder.name / file.name).symlink_to(file)
    path = damage(src / component / f"{info['context']}.parquet", how)
    status, err = run(["convert", "waymo", src, tmp_path / "dst", "--quiet"], capsys)
    errors = [line for line in err if "error:" in line]
    assert status == 1 and len(errors) == 1 and str(path) in errors[0]
    assert summary(tmp_path / "dst") == (1, 75, messages)


def test_demo_into_an_existing_file_is_one_line(tmp_path: Path, capsys) -> None:
    # Was NotADirectoryError: [Errno 20] Not a directory: '.../scenes'.
    dst = tmp_path / "taken"
    dst.write_bytes(b"kept")
    status, err = run(["demo", dst], capsys)
    assert (status, err) == (1, [f"avdata: error: {dst}: expected a folder to write into, got a file"])
    assert dst.read_bytes() == b"kept"
