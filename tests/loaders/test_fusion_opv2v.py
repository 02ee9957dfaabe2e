"""Intermediate fusion over a converted OPV2V scene (built around the real V2XSet frame file in REALDATA):
OPV2V's GPS-noised ``predicted_ego_pos`` as the transmitted pose, checked against the source YAML with
OpenCOOD's ``x_to_world`` and the converter's reflection R = diag(1, -1, 1) of CARLA's left-handed world."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from avdata.converters.base import ConvertConfig, run_conversion
from avdata.converters.opv2v import Opv2vConverter
from avdata.loaders import Collaboration, FrameDataset, FrameOptions
from tests.converters.opv2v_fixtures import FRAMES, SCENARIO, build_opv2v
from tests.converters.test_opv2v import x_to_world
from tests.realdata import REALDATA

REFLECT = np.diag([1.0, -1.0, 1.0, 1.0])


@pytest.fixture(scope="module")
def converted(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    assert REALDATA.is_dir()
    root = tmp_path_factory.mktemp("opv2v_fusion")
    scenario = build_opv2v(root / "src")
    result = run_conversion(Opv2vConverter(ConvertConfig(src=root / "src", dst=root / "dst", quiet=True)))
    assert result.problems == []
    return scenario, root / "dst"


def frame_yaml(scenario: Path, agent: str, number: int) -> dict:
    with open(scenario / agent / f"{number:06d}.yaml") as stream:
        return yaml.safe_load(stream)


@pytest.mark.parametrize("source", ["true", "predicted"])
def test_pairwise_transforms_follow_the_chosen_pose_source(converted: tuple[Path, Path], source: str) -> None:
    scenario, dst = converted
    options = FrameOptions(sensors=("*/lidar",), frame="ego/lidar",
                           collaboration=Collaboration(agents=("*",), fusion="intermediate", pose_source=source))
    dataset = FrameDataset(dst, options, scenes=[f"validate.{SCENARIO}"])
    for k, number in enumerate(FRAMES):
        item = dataset[k]
        assert item["agents"] == ["ego", "cav_4288", "infra_1"]
        ego = frame_yaml(scenario, "4279", number)
        cav = frame_yaml(scenario, "4288", number)
        world_T_cav = x_to_world(cav["lidar_pose"])
        if source == "predicted":  # the GPS error of the vehicle moves its lidar with it
            world_T_cav = x_to_world(cav["predicted_ego_pos"]) @ np.linalg.inv(x_to_world(cav["true_ego_pos"])) @ world_T_cav
        expected = REFLECT @ np.linalg.inv(x_to_world(ego["lidar_pose"])) @ world_T_cav @ REFLECT
        np.testing.assert_allclose(item["pairwise_T"][1, 0].numpy(), expected, atol=1e-6)
        np.testing.assert_allclose(item["pairwise_T"][0, 1].numpy(), np.linalg.inv(expected), atol=1e-6)
