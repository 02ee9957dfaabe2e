"""Hypothesis flips and truncates bytes of real Argoverse 2 feather and Waymo v2 Parquet files: a conversion
either succeeds, reporting problems, or stops with avdata's own one-line error; nothing else is raised (issue 33.7:
pyarrow raises SystemError, UnicodeDecodeError, ... on damaged bytes, and each is damage of that file)."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import pyarrow.feather as feather
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.argoverse2 import Argoverse2Converter
from avdata.converters.waymo import WaymoConverter
from avdata.errors import AvdataError
from tests.converters.test_argoverse2 import LOG
from tests.converters.test_argoverse2_bad_input import layout
from tests.converters.test_kitti_nuscenes_byte_flips import damage, damaged

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "oracles"))
from waymo_fixture import waymo_v2_fixture  # noqa: E402

AV2_FILES = ["annotations.feather", "city_SE3_egovehicle.feather", "calibration/egovehicle_SE3_sensor.feather",
             "calibration/intrinsics.feather"]
WAYMO_COMPONENTS = ["vehicle_pose", "lidar_box", "lidar_calibration", "camera_calibration", "projected_lidar_box", "stats"]


def check(converter: type, root: Path, dst: Path) -> None:
    try:
        result = run_conversion(converter(ConvertConfig(src=root, dst=dst, quiet=True)))
    except AvdataError as error:
        assert "\n" not in str(error)
        return
    for problem in result.problems:
        assert "\n" not in problem.message


def flip(path: Path, change: tuple[float, int, bool]) -> None:
    data = path.read_bytes()
    path.unlink()  # a link to the real file is replaced, never written through
    path.write_bytes(damaged(data, *change))


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(file_index=st.integers(0, 3), change=damage)
def test_damaged_argoverse2_feather_files(tmp_path_factory, file_index, change):
    tmp = tmp_path_factory.mktemp("av2")
    root = layout(tmp / "src")
    flip(root / "val" / LOG / AV2_FILES[file_index], change)
    check(Argoverse2Converter, root, tmp / "out")


@pytest.mark.oracle
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(file_index=st.integers(0, 5), change=damage)
def test_damaged_waymo_parquet_files(tmp_path_factory, file_index, change):
    fixture, info = waymo_v2_fixture()
    tmp = tmp_path_factory.mktemp("waymo")
    root = tmp / "src"
    shutil.copytree(fixture, root, ignore=shutil.ignore_patterns("*.npz", "*.json"))
    flip(root / WAYMO_COMPONENTS[file_index] / f"{info['context']}.parquet", change)
    check(WaymoConverter, root, tmp / "out")


def test_the_flip_that_raised_system_error_is_one_line(tmp_path):
    # A byte flipped in a string column's offsets made pyarrow raise "SystemError: Negative size passed to
    # PyUnicode_New", which the reader did not catch.
    root = layout(tmp_path / "src")
    path = root / "val" / LOG / "annotations.feather"
    data = bytearray(path.read_bytes())
    offsets = feather.read_table(path).column("category").chunk(0).buffers()[1]
    values = np.frombuffer(offsets, dtype=np.int32)
    start = data.find(values[:16].tobytes())
    assert start > 0
    data[start + 4 * 3: start + 4 * 4] = np.int32(-1000).tobytes()
    path.unlink()
    path.write_bytes(bytes(data))
    result = run_conversion(Argoverse2Converter(ConvertConfig(src=root, dst=tmp_path / "out", quiet=True)))
    errors = [p for p in result.problems if p.severity == "error"]
    assert len(errors) == 1 and errors[0].file == str(path) and "unreadable feather file" in errors[0].message
