"""V2V4Real cameras are not converted: its release publishes no camera calibration (docs/v2x.md).

What was checked: ucla-mobility/V2V4Real's ``opencood/data_utils/datasets/basedataset.py`` (the dataset
loader of its OpenCOOD fork) builds ``<frame>_camera0..3.png`` paths with ``load_camera_files`` (inherited
from OpenCOOD's OPV2V loader) and never opens them; no file of the repository reads a camera intrinsic or
extrinsic, and its frame YAMLs hold ``lidar_pose`` and ``vehicles``. OPV2V's ``cameraN.extrinsic`` is in
CARLA's Unreal camera axes (tests/converters/test_opv2v.py checks it on the real V2XSet file); for the real
V2V4Real lidars that convention would be a guess. So a V2V4Real agent folder holding ``cameraN`` entries
(here the real V2XSet file's four, copied into every frame) or ``_cameraN.png`` images is converted without
cameras, with one warning line per agent, and its lidar data and labels are kept.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.opv2v import Opv2vConverter
from avdata.schema import DatasetReader
from tests.converters.opv2v_fixtures import build_v2v4real, real_frame


def test_camera_entries_and_images_are_ignored_with_one_line_per_agent(tmp_path: Path) -> None:
    scenario = build_v2v4real(tmp_path / "src")
    cameras = {key: value for key, value in real_frame().items() if key.startswith("camera")}
    assert sorted(cameras) == ["camera0", "camera1", "camera2", "camera3"]
    for path in sorted((scenario / "0").glob("*.yaml")):
        data = yaml.safe_load(path.read_text())
        path.write_text(yaml.safe_dump({**data, **cameras}))
    (scenario / "1" / "000000_camera0.png").write_bytes(b"\x89PNG\r\n\x1a\n")  # never opened: not even checked
    result = run_conversion(Opv2vConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "dst", quiet=True)))
    scene = result.written[0]
    assert [(p.severity, p.file, p.message) for p in result.problems] == [
        ("warning", str(scenario / "0"), "V2V4Real cameras: expected none (the release publishes no camera "
                                         "calibration), got fields camera0, camera1, camera2, camera3; not converted"),
        ("warning", str(scenario / "1"), "V2V4Real cameras: expected none (the release publishes no camera "
                                         "calibration), got 1 images (000000_camera0.png ...); not converted")]
    reader = DatasetReader(tmp_path / "dst")
    assert sorted(reader.scene(scene).sensors()) == ["cav_1/lidar", "ego/lidar"]
    assert len(reader.scene(scene).frame_infos()) == 3


def test_without_camera_entries_or_images_nothing_is_said(tmp_path: Path) -> None:
    build_v2v4real(tmp_path / "src")
    result = run_conversion(Opv2vConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "dst", quiet=True)))
    assert result.problems == [] and len(result.written) == 1
