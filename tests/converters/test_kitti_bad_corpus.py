"""Bad-input corpus for KITTI object, tracking and raw, built from the real files: each case states which
record is lost, the message and the outcome; nothing raises, nothing else is lost (Issue 16.3, 16.7, 17.1)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.kitti import KittiObjectConverter, KittiRawConverter, KittiTrackingConverter
from avdata.schema import DatasetReader
from tests.realdata import REALDATA

REAL = REALDATA / "kitti"
OBJECT_FOLDERS = {"calib": ".txt", "label_2": ".txt", "velodyne": ".bin", "image_2": ".png"}


def object_copy(root: Path) -> Path:
    for folder, suffix in OBJECT_FOLDERS.items():
        (root / "training" / folder).mkdir(parents=True)
        for sample in ("000000", "000001", "000002"):
            (root / "training" / folder / f"{sample}{suffix}").symlink_to(
                REAL / "object" / "training" / folder / f"{sample}{suffix}")
    return root


def rewrite(path: Path, edit) -> None:
    data = edit(path.read_bytes())
    path.unlink()
    path.write_bytes(data)


def replace_line(data: bytes, index: int, new: bytes) -> bytes:
    lines = data.split(b"\n")
    lines[index] = new
    return b"\n".join(lines)


def calib_line(key: str, values) -> bytes:
    return (f"{key}: " + " ".join(f"{v:.12e}" for v in np.ravel(values))).encode()


def object_calib(sample: str) -> dict[str, np.ndarray]:
    out = {}
    for line in (REAL / "object" / "training" / "calib" / f"{sample}.txt").read_text().splitlines():
        if line.strip():
            key, *values = line.split()
            out[key.rstrip(":")] = np.array(values, dtype=float)
    return out


# (case id, file to edit, edit, expected messages, samples written, objects written)
_LABEL_1 = REAL / "object" / "training" / "label_2" / "000001.txt"


def _r_off() -> np.ndarray:
    """Sample 000002's Tr_velo_to_cam with one entry off by 1e-4 (read when a case runs, never at import)."""
    r_off = object_calib("000002")["Tr_velo_to_cam"].reshape(3, 4).copy()
    r_off[0, 0] += 1e-4
    return r_off


OBJECT_CASES = [
    ("label-nan", "label_2/000001.txt",
     lambda d: replace_line(d, 1, d.split(b"\n")[1].replace(b"-16.53", b"nan")),
     ["line 2: x: expected a finite number, got 'nan'; object dropped, sample 000001 written without it"], [0, 1, 2], 5),
    ("label-not-utf8", "label_2/000001.txt", lambda d: replace_line(d, 0, b"Truck \xff\xfe 0 -1.57"),
     ["line 1: expected UTF-8 text, got b'Truck \\xff\\xfe 0 -1.57'; object dropped"], [0, 1, 2], 5),
    # A rotation_y of 1e308 rad gave a box of arbitrary heading without a word.
    ("label-rotation-turns", "label_2/000001.txt",
     lambda d: replace_line(d, 1, b" ".join(d.split(b"\n")[1].split()[:14] + [b"1e308"])),
     ["line 2: rotation_y: expected an angle within +-12.57 rad (two turns), got '1e308'; object dropped, sample "
      "000001 written without it"], [0, 1, 2], 5),
    ("label-negative-size", "label_2/000001.txt",
     lambda d: replace_line(d, 1, d.split(b"\n")[1].replace(b"1.67 1.87 3.69", b"1.67 -1.87 3.69")),
     ["line 2: dimensions: expected non-negative height, width, length, got 1.67 -1.87 3.69"], [0, 1, 2], 5),
    ("label-occluded-fraction", "label_2/000001.txt",
     lambda d: replace_line(d, 0, d.split(b"\n")[0].replace(b"0.00 0 -1.57", b"0.00 1.5 -1.57")),
     ["line 1: occluded: expected an integer -1..3, got '1.5'"], [0, 1, 2], 5),
    ("r0-rect-zeros", "calib/000002.txt", lambda d: replace_line(d, 4, calib_line("R0_rect", np.zeros(9))),
     ["R0_rect: expected a rotation", "sample 000002 skipped"], [0, 1], None),
    ("tr-not-rotation", "calib/000002.txt",
     lambda d: replace_line(d, 5, calib_line("Tr_velo_to_cam", object_calib("000002")["Tr_velo_to_cam"] * 1.1)),
     ["Tr_velo_to_cam: expected a rotation (max |R^T R - I| <= 0.01)", "sample 000002 skipped"], [0, 1], None),
    ("p3-singular", "calib/000002.txt", lambda d: replace_line(d, 3, calib_line("P3", np.zeros(12))),
     ["P3: expected a projection whose left 3x3 block (intrinsics K, fx > 0, fy > 0) is invertible"], [0, 1], None),
    ("calib-nan", "calib/000002.txt", lambda d: replace_line(d, 2, calib_line("P2", [float("nan")] * 12)),
     ["line 3: P2: expected finite numbers"], [0, 1], None),
    # A finite but absurd translation or focal length reached the scene writer, which refused the whole scene
    # (all three samples) naming the source folder, not the calibration file.
    ("tr-translation-huge", "calib/000002.txt",
     lambda d: replace_line(d, 5, calib_line("Tr_velo_to_cam", _with(object_calib("000002")["Tr_velo_to_cam"], 3, 1e30))),
     ["line 6: Tr_velo_to_cam: expected values within 1e+07, got 1.000000000000e+30", "sample 000002 skipped"], [0, 1],
     None),
    ("p2-focal-huge", "calib/000002.txt",
     lambda d: replace_line(d, 2, calib_line("P2", _with(object_calib("000002")["P2"], 0, 1e12))),
     ["line 3: P2: expected values within 1e+06, got 1.000000000000e+12", "sample 000002 skipped"], [0, 1], None),
]


def _with(values: np.ndarray, index: int, value: float) -> np.ndarray:
    out = values.copy()
    out[index] = value
    return out


@pytest.mark.parametrize("case", OBJECT_CASES, ids=[c[0] for c in OBJECT_CASES])
def test_object_bad_input_loses_only_its_record(tmp_path, case):
    _, name, edit, messages, samples, n_objects = case
    src = object_copy(tmp_path / "src")
    rewrite(src / "training" / name, edit)
    result = run_conversion(KittiObjectConverter(ConvertConfig(src=src, dst=tmp_path / "out", quiet=True)))
    (error,) = [p for p in result.problems if p.severity == "error"]
    assert error.file.endswith(name)
    for message in messages:
        assert message in error.message
    assert "\n" not in error.message
    dataset = DatasetReader(tmp_path / "out")
    assert dataset.scene("training_000000").metadata["kitti_sample_ids"] == samples
    if n_objects is not None:
        assert dataset.objects().num_rows == n_objects  # 6 real objects (no DontCare) minus the bad line's


def test_object_rotation_off_by_more_than_noise_is_repaired_with_a_warning(tmp_path):
    src = object_copy(tmp_path / "src")
    rewrite(src / "training" / "calib" / "000002.txt", lambda d: replace_line(d, 5, calib_line("Tr_velo_to_cam", _r_off())))
    result = run_conversion(KittiObjectConverter(ConvertConfig(src=src, dst=tmp_path / "out", quiet=True)))
    assert result.n_errors == 0
    (warning,) = result.problems
    assert warning.file.endswith("calib/000002.txt")
    assert warning.message.startswith("Tr_velo_to_cam: rotation off orthonormality by 0.0001")
    assert DatasetReader(tmp_path / "out").scene("training_000000").metadata["kitti_sample_ids"] == [0, 1, 2]


def tracking_copy(root: Path) -> Path:
    shutil.copytree(REAL / "tracking" / "training", root / "training", symlinks=True,
                    ignore=shutil.ignore_patterns("label_02", "oxts"))
    for folder in ("label_02", "oxts"):
        (root / "training" / folder).mkdir()
        shutil.copy(REAL / "tracking" / "training" / folder / "0001.txt", root / "training" / folder / "0001.txt")
    return root


def _tracking_lines() -> list[str]:
    return (REAL / "tracking" / "training" / "label_02" / "0001.txt").read_text().splitlines()


def _first_object_line(frame: int, skip: int = 0) -> int:
    lines = _tracking_lines()
    return [i for i, line in enumerate(lines) if line.startswith(f"{frame} ") and "DontCare" not in line][skip]


def _edit_field(line_index: int, field: int, value: str):
    def edit(data: bytes) -> bytes:
        fields = data.split(b"\n")[line_index].split(b" ")
        fields[field] = value.encode()
        return replace_line(data, line_index, b" ".join(fields))
    return edit


def tracking_cases() -> list[tuple]:
    """The cases, built from the real labels when a test runs (never at import)."""
    l3 = _first_object_line(3)
    l4a, l4b = _first_object_line(4), _first_object_line(4, 1)
    return [
        ("box-nan", "label_02/0001.txt", _edit_field(l3, 13, "nan"),
         f"line {l3 + 1}: x: expected a finite number, got 'nan'; object dropped, frame 3 written without it", 447, 1),
        ("negative-id", "label_02/0001.txt", _edit_field(l3, 1, "-4"),
         f"line {l3 + 1}: track id: expected a non-negative id on a {_tracking_lines()[l3].split()[2]}, got '-4'; "
         f"object dropped, frame 3 written without it", 447, 1),
        ("duplicate-id", "label_02/0001.txt", _edit_field(l4b, 1, _tracking_lines()[l4a].split()[1]),
         f"line {l4b + 1}: track id: expected ids unique within frame 4, got {_tracking_lines()[l4a].split()[1]} again "
         f"(first on line {l4a + 1}); object dropped, frame 4 written without it", 447, 1),
        ("oxts-nan", "oxts/0001.txt", _edit_field(10, 5, "nan"),
         "line 11: value 6 (yaw): expected a finite number, got 'nan'; frame 10 skipped (no pose)", 446, 0),
        # A 20-digit track id overflowed the int64 column: an OverflowError traceback that lost the conversion.
        ("huge-id", "label_02/0001.txt", _edit_field(l3, 1, "9" * 20),
         f"line {l3 + 1}: track id: expected an integer below 2^31, got '{'9' * 20}'; object dropped, frame 3 "
         f"written without it", 447, 1),
        # A latitude of 1e308 or a yaw of 1e30 rad gave frame 10 a meaningless pose without a word; an altitude of
        # 1e308 m reached the scene writer, which refused the whole sequence, naming the source folder.
        ("oxts-latitude", "oxts/0001.txt", _edit_field(10, 0, "1e308"),
         "line 11: value 1 (lat): expected a value within +-90 deg, got '1e308'; frame 10 skipped (no pose)", 446, 0),
        ("oxts-yaw", "oxts/0001.txt", _edit_field(10, 5, "1e30"),
         "line 11: value 6 (yaw): expected a value within +-pi, got '1e30'; frame 10 skipped (no pose)", 446, 0),
        ("oxts-altitude", "oxts/0001.txt", _edit_field(10, 2, "1e308"),
         "line 11: value 3 (alt): expected a value within +-1e+07 m, got '1e308'; frame 10 skipped (no pose)", 446, 0),
    ]


TRACKING_CASE_IDS = ["box-nan", "negative-id", "duplicate-id", "oxts-nan", "huge-id", "oxts-latitude", "oxts-yaw",
                     "oxts-altitude"]


@pytest.fixture(scope="module")
def clean_tracking_objects(tmp_path_factory) -> int:
    dst = tmp_path_factory.mktemp("clean_tracking")
    assert run_conversion(KittiTrackingConverter(ConvertConfig(src=REAL / "tracking", dst=dst, quiet=True))).n_errors == 0
    return DatasetReader(dst).objects().num_rows


@pytest.mark.parametrize("case_id", TRACKING_CASE_IDS)
def test_tracking_bad_input_loses_only_its_record(tmp_path, case_id, clean_tracking_objects):
    (case,) = [c for c in tracking_cases() if c[0] == case_id]
    _, name, edit, message, n_frames, objects_lost = case
    src = tracking_copy(tmp_path / "src")
    rewrite(src / "training" / name, edit)
    result = run_conversion(KittiTrackingConverter(ConvertConfig(src=src, dst=tmp_path / "out", quiet=True)))
    (error,) = [p for p in result.problems if p.severity == "error"]
    assert error.file.endswith(name) and error.message == message
    dataset = DatasetReader(tmp_path / "out")
    assert dataset.frames().num_rows == n_frames
    if name.startswith("label"):
        assert dataset.objects().num_rows == clean_tracking_objects - objects_lost


def raw_copy(root: Path, n_packets: int) -> Path:
    date = root / "2011_09_26"
    shutil.copytree(REAL / "raw" / "2011_09_26", date, symlinks=True)
    drive = date / "2011_09_26_drive_0001_sync"
    packet = (drive / "oxts" / "data" / "0000000000.txt").read_text()
    shutil.rmtree(drive / "oxts" / "data")
    (drive / "oxts" / "data").mkdir()
    for frame in range(n_packets):
        (drive / "oxts" / "data" / f"{frame:010d}.txt").write_text(packet)
    (drive / "oxts" / "timestamps.txt").unlink()
    shutil.copy(REAL / "raw" / "2011_09_26" / "2011_09_26_drive_0001_sync" / "oxts" / "timestamps.txt",
                drive / "oxts" / "timestamps.txt")
    return root


def raw_errors(tmp_path: Path, src: Path) -> tuple[list[str], DatasetReader]:
    result = run_conversion(KittiRawConverter(ConvertConfig(src=src, dst=tmp_path / "out", quiet=True)))
    return [f"{Path(p.file).name}: {p.message}" for p in result.problems if p.severity == "error"], \
        DatasetReader(tmp_path / "out")


def test_raw_missing_oxts_packets_are_one_line(tmp_path):
    errors, dataset = raw_errors(tmp_path, REAL / "raw")
    assert errors == ["data: frames 1-107: oxts packet missing; skipped (no pose)"]
    assert dataset.frames().num_rows == 1


def test_raw_timestamps_shorter_than_packets_are_named(tmp_path):
    src = raw_copy(tmp_path / "src", 108)
    times = src / "2011_09_26" / "2011_09_26_drive_0001_sync" / "oxts" / "timestamps.txt"
    times.write_text("\n".join(times.read_text().splitlines()[:20]) + "\n")
    errors, dataset = raw_errors(tmp_path, src)
    assert errors == ["timestamps.txt: expected a time per oxts packet, got 20 lines for 108 packets; "
                      "frames 20-107 skipped (no time)"]
    assert dataset.frames().num_rows == 20


def test_raw_duplicate_timestamp_loses_that_frame(tmp_path):
    src = raw_copy(tmp_path / "src", 10)
    times = src / "2011_09_26" / "2011_09_26_drive_0001_sync" / "oxts" / "timestamps.txt"
    lines = times.read_text().splitlines()
    lines[5] = lines[4]
    times.write_text("\n".join(lines) + "\n")
    errors, dataset = raw_errors(tmp_path, src)
    assert errors[0].startswith("timestamps.txt: line 6: expected times increasing, got ")
    assert errors[0].endswith("; frame 5 skipped")
    assert errors[1] == "data: frames 10-107: oxts packet missing; skipped (no pose)"
    assert dataset.frames().num_rows == 9
    assert np.all(np.diff(dataset.frames().column("timestamp_ns").to_numpy()) > 0)


def test_raw_duplicate_sensor_timestamp_loses_that_message_only(tmp_path):
    """Real object sweeps stand in for the drive's (absent) velodyne files; the sensor's own times repeat once."""
    src = raw_copy(tmp_path / "src", 3)
    velo = src / "2011_09_26" / "2011_09_26_drive_0001_sync" / "velodyne_points"
    times_path = velo / "timestamps.txt"
    lines = times_path.read_text().splitlines()
    lines[1] = lines[0]
    times_path.unlink()
    times_path.write_text("\n".join(lines) + "\n")
    (velo / "data").mkdir(exist_ok=True)
    for frame in range(3):
        (velo / "data" / f"{frame:010d}.bin").symlink_to(REAL / "object" / "training" / "velodyne" / f"00000{frame}.bin")
    errors, dataset = raw_errors(tmp_path, src)
    assert errors == ["data: frames 3-107: oxts packet missing; skipped (no pose)",
                      "timestamps.txt: line 2: expected times increasing, got repeated or earlier times; "
                      "frame 1 written without this sensor"]
    assert dataset.frames().num_rows == 3
    times = [dict(t) for t in dataset.frames().column("sensor_timestamps_ns").to_pylist()]
    assert ["ego/velodyne" in t for t in times] == [True, False, True]
    scene = dataset.scenes[0]
    raw = np.fromfile(REAL / "object" / "training" / "velodyne" / "000002.bin", dtype="<f4").reshape(-1, 4)
    np.testing.assert_array_equal(dataset.points(scene, 2, "ego/velodyne")["x"], raw[:, 0])


def test_raw_packet_named_far_beyond_the_timestamps_is_named_not_enumerated(tmp_path):
    # 99999999999.txt made a list of the 10^11 frames up to it: a MemoryError traceback (or the machine's memory).
    src = raw_copy(tmp_path / "src", 108)
    data = src / "2011_09_26" / "2011_09_26_drive_0001_sync" / "oxts" / "data"
    shutil.copy(data / "0000000005.txt", data / "99999999999.txt")
    errors, dataset = raw_errors(tmp_path, src)
    assert errors == ["timestamps.txt: expected a time per oxts packet, got 108 lines for 100000000000 packets; "
                      "frames 99999999999 skipped (no time)"]
    assert dataset.frames().num_rows == 108
