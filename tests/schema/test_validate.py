"""validate_dataset: one problem per line, naming scene, topic and time."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from avdata.frames import Boxes3D, Transform
from avdata.schema import DatasetWriter, ObjectLabels
from avdata.schema.validate import validate_dataset
from tests.schema.conftest import T0, cloud


def test_clean_dataset_has_no_problems(dataset: Path) -> None:
    assert validate_dataset(dataset) == []


def test_unresolvable_frames_and_times_are_reported(tmp_path: Path) -> None:
    with DatasetWriter(tmp_path / "ds", source="unit-test") as writer:
        with writer.scene("s") as scene:
            scene.add_agent("ego", kind="vehicle", origin="rear axle")
            scene.add_static_transform("ego", "ego/lidar", Transform.identity())
            scene.add_transform("world", "ego", T0, Transform.identity())
            scene.add_transform("world", "ego", T0 + 100, Transform.identity())
            scene.add_point_cloud("ego/lidar", T0 + 50, cloud(0, 10))
            scene.add_point_cloud("ego/lidar", T0 + 500, cloud(1, 10))
            scene.add_point_cloud("ego/radar", T0 + 50, cloud(2, 10))
            boxes = Boxes3D.from_yaw([[1.0, 2.0, 0.5]], [[4.0, 2.0, 1.5]], [0.0], "ego", ids=["1"], classes=["car"])
            scene.add_frame(0, T0 + 50, ObjectLabels(boxes=boxes))
    problems = [str(p) for p in validate_dataset(tmp_path / "ds")]
    assert len(problems) == 2, problems
    assert problems[0].startswith(f"s: /ego/lidar/points @ {T0 + 500} ns: frame 'ego/lidar' not resolvable")
    assert "extrapolation into the future" in problems[0]
    assert problems[1].startswith(f"s: /ego/radar/points @ {T0 + 50} ns: frame 'ego/radar' not resolvable")
    assert all("\n" not in p for p in problems)


def test_calibrations_need_their_frame_in_the_tree_not_a_pose_at_their_time(tmp_path: Path) -> None:
    # KITTI tracking with line 1 of oxts NaN: frame 0 has no pose, so poses start after the calibrations'
    # time; validate used to call that scene broken although every frame and reading resolves.
    K = np.array([[700.0, 0.0, 600.0], [0.0, 700.0, 180.0], [0.0, 0.0, 1.0]])
    with DatasetWriter(tmp_path / "ds", source="unit-test") as writer:
        with writer.scene("s") as scene:
            scene.add_agent("ego", kind="vehicle", origin="rear axle")
            scene.add_static_transform("ego", "ego/cam", Transform.identity())
            scene.add_camera_calibration("ego/cam", T0, K, 1242, 375)
            scene.add_camera_calibration("ego/ghost", T0, K, 1242, 375)
            scene.add_transform("world", "ego", T0 + 100, Transform.identity())
            scene.add_frame(0, T0 + 100, ObjectLabels.empty("world"))
    problems = [str(p) for p in validate_dataset(tmp_path / "ds")]
    assert problems == [f"s: /ego/ghost/calibration @ {T0} ns: frame 'ego/ghost' is not in the frame tree"]


def test_unlisted_scene_and_missing_index_are_reported(dataset: Path, tmp_path: Path) -> None:
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    shutil.copy(copy / "scenes" / "scene-b.mcap", copy / "scenes" / "scene-z.mcap")
    (copy / "index" / "visibility.parquet").unlink()
    problems = [str(p) for p in validate_dataset(copy)]
    assert "scene-z: - @ - ns: scene file not listed in avdata.json; run 'avdata index'" in problems
    assert "-: index/visibility.parquet @ - ns: index table missing; run 'avdata index'" in problems
    assert np.all([p.count("\n") == 0 for p in problems])


def test_labels_with_non_finite_boxes_are_refused_before_writing() -> None:
    import pytest

    from avdata.errors import AvdataError

    boxes = Boxes3D.from_yaw([[np.nan, 0.0, 0.0]], [[4.0, 2.0, 1.5]], [0.0], "world", ids=["7"], classes=["car"])
    with pytest.raises(AvdataError, match=r"NaN or inf for object ids \['7'\]"):
        ObjectLabels(boxes=boxes)


def test_a_manifest_changed_after_writing_is_reported(dataset: Path, tmp_path: Path) -> None:
    import json
    import shutil

    import pytest

    from avdata.errors import InputError
    from avdata.schema import DatasetReader

    original = (dataset / "avdata.json").read_text()
    assert json.loads(original)["crc32"] > 0
    cases = {
        "value": original.replace('"unit-test"', '"unit-tesT"'),  # valid JSON, another word
        "white space": original.replace('{\n  "', '{\n \t"', 1),  # the same values
        "crc": original.replace(f'"crc32": {json.loads(original)["crc32"]}', '"crc32": 1'),
    }
    expected = {"value": "of the manifest's content, got", "white space": "differs from its canonical form",
                "crc": "expected CRC-32 1 of the manifest's content"}
    for case, text in cases.items():
        assert text != original, case
        copy = tmp_path / case.replace(" ", "-")
        shutil.copytree(dataset, copy)
        (copy / "avdata.json").write_text(text)
        problems = [str(p) for p in validate_dataset(copy)]
        assert len(problems) == 1 and expected[case] in problems[0], (case, problems)
        assert problems[0].startswith(f"-: avdata.json @ - ns: {copy / 'avdata.json'}: ")
        with pytest.raises(InputError, match="avdata.json"):  # also without verify: the check costs nothing
            DatasetReader(copy)
