"""Bad OPV2V / V2XSet / V2V4Real input costs the frame or camera it is in (issue 34), with one line naming the
file and field; hostile copies of the real V2XSet frame (tests/converters/opv2v_fixtures.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.opv2v import Opv2vConverter
from avdata.schema import DatasetReader
from avdata.schema.validate import validate_dataset
from tests.converters.opv2v_fixtures import build_opv2v, build_v2v4real


def edit(path: Path, change) -> None:
    data = yaml.safe_load(path.read_text())
    change(data)
    path.write_text(yaml.safe_dump(data))


def convert(tmp_path: Path):
    result = run_conversion(Opv2vConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "dst", quiet=True)))
    assert validate_dataset(tmp_path / "dst") == []
    return result, [str(p) for p in result.problems if p.severity == "error"], \
        [str(p) for p in result.problems if p.severity == "warning"]


def test_an_ego_pose_of_1e30_costs_that_frame(tmp_path: Path) -> None:
    # The scene writer refused it, and the scenario was lost.
    scenario = build_opv2v(tmp_path / "src")
    path = scenario / "4279" / "000071.yaml"
    edit(path, lambda data: data["lidar_pose"].__setitem__(0, 1e30))
    result, errors, _ = convert(tmp_path)
    assert len(result.written) == 1 and len(errors) == 1
    assert f"{path}: field lidar_pose: expected a position within 1e+07 m, got [1e+30" in errors[0]
    assert DatasetReader(tmp_path / "dst").frames().num_rows == 2


def test_an_all_zero_camera_matrix_costs_that_camera_in_that_frame(tmp_path: Path) -> None:
    scenario = build_opv2v(tmp_path / "src")
    path = scenario / "4279" / "000071.yaml"
    edit(path, lambda data: data["camera0"].__setitem__("intrinsic", np.zeros((3, 3)).tolist()))
    result, errors, _ = convert(tmp_path)
    assert len(result.written) == 1 and len(errors) == 1
    assert f"{path}: field camera0.intrinsic: expected finite values with positive focal lengths, got [0.0" in errors[0]
    assert errors[0].endswith("; image skipped")
    reader = DatasetReader(tmp_path / "dst")
    scene = reader.scene(result.written[0])
    assert reader.frames().num_rows == 3 and len(scene.times("/ego/camera0/image")) == 2


def test_a_frame_without_vehicles_is_a_warning(tmp_path: Path) -> None:
    # Its objects were dropped without a word.
    scenario = build_opv2v(tmp_path / "src")
    path = scenario / "4288" / "000071.yaml"
    edit(path, lambda data: data.pop("vehicles"))
    result, errors, warnings = convert(tmp_path)
    assert errors == [] and len(result.written) == 1
    mine = [w for w in warnings if str(path) in w]
    assert len(mine) == 1 and mine[0].endswith(f"{path}: field vehicles: expected the labelled objects (an empty mapping "
                                               "when none), got no such field; this agent labels no object in this frame")


def test_v2v4real_rotation_scaled_is_refused_and_near_one_repaired_with_a_warning(tmp_path: Path) -> None:
    # A rotation scaled x2 (|R^T R - I| = 3) was written as a yaw of 12.6 deg instead of 11.0 deg.
    scenario = build_v2v4real(tmp_path / "src")
    files = sorted((scenario / "0").glob("*.yaml"))
    scaled, nudged = files[1], files[2]

    def scale(factor: float):
        def change(data: dict) -> None:
            pose = np.asarray(data["lidar_pose"], dtype=np.float64)
            pose[:3, :3] *= factor
            data["lidar_pose"] = pose.tolist()
        return change

    edit(scaled, scale(2.0))
    edit(nudged, scale(1.001))
    result, errors, warnings = convert(tmp_path)
    assert len(errors) == 1 and f"{scaled}: field lidar_pose: expected a rotation (max |R^T R - I| <= 0.01)" in errors[0]
    assert "(deviation 3)" in errors[0]
    assert any(f"{nudged}: field lidar_pose: rotation off orthonormality by 0.002" in w for w in warnings)
    assert DatasetReader(tmp_path / "dst").frames().num_rows == 2


def _first_vehicle(data: dict) -> dict:
    return data["vehicles"][min(data["vehicles"])]


@pytest.mark.parametrize(("change", "message"), [
    # Accepted without a word: an RSU flag of "garbage" made the CAV an RSU; an angle of 1e308 deg gave a box of
    # arbitrary heading; a speed of -1 km/h reversed its velocity; YAML true was read as the number 1.
    (lambda d: d.update(RSU="garbage"), "field RSU: expected true or false, got 'garbage'"),
    (lambda d: d["lidar_pose"].__setitem__(4, 1e308), "field lidar_pose: expected angles within +-720 deg, got [-0.0029"),
    (lambda d: d["lidar_pose"].__setitem__(0, True), "field lidar_pose: expected numbers, got [True, "),
    (lambda d: _first_vehicle(d)["angle"].__setitem__(1, 1e308), ".angle: expected angles within +-720 deg, got "),
    (lambda d: _first_vehicle(d).update(speed=-1.0), ".speed: expected km/h in [0, 3600], got -1.0"),
])
def test_a_value_of_the_wrong_kind_costs_its_frame_or_vehicle(tmp_path: Path, change, message: str) -> None:
    scenario = build_opv2v(tmp_path / "src")
    path = scenario / "4288" / "000071.yaml"
    edit(path, change)
    result, errors, _ = convert(tmp_path)
    assert len(result.written) == 1 and len(errors) == 1 and f"{path}: " in errors[0] and message in errors[0]
    assert DatasetReader(tmp_path / "dst").frames().num_rows == 3


def test_v2v4real_a_class_that_is_not_text_costs_that_vehicle(tmp_path: Path) -> None:
    # obj_type null became the class "None".
    scenario = build_v2v4real(tmp_path / "src")
    path = sorted((scenario / "0").glob("*.yaml"))[1]
    edit(path, lambda data: _first_vehicle(data).update(obj_type=None))
    result, errors, _ = convert(tmp_path)
    assert len(errors) == 1 and f"{path}: field vehicles.10.obj_type: expected a class name, got None" in errors[0]
    assert "None" not in DatasetReader(tmp_path / "dst").objects().column("source_class").to_pylist()


def test_a_yaml_alias_bomb_in_a_number_field_is_refused_without_building_it(tmp_path: Path) -> None:
    # Eight lines of aliases made a lidar_pose of 10^7 numbers (10^9 with two more lines: 8 GB, or a MemoryError
    # traceback) before its shape was checked.
    scenario = build_opv2v(tmp_path / "src")
    path = scenario / "4288" / "000071.yaml"
    bomb = ["l0: &l0 [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]"]
    bomb += [f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * 10) + "]" for i in range(1, 7)]
    text = path.read_text().replace("lidar_pose:", "old_pose:", 1)
    path.write_text(text + "\n".join(bomb) + "\nlidar_pose: *l6\n")
    result, errors, _ = convert(tmp_path)
    assert len(result.written) == 1
    assert errors == [f"error: {result.written[0]}: {path}: field lidar_pose: expected at most 64 numbers and lists, "
                      "got more"]
