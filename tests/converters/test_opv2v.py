"""OPV2V / V2XSet and V2V4Real converter against OpenCOOD's formulas, written out here independently.

Oracle formulas (cited, re-implemented in this file, not imported from avdata):
- ``x_to_world`` and ``x1_to_x2``: OpenCOOD / V2V4Real ``opencood/utils/transformation_utils.py``.
- box corners: ``create_bbx(extent)`` and ``project_world_objects`` in ``opencood/utils/box_utils.py``
  (object pose = ``location + center`` with ``angle``; corners = x_to_world(object pose) @ ±extent).
- intensity: ``pcd_utils.pcd_to_np`` = open3d ``colors[:, 0]`` (checked with open3d itself).
- RH world: our ``world`` is CARLA's map with y negated (``diag(1, -1, 1)``).
The real V2XSet frame ``../shared/realdata/v2xset/.../4279/000069.yaml`` is the ego's first frame.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.opv2v import Opv2vConverter
from avdata.schema import DatasetReader
from avdata.schema.validate import validate_dataset
from avdata.sources.opv2v import boxes_from_carla
from tests.converters.opv2v_fixtures import FRAMES, HAND_BOX_ID, N_POINTS, REAL_YAML, build_opv2v, build_v2v4real, real_frame
from tests.converters.v2x_eval import check_eval_three_missed_one_false

SCENE = "validate.2021_08_21_17_30_41"
V2V4REAL_SCENE = "test.testoutput_CAV_data_2022-03-15-09-54-40_0"
REFLECT = np.diag([1.0, -1.0, 1.0])


def x_to_world(pose: list[float]) -> np.ndarray:
    """OpenCOOD ``transformation_utils.x_to_world``: [x, y, z, roll, yaw, pitch] degrees -> 4x4."""
    x, y, z, roll, yaw, pitch = pose
    c_y, s_y = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
    c_r, s_r = np.cos(np.radians(roll)), np.sin(np.radians(roll))
    c_p, s_p = np.cos(np.radians(pitch)), np.sin(np.radians(pitch))
    return np.array([
        [c_p * c_y, c_y * s_p * s_r - s_y * c_r, -c_y * s_p * c_r - s_y * s_r, x],
        [s_y * c_p, s_y * s_p * s_r + c_y * c_r, -s_y * s_p * c_r + c_y * s_r, y],
        [s_p, -c_p * s_r, c_p * c_r, z],
        [0.0, 0.0, 0.0, 1.0],
    ])


def create_bbx(extent: list[float]) -> np.ndarray:
    """OpenCOOD ``box_utils.create_bbx``: (8, 3) corners of half ``extent``."""
    e = extent
    return np.array([[e[0], -e[1], -e[2]], [e[0], e[1], -e[2]], [-e[0], e[1], -e[2]], [-e[0], -e[1], -e[2]],
                     [e[0], -e[1], e[2]], [e[0], e[1], e[2]], [-e[0], e[1], e[2]], [-e[0], -e[1], e[2]]])


def opencood_corners(vehicle: dict, parent_to_world: np.ndarray) -> np.ndarray:
    """(8, 3) corners in the parent's world as ``project_world_objects`` builds them."""
    loc, center, angle = vehicle["location"], vehicle["center"], vehicle["angle"]
    pose = [loc[0] + center[0], loc[1] + center[1], loc[2] + center[2], angle[0], angle[1], angle[2]]
    object_to_world = parent_to_world @ x_to_world(pose)
    corners = np.c_[create_bbx(vehicle["extent"]), np.ones(8)] @ object_to_world.T
    return corners[:, :3]


def same_corner_sets(a: np.ndarray, b: np.ndarray) -> float:
    """Largest distance from a corner of ``a`` to its nearest corner in ``b`` (orders differ under reflection)."""
    return float(np.max(np.min(np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2), axis=1)))


@pytest.fixture(scope="module")
def converted(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("opv2v")
    build_opv2v(root / "src")
    build_v2v4real(root / "src")
    result = run_conversion(Opv2vConverter(ConvertConfig(src=root / "src", dst=root / "dst", quiet=True)))
    assert result.problems == [] and sorted(result.written) == [V2V4REAL_SCENE, SCENE]
    return root / "src", root / "dst"


def _load(path: Path) -> dict:
    with open(path) as stream:
        return yaml.safe_load(stream)


def test_real_file_camera_extrinsic_is_camera_T_lidar() -> None:
    real = real_frame()
    lidar = x_to_world(real["lidar_pose"])
    for k in range(4):
        camera = real[f"camera{k}"]
        expected = np.linalg.inv(x_to_world(camera["cords"])) @ lidar
        np.testing.assert_allclose(np.asarray(camera["extrinsic"]), expected, atol=1e-9)


def test_agents_ego_rsu_and_sensors(converted: tuple[Path, Path]) -> None:
    _, dst = converted
    scene = DatasetReader(dst).scene(SCENE)
    agents = scene.metadata["agents"]
    assert agents["ego"] == {"kind": "vehicle", "object_id": "4279", "source_id": "4279",
                             "origin": "the LiDAR (lidar_pose), right-handed: x forward, y left, z up"}
    assert agents["cav_4288"]["kind"] == "vehicle" and agents["infra_1"]["kind"] == "infrastructure"
    assert scene.ego_frame() == "ego" and scene.metadata["variant"] == "opv2v"
    assert {"ego/lidar", "cav_4288/lidar", "infra_1/lidar", "ego/camera0"} <= set(scene.sensors())
    assert scene.sensors()["ego/camera0"]["width"] == 800
    assert [i.timestamp_ns for i in scene.frame_infos()] == [(n - FRAMES[0]) * 50_000_000 for n in FRAMES]
    assert validate_dataset(dst) == []


def test_world_boxes_equal_opencood_formula(converted: tuple[Path, Path]) -> None:
    src, dst = converted
    scene = DatasetReader(dst).scene(SCENE)
    folder = src / "validate" / "2021_08_21_17_30_41"
    for index, number in enumerate(FRAMES):
        _, labels = scene.labels(index)
        ours = dict(zip(labels.boxes.ids.tolist(), labels.boxes.corners(), strict=True))
        expected: dict[str, np.ndarray] = {}
        for agent in ("4279", "4288", "-1"):  # the ego first: its entry wins, as in the converter
            for object_id, vehicle in _load(folder / agent / f"{number:06d}.yaml")["vehicles"].items():
                expected.setdefault(str(object_id), opencood_corners(vehicle, np.eye(4)) @ REFLECT)
        assert sorted(ours) == sorted(expected)
        worst = max(same_corner_sets(ours[i], expected[i]) for i in expected)
        assert worst < 1e-6, worst
        assert labels.boxes.frame == "world" and set(labels.boxes.classes.tolist()) == {"car"}


def test_hand_worked_carla_box_yaw_plus_30_degrees(converted: tuple[Path, Path]) -> None:
    """CARLA location (10, 5, 1), half extent (2, 1, 0.75), yaw +30 deg (clockwise seen from above in the
    left-handed map) -> right-handed centre (10, -5, 1), size (4, 2, 1.5), yaw -30 deg; its front-left
    bottom corner is centre + R(-30°)·(2, 1, -0.75) = (10 + 2cos30 + 1sin30, -5 - 2sin30 + 1cos30, 0.25)."""
    _, dst = converted
    _, labels = DatasetReader(dst).scene(SCENE).labels(0)
    box = labels.boxes[labels.boxes.ids == str(HAND_BOX_ID)]
    np.testing.assert_allclose(box.center[0], [10.0, -5.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(box.size_lwh[0], [4.0, 2.0, 1.5], atol=1e-12)
    np.testing.assert_allclose(box.yaw()[0], np.radians(-30.0), atol=1e-12)
    np.testing.assert_allclose(box.quat_wxyz[0], [np.cos(np.radians(15)), 0.0, 0.0, -np.sin(np.radians(15))], atol=1e-12)
    c30, s30 = np.cos(np.radians(30)), np.sin(np.radians(30))
    np.testing.assert_allclose(box.corners()[0, 3], [10 + 2 * c30 + s30, -5 - 2 * s30 + c30, 0.25], atol=1e-12)


def test_world_points_and_intensity_equal_opencood(converted: tuple[Path, Path], tmp_path: Path) -> None:
    src, dst = converted
    dataset = DatasetReader(dst)
    graph = dataset.frame_graph(SCENE)
    folder = src / "validate" / "2021_08_21_17_30_41"
    code = ("import sys, numpy as np\nfrom avdata.generators._open3d import load_open3d\no3d = load_open3d()\n"
            "out = sys.argv[1]\n"
            "for path in sys.argv[2:]:\n"
            "    p = o3d.io.read_point_cloud(path)\n"
            "    name = path.split('/')[-2] + '_' + path.split('/')[-1][:-4]\n"
            "    np.save(f'{out}/{name}.npy', np.hstack([np.asarray(p.points), np.asarray(p.colors)[:, :1]]))\n")
    agents = (("4279", "ego"), ("4288", "cav_4288"), ("-1", "infra_1"))
    pcds = [str(folder / agent / f"{number:06d}.pcd") for agent, _ in agents for number in FRAMES]
    # The readings go to tmp_path: the source folder is shared, and a file added to it changes its fingerprint.
    subprocess.run([sys.executable, "-c", code, str(tmp_path), *pcds], check=True, timeout=300)
    for agent, name in agents:
        for index, number in enumerate(FRAMES):
            out = tmp_path / f"{agent}_{number:06d}.npy"
            opencood = np.load(out)  # pcd_utils.pcd_to_np: xyz and colors[:, 0]
            pose = _load(folder / agent / f"{number:06d}.yaml")["lidar_pose"]
            expected = (np.c_[opencood[:, :3], np.ones(len(opencood))] @ x_to_world(pose).T)[:, :3] @ REFLECT
            time_ns = dataset.sensor_time(SCENE, index, f"{name}/lidar")
            cloud = dataset.points(SCENE, index, f"{name}/lidar")
            xyz = np.stack([cloud["x"], cloud["y"], cloud["z"]], axis=1).astype(np.float64)
            world = graph.lookup("world", f"{name}/lidar", time_ns).apply(xyz)
            np.testing.assert_allclose(world, expected, atol=1e-6, rtol=0)
            np.testing.assert_allclose(cloud["intensity"], opencood[:, 3], atol=1e-7)


def test_predicted_and_true_vehicle_frames_and_camera(converted: tuple[Path, Path]) -> None:
    src, dst = converted
    dataset = DatasetReader(dst)
    graph = dataset.frame_graph(SCENE)
    real = _load(REAL_YAML)
    for frame, key in (("ego/vehicle", "true_ego_pos"), ("ego/vehicle_predicted", "predicted_ego_pos")):
        matrix = x_to_world(real[key])
        expected = np.eye(4)
        expected[:3, :3] = REFLECT @ matrix[:3, :3] @ REFLECT
        expected[:3, 3] = REFLECT @ matrix[:3, 3]
        np.testing.assert_allclose(graph.lookup("world", frame, 0).as_matrix(), expected, atol=1e-9)
    # camera0 looks forward: a point 10 m ahead of the camera (Unreal x) is at optical (0, 0, 10), and
    # world_T_optical agrees with the camera's own ``cords`` pose.
    cords = x_to_world(real["camera0"]["cords"])
    ahead_carla = (cords @ [10.0, 0.0, 0.0, 1.0])[:3]
    world_T_optical = graph.lookup("world", "ego/camera0", 0)
    np.testing.assert_allclose(world_T_optical.apply(np.array([0.0, 0.0, 10.0])), REFLECT @ ahead_carla, atol=1e-5)
    calibration = dataset.scene(SCENE).camera_calibration("ego/camera0", 0)
    np.testing.assert_allclose(np.asarray(calibration.K).reshape(3, 3), real["camera0"]["intrinsic"])


def test_v2v4real_world_boxes_and_shared_ids(converted: tuple[Path, Path]) -> None:
    src, dst = converted
    scene = DatasetReader(dst).scene(V2V4REAL_SCENE)
    assert scene.metadata["variant"] == "v2v4real" and scene.ego_frame() == "ego"
    folder = src / "test" / "testoutput_CAV_data_2022-03-15-09-54-40_0"
    for index in range(3):
        _, labels = scene.labels(index)
        assert sorted(labels.boxes.ids.tolist()) == ["0", "0_30", "1", "1_31"]
        ours = dict(zip(labels.boxes.ids.tolist(), labels.boxes.corners(), strict=True))
        for cav in ("0", "1"):
            data = _load(folder / cav / f"{index:06d}.yaml")
            lidar_to_world = np.asarray(data["lidar_pose"])
            for object_id, vehicle in data["vehicles"].items():
                # shared objects keep the ego's box; the fixture's two views agree exactly, so both must match
                key = str(vehicle["ass_id"]) if vehicle["ass_id"] >= 0 else f"{cav}_{object_id}"
                assert same_corner_sets(ours[key], opencood_corners(vehicle, lidar_to_world)) < 1e-6
        assert dict(zip(labels.boxes.ids, labels.boxes.classes, strict=True))["0_30"] == "pedestrian"


def test_bad_inputs_cost_their_record(tmp_path: Path) -> None:
    scenario = build_opv2v(tmp_path / "src")
    bad_vehicle = scenario / "4288" / "000071.yaml"
    data = _load(bad_vehicle)
    data["vehicles"][4306]["extent"] = [2.0, -1.0, 0.7]
    bad_vehicle.write_text(yaml.safe_dump(data))
    (scenario / "-1" / "000073.yaml").write_text("lidar_pose: [1, 2, 3]\nvehicles: {}\n")
    (scenario / "4288" / "000073.pcd").write_bytes(b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y\n")
    result = run_conversion(Opv2vConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "dst", quiet=True)))
    lines = sorted(str(p) for p in result.problems)
    assert len(lines) == 3 and result.written == [SCENE]
    assert "4288/000071.yaml: field vehicles.4306.extent: expected positive half sizes, got [2.0, -1.0, 0.7]" in lines[0] \
        or any("vehicles.4306.extent" in line for line in lines)
    assert any("-1/000073.yaml: field lidar_pose: expected 6 numbers or a 4x4 matrix" in line for line in lines)
    assert any("4288/000073.pcd" in line and "DATA line" in line for line in lines)
    _, labels = DatasetReader(tmp_path / "dst").scene(SCENE).labels(1)
    assert "4306" in labels.boxes.ids.tolist()  # still labelled by the ego (the bad copy only cost its own entry)
    proc = subprocess.run([sys.executable, "-m", "avdata.cli", "convert", "opv2v", str(tmp_path / "src"),
                           str(tmp_path / "dst2"), "--quiet"], capture_output=True, text=True)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert len([line for line in proc.stderr.splitlines() if line.startswith("error:")]) == 3


def test_boxes_from_carla_matches_opencood_for_a_tilted_box() -> None:
    vehicle = {"location": [3.0, -2.0, 0.5], "center": [0.1, -0.2, 0.7], "extent": [2.2, 0.9, 0.8],
               "angle": [4.0, 123.0, -7.0]}
    loc = np.add(vehicle["location"], vehicle["center"])
    roll, yaw, pitch = vehicle["angle"]
    boxes = boxes_from_carla(loc, vehicle["extent"], [roll, pitch, yaw], "world")
    assert same_corner_sets(boxes.corners()[0], opencood_corners(vehicle, np.eye(4)) @ REFLECT) < 1e-9


def test_loader_collaborative_early_fusion_and_comm_range(converted: tuple[Path, Path]) -> None:
    from avdata.loaders import Collaboration, FrameDataset, FrameOptions

    def options(**link: float) -> FrameOptions:
        return FrameOptions(sensors=("*/lidar",), frame="ego",
                            collaboration=Collaboration(agents=("ego", "cav_*", "infra_*"), fusion="early", **link))

    _, dst = converted
    fused = FrameDataset(dst, options(), scenes=[SCENE])
    item = fused[1]
    assert item["agents"] == ["ego", "cav_4288", "infra_1"] and item["agent_received"].all()
    agent_index = item["points"]["fused"][:, item["point_fields"]["fused"].index("agent_index")]
    assert np.bincount(agent_index.long().numpy()).tolist() == [N_POINTS] * 3
    assert "4279" not in item["object_ids"]  # the ego's own box (listed by its peer) is not its target
    near = float(item["agent_distance_m"][1:].min())
    cut = FrameDataset(dst, options(comm_range_m=near + 0.01), scenes=[SCENE])[1]
    assert cut["agent_received"].sum() == 2 and len(cut["points"]["fused"]) == 2 * N_POINTS


def test_eval_detection_avdata_protocol(converted: tuple[Path, Path], tmp_path: Path) -> None:
    _, dst = converted
    check_eval_three_missed_one_false(dst, tmp_path)


def test_agents_disagreeing_on_an_actor_are_warned_about(tmp_path: Path) -> None:
    scenario = build_opv2v(tmp_path / "src")
    path = scenario / "4288" / "000073.yaml"
    data = _load(path)
    data["vehicles"][4306]["location"][0] += 0.5
    path.write_text(yaml.safe_dump(data))
    result = run_conversion(Opv2vConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "dst", quiet=True)))
    assert [(p.severity, Path(p.file).name) for p in result.problems] == [("warning", "000073.yaml")]
    assert "actors ['4306'] lie up to 0.5 m from where an earlier agent lists them" in result.problems[0].message
    _, labels = DatasetReader(tmp_path / "dst").scene(SCENE).labels(2)
    real = real_frame()["vehicles"][4306]
    box = labels.boxes[labels.boxes.ids == "4306"]
    assert box.center[0, 0] == pytest.approx(real["location"][0] + real["center"][0], abs=1e-9)  # the ego's entry


def test_parallel_and_rerun_give_the_same_bytes(converted: tuple[Path, Path], tmp_path: Path) -> None:
    src, dst = converted
    parallel = tmp_path / "parallel"
    result = run_conversion(Opv2vConverter(ConvertConfig(src=src, dst=parallel, workers=2, quiet=True)))
    assert sorted(result.written) == [V2V4REAL_SCENE, SCENE]
    for scene in (SCENE, V2V4REAL_SCENE):
        assert (parallel / "scenes" / f"{scene}.mcap").read_bytes() == (dst / "scenes" / f"{scene}.mcap").read_bytes()
    again = run_conversion(Opv2vConverter(ConvertConfig(src=src, dst=parallel, quiet=True)))
    assert again.written == [] and sorted(again.complete) == [V2V4REAL_SCENE, SCENE]
