"""The fast paths of ``avdata.sources.kitti``: memory-mapped velodyne scans and calibrations parsed once per text."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from avdata.errors import InputError
from avdata.sources.kitti import VELODYNE_DTYPE, read_calib, read_velodyne, velo_T_sensors
from avdata.sources.kitti.geometry import _velo_T_sensors
from tests.realdata import REALDATA

OBJECT = REALDATA / "kitti" / "object" / "training"
#: The three real samples (named, not listed: nothing is read at import)
SCANS = [OBJECT / "velodyne" / f"{name}.bin" for name in ("000000", "000001", "000002")]
CALIBS = [OBJECT / "calib" / f"{name}.txt" for name in ("000000", "000001", "000002")]


@pytest.mark.parametrize("path", SCANS, ids=[p.name for p in SCANS])
def test_mapped_scan_equals_the_file_read_whole(path: Path) -> None:
    points = read_velodyne(path)
    assert points.dtype == VELODYNE_DTYPE and not points.flags.writeable
    assert points.tobytes() == path.read_bytes() and len(points) == path.stat().st_size // 16
    np.testing.assert_array_equal(points["intensity"], np.fromfile(path, dtype="<f4").reshape(-1, 4)[:, 3])


def test_torn_and_empty_scans(tmp_path: Path) -> None:
    torn = tmp_path / "torn.bin"
    torn.write_bytes(SCANS[0].read_bytes()[:1001])
    with pytest.raises(InputError, match=r"torn\.bin: expected a size that is a multiple of 16 bytes .* got 1001 bytes"):
        read_velodyne(torn)
    empty = tmp_path / "empty.bin"
    empty.write_bytes(b"")  # was read as an empty cloud and written without a word
    with pytest.raises(InputError, match=r"empty\.bin: expected the points of a sweep, got an empty file \(0 bytes\)"):
        read_velodyne(empty)


def test_calibration_of_the_same_text_is_shared_but_warnings_name_each_file(tmp_path: Path) -> None:
    text = CALIBS[0].read_text()
    first, second = tmp_path / "000000.txt", tmp_path / "000001.txt"
    first.write_text(text)
    second.write_text(text)
    a, b = read_calib(first), read_calib(second)
    assert a.P is b.P and not a.P.flags.writeable  # parsed and checked once; nobody can change the shared copy
    fresh = read_calib(CALIBS[0])
    np.testing.assert_array_equal(a.velo_to_cam, fresh.velo_to_cam)
    # R0_rect scaled by 1.001: repaired with a warning, which must name the file it came from.
    lines = text.splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("R0_rect"))
    values = [float(v) * 1.001 for v in lines[k].split()[1:]]
    lines[k] = "R0_rect: " + " ".join(f"{v:.12e}" for v in values)
    for path in (first, second):
        path.write_text("\n".join(lines) + "\n")
    warned = [read_calib(path).warnings for path in (first, second)]
    assert [w[0][0] for w in warned] == [str(first), str(second)]
    assert warned[0][0][1] == warned[1][0][1] and "R0_rect" in warned[0][0][1]
    # A broken file is still reported with its own path and line, whatever was cached before.
    broken = tmp_path / "000002.txt"
    broken.write_text(text.replace("P2:", "P2: nan", 1))
    with pytest.raises(InputError, match=r"000002\.txt: line 3: expected 12 values for P2"):
        read_calib(broken)


@pytest.mark.parametrize("path", CALIBS, ids=[p.name for p in CALIBS])
def test_cached_sensor_poses_equal_a_fresh_computation(path: Path) -> None:
    calib = read_calib(path)
    cached, fresh = velo_T_sensors(calib), _velo_T_sensors(calib)
    assert velo_T_sensors(calib) is not cached  # each caller gets its own dict
    assert list(cached) == list(fresh)
    for name, pose in fresh.items():
        assert np.array_equal(cached[name].rotation, pose.rotation)
        assert np.array_equal(cached[name].translation, pose.translation)
