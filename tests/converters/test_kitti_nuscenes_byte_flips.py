"""Hypothesis flips and truncates bytes of real KITTI and Lyft (nuScenes-schema) source files: a conversion
either succeeds, reporting problems, or stops with avdata's own one-line error; nothing else is raised
(Issue 16.2 for the KITTI and nuScenes sources)."""

from __future__ import annotations

import shutil
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.kitti import KittiObjectConverter, KittiTrackingConverter
from avdata.converters.nuscenes import NuScenesConverter
from avdata.errors import AvdataError
from tests.realdata import REALDATA

KITTI = REALDATA / "kitti"
LYFT = REALDATA / "nuscenes_schema" / "lyft" / "v1.01-train"

#: (converter, source files that can be damaged, relative to the layout root)
OBJECT_FILES = ["training/label_2/000001.txt", "training/calib/000001.txt"]
TRACKING_FILES = ["training/label_02/0001.txt", "training/calib/0001.txt", "training/oxts/0001.txt"]
LYFT_FILES = [f"v1.01-train/{name}.json" for name in ("sample_annotation", "sample_data", "ego_pose", "calibrated_sensor",
                                                     "sample", "scene", "instance", "sensor")]

damage = st.tuples(st.floats(0.0, 1.0, exclude_max=True), st.integers(0, 255), st.booleans())


def damaged(data: bytes, where: float, value: int, truncate: bool) -> bytes:
    position = int(where * len(data))
    if truncate:
        return data[:position]
    return data[:position] + bytes([value if value != data[position] else (value + 1) % 256]) + data[position + 1:]


def layout(kind: str, root: Path) -> Path:
    if kind == "object":
        for folder in ("calib", "label_2"):
            (root / "training" / folder).mkdir(parents=True)
            for sample in ("000000", "000001"):
                shutil.copy(KITTI / "object" / "training" / folder / f"{sample}.txt", root / "training" / folder)
    elif kind == "tracking":
        for folder in ("calib", "label_02", "oxts"):
            (root / "training" / folder).mkdir(parents=True)
            shutil.copy(KITTI / "tracking" / "training" / folder / "0001.txt", root / "training" / folder)
    else:
        shutil.copytree(LYFT / "v1.01-train", root / "v1.01-train")
    return root


CONVERTERS = {"object": KittiObjectConverter, "tracking": KittiTrackingConverter, "lyft": NuScenesConverter}
FILES = {"object": OBJECT_FILES, "tracking": TRACKING_FILES, "lyft": LYFT_FILES}


def check(kind: str, tmp: Path, file_index: int, change: tuple[float, int, bool]) -> None:
    root = layout(kind, tmp / "src")
    path = root / FILES[kind][file_index % len(FILES[kind])]
    path.write_bytes(damaged(path.read_bytes(), *change))
    try:
        result = run_conversion(CONVERTERS[kind](ConvertConfig(src=root, dst=tmp / "out", quiet=True)))
    except AvdataError as error:
        assert "\n" not in str(error)
        return
    for problem in result.problems:
        assert "\n" not in problem.message


def run(kind: str, tmp_path_factory, file_index: int, change: tuple[float, int, bool]) -> None:
    tmp = tmp_path_factory.mktemp(kind)
    check(kind, tmp, file_index, change)


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(file_index=st.integers(0, 7), change=damage)
def test_damaged_kitti_object_files(tmp_path_factory, file_index, change):
    run("object", tmp_path_factory, file_index, change)


@settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(file_index=st.integers(0, 7), change=damage)
def test_damaged_kitti_tracking_files(tmp_path_factory, file_index, change):
    run("tracking", tmp_path_factory, file_index, change)


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(file_index=st.integers(0, 7), change=damage)
def test_damaged_lyft_tables(tmp_path_factory, file_index, change):
    run("lyft", tmp_path_factory, file_index, change)
