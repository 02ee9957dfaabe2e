"""FrameDataset items against DatasetReader, FrameGraph and hand-computed values."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from avdata.errors import AvdataError
from avdata.frames import Boxes3D, Transform
from avdata.loaders import Collaboration, FrameDataset, FrameOptions, LabelFilter
from avdata.schema import UNIFIED_CLASSES, DatasetReader, DatasetWriter, ObjectLabels
from tests.loaders.conftest import (
    CAMERA_K,
    EGO_T_CAMERA,
    EGO_T_LIDAR,
    INFRA_T_LIDAR,
    LIDAR_DELAY_NS,
    PERIOD_NS,
    T0_NS,
    boxes_world,
    lidar_points,
    world_T_ego,
    world_T_infra,
)

FRAMES = ["world", "ego", "ego/lidar_top", "ego/cam_front", "infra_00", "infra_00/lidar"]


def homogeneous(xyz: np.ndarray) -> np.ndarray:
    return np.concatenate([xyz, np.ones((len(xyz), 1))], axis=1)


def explicit_world_T(frame: str, time_ns: int) -> np.ndarray:
    """world_T_frame as a 4x4 built from the test's own constants (not through the graph)."""
    ego = world_T_ego(time_ns).as_matrix()
    infra = world_T_infra("infra_00").as_matrix()
    return {
        "world": np.eye(4),
        "ego": ego,
        "ego/lidar_top": ego @ EGO_T_LIDAR.as_matrix(),
        "ego/cam_front": ego @ EGO_T_CAMERA.as_matrix(),
        "infra_00": infra,
        "infra_00/lidar": infra @ INFRA_T_LIDAR.as_matrix(),
    }[frame]


def test_item_keys_and_values_equal_the_reader(dataset: Path) -> None:
    ds = FrameDataset(dataset, sensors=["ego/lidar_top", "ego/cam_front"], scenes=["v2i"])
    reader = DatasetReader(dataset)
    assert len(ds) == 3
    assert ds.keys() == [("v2i", 0), ("v2i", 1), ("v2i", 2)]
    item = ds[1]
    t = T0_NS + PERIOD_NS
    assert (item["scene"], item["frame_index"], item["timestamp_ns"], item["frame"]) == ("v2i", 1, t, "ego")
    assert item["sensor_timestamps_ns"] == {"ego/lidar_top": t, "ego/cam_front": t}
    raw = reader.points("v2i", 1, "ego/lidar_top")
    assert item["point_fields"]["ego/lidar_top"] == ("x", "y", "z", "intensity")
    cloud = item["points"]["ego/lidar_top"]
    assert cloud.dtype == torch.float32 and cloud.shape == (len(raw), 4)
    np.testing.assert_array_equal(cloud[:, 3].numpy(), raw["intensity"])
    # ego = lidar + (1, 0, 2), same axes
    np.testing.assert_allclose(cloud[:, 0].numpy(), raw["x"] + 1.0, atol=1e-5)
    np.testing.assert_allclose(cloud[:, 2].numpy(), raw["z"] + 2.0, atol=1e-5)
    _, labels = reader.scene("v2i").labels(1)
    assert item["object_ids"] == labels.boxes.ids.tolist() == ["a", "b", "c", "d"]
    classes = list(UNIFIED_CLASSES)
    assert item["labels"].tolist() == [classes.index(c) for c in ("car", "pedestrian", "truck", "cyclist")]


@pytest.mark.parametrize("frame", FRAMES)
def test_points_in_each_frame_equal_explicit_matrix_products(dataset: Path, frame: str) -> None:
    ds = FrameDataset(dataset, sensors=["*/lidar*"], frame=frame, agents=["*"], scenes=["v2i"])
    for k in range(3):
        t = T0_NS + k * PERIOD_NS
        item = ds[k]
        graph = DatasetReader(dataset).scene("v2i").graph
        for sensor in ("ego/lidar_top", "infra_00/lidar"):
            raw = lidar_points(sensor, k)
            xyz = np.stack([raw["x"], raw["y"], raw["z"]], axis=1).astype(np.float64)
            frame_T_sensor = np.linalg.inv(explicit_world_T(frame, t)) @ explicit_world_T(sensor, t)
            expected = (frame_T_sensor @ homogeneous(xyz).T).T[:, :3]
            got = item["points"][sensor][:, :3].numpy()
            np.testing.assert_allclose(got, expected, atol=2e-4)
            np.testing.assert_allclose(graph.lookup(frame, sensor, t).as_matrix(), frame_T_sensor, atol=1e-9)
        np.testing.assert_array_equal(item["points"]["infra_00/lidar"][:, 4].numpy(),
                                      lidar_points("infra_00/lidar", k)["object_id"].astype(np.float32))


@pytest.mark.parametrize("frame", FRAMES)
def test_boxes_in_each_frame_equal_explicit_matrix_products(dataset: Path, frame: str) -> None:
    ds = FrameDataset(dataset, FrameOptions(frame=frame, with_velocity=True), scenes=["v2i"])
    for k in range(3):
        t = T0_NS + k * PERIOD_NS
        boxes = ds[k]["boxes"].numpy().astype(np.float64)
        world = boxes_world(k)
        frame_T_world = np.linalg.inv(explicit_world_T(frame, t))
        np.testing.assert_allclose(boxes[:, :3], (frame_T_world @ homogeneous(world.center).T).T[:, :3], atol=1e-4)
        np.testing.assert_allclose(boxes[:, 3:6], world.size_lwh, atol=1e-6)
        # the box x axis moved into the frame, projected on its xy plane
        axis_world = np.stack([np.cos(world.yaw()), np.sin(world.yaw()), np.zeros(4)], axis=1)
        axis_frame = axis_world @ frame_T_world[:3, :3].T
        if frame != "ego/cam_front" and not frame.endswith("/lidar"):
            np.testing.assert_allclose(np.cos(boxes[:, 6]), axis_frame[:, 0], atol=1e-5)
            np.testing.assert_allclose(np.sin(boxes[:, 6]), axis_frame[:, 1], atol=1e-5)
        velocity = world.velocity @ frame_T_world[:3, :3].T
        np.testing.assert_allclose(boxes[:, 7:9], velocity[:, :2], atol=1e-5)


def test_boxes_in_ego_frame_hand_computed(dataset: Path) -> None:
    # frame 0: ego at (10, 5) facing world +y. Car a at world (10, 25), yaw 0, moving +y at 5 m/s
    # is 20 m straight ahead, heading -90 deg (to the ego's right), moving +x at 5 m/s.
    item = FrameDataset(dataset, FrameOptions(with_velocity=True, with_quaternions=True), scenes=["v2i"])[0]
    a = item["boxes"][item["object_ids"].index("a")].numpy()
    np.testing.assert_allclose(a, [20.0, 0.0, 0.8, 4.0, 2.0, 1.6, -np.pi / 2, 5.0, 0.0], atol=1e-5)
    np.testing.assert_allclose(item["boxes_quat_wxyz"][0].numpy(), [np.cos(-np.pi / 4), 0, 0, np.sin(-np.pi / 4)],
                               atol=1e-9)


def test_labels_already_in_the_item_frame_are_the_stored_ones(tmp_path: Path) -> None:
    # Labels stored in world are not moved for a world item (an identity move round-trips the quaternions
    # through matrices, which changes last bits of some); in the ego frame they are moved.
    rng = np.random.default_rng(3)
    n = 20
    boxes = Boxes3D.from_yaw(rng.uniform(-50, 50, (n, 3)), rng.uniform(1, 5, (n, 3)), rng.uniform(-np.pi, np.pi, n),
                             "world", ids=np.array([f"o{i}" for i in range(n)]), classes=np.array(["car"] * n))
    assert not np.array_equal(boxes.transform(Transform.identity(), "world").quat_wxyz, boxes.quat_wxyz)
    with DatasetWriter(tmp_path / "ds", source="loader-tests") as writer, writer.scene("yawed") as scene:
        scene.add_agent("ego", kind="vehicle", origin="rear axle on the ground")
        scene.add_transform("world", "ego", T0_NS, world_T_ego(T0_NS))
        scene.add_frame(0, T0_NS, ObjectLabels(boxes=boxes), {})
    options = FrameOptions(sensors=(), with_quaternions=True)
    world = FrameDataset(tmp_path / "ds", replace(options, frame="world"))[0]
    assert world["object_ids"] == list(boxes.ids)
    np.testing.assert_array_equal(world["boxes_quat_wxyz"].numpy(), boxes.quat_wxyz)
    np.testing.assert_array_equal(world["boxes"].numpy(), np.c_[boxes.center, boxes.size_lwh, boxes.yaw()].astype(np.float32))
    ego = FrameDataset(tmp_path / "ds", replace(options, frame="ego"))[0]
    expected = boxes.transform(world_T_ego(T0_NS).inverse(), "ego")
    np.testing.assert_allclose(ego["boxes_quat_wxyz"].numpy(), expected.quat_wxyz, atol=1e-12)
    np.testing.assert_allclose(ego["boxes"][:, :3].numpy(), expected.center, atol=1e-4)


def test_sensor_time_differs_from_frame_time_motion_is_compensated(dataset: Path) -> None:
    # The lidar fires 20 ms after the frame time; at 10 m/s along world +y (= ego +x) the ego has
    # moved 0.2 m forward, so a point seen then lies 0.2 m further ahead in the ego frame of the frame time.
    ds = FrameDataset(dataset, sensors="ego/lidar_top", scenes=["offset"])
    item = ds[1]
    t = T0_NS + PERIOD_NS
    assert item["sensor_timestamps_ns"] == {"ego/lidar_top": t + LIDAR_DELAY_NS}
    raw = lidar_points("ego/lidar_top", 1)
    np.testing.assert_allclose(item["points"]["ego/lidar_top"][:, 0].numpy(), raw["x"] + 1.0 + 0.2, atol=1e-5)
    np.testing.assert_allclose(item["points"]["ego/lidar_top"][:, 1].numpy(), raw["y"], atol=1e-5)
    # labels stored in the ego frame come out in world through the ego pose at the frame time
    world = FrameDataset(dataset, scenes=["offset"], frame="world")[1]
    np.testing.assert_allclose(world["boxes"][:, :3].numpy(), boxes_world(1).center, atol=1e-4)
    assert np.allclose(world_T_ego(t + LIDAR_DELAY_NS).translation, [10.0, 6.2, 0.0])


def test_image_and_projection(dataset: Path) -> None:
    ds = FrameDataset(dataset, sensors=["ego/cam_front"], scenes=["v2i"], frame="world")
    item = ds[2]
    image = item["images"]["ego/cam_front"]
    assert image.dtype == torch.uint8 and image.shape == (3, 6, 8)
    assert image[:, 1, 2].tolist() == [32, 20, 10]  # RGB of the BGR pixel (10, 20, 32)
    assert int(image.sum()) == 62
    calibration = item["calibrations"]["ego/cam_front"]
    np.testing.assert_array_equal(calibration["K"].numpy(), CAMERA_K)
    assert (calibration["width"], calibration["height"]) == (8, 6)
    t = T0_NS + 2 * PERIOD_NS
    camera_T_world = np.linalg.inv(explicit_world_T("ego/cam_front", t))
    expected = np.hstack([CAMERA_K, np.zeros((3, 1))]) @ camera_T_world
    np.testing.assert_allclose(item["projections"]["ego/cam_front"].numpy(), expected, atol=1e-9)
    # car a, straight ahead of the ego, projects onto the principal point column
    centre = boxes_world(2).center[0]
    uvw = expected @ np.append(centre, 1.0)
    assert uvw[0] / uvw[2] == pytest.approx(4.0, abs=1e-9)


@pytest.mark.parametrize(
    ("options", "expected_ids"),
    [
        ({}, ["a", "b", "c", "d"]),
        ({"classes": ["car", "truck"]}, ["a", "c"]),
        # ego at (10, 5): a 20 m, b ~5 m, c 100 m, d ~40 m
        ({"max_range_m": 30.0}, ["a", "b"]),
        ({"max_range_m": 45.0}, ["a", "b", "d"]),
        ({"visible_to": "ego/lidar_top"}, ["a", "b", "d"]),
        ({"visible_to": "ego/lidar_top", "min_points": 10}, ["a", "d"]),
        ({"visible_to": "ego/lidar_top", "min_points": 11}, ["a"]),
        ({"visible_to": "ego/lidar_top", "max_occlusion": 1}, ["a", "b"]),
        ({"visible_to": "ego/lidar_top", "max_occlusion": 0}, ["a"]),
        ({"visible_to": ["ego/lidar_top", "infra_02/lidar"], "max_occlusion": 0}, ["a", "c"]),
        ({"visible_to": "infra_*/lidar", "min_points": 5}, ["a", "c"]),
        ({"visible_to": "infra_01/lidar"}, []),
        ({"classes": ["car", "cyclist"], "visible_to": "*", "min_points": 4, "max_range_m": 45.0}, ["a", "d"]),
    ],
)
def test_filters_keep_exactly_the_hand_checked_objects(dataset: Path, options: dict, expected_ids: list) -> None:
    item = FrameDataset(dataset, FrameOptions(labels=LabelFilter(**options)), scenes=["v2i"])[0]
    assert item["object_ids"] == expected_ids
    assert item["boxes"].shape == (len(expected_ids), 7)
    classes = options.get("classes", list(UNIFIED_CLASSES))
    names = {"a": "car", "b": "pedestrian", "c": "truck", "d": "cyclist"}
    assert item["labels"].tolist() == [classes.index(names[i]) for i in expected_ids]


def test_class_indices_follow_the_requested_order(dataset: Path) -> None:
    item = FrameDataset(dataset, scenes=["v2i"], classes=["truck", "car"])[0]
    assert item["object_ids"] == ["a", "c"]
    assert item["labels"].tolist() == [1, 0]


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda root: FrameDataset(root, classes=["car", "spaceship"]), "unified taxonomy"),
        (lambda root: FrameDataset(root, FrameOptions(labels=LabelFilter(min_points=3))), "visible_to"),
        (lambda root: LabelFilter(max_occlusion=4, visible_to="ego/lidar_top"), "max_occlusion"),
        (lambda root: FrameDataset(root, sensors=["ego/radar"]), "ego/radar"),
        (lambda root: Collaboration(agents=()), "at least one agent"),
        (lambda root: Collaboration(agents=("*",), comm_range_m=-1.0), "comm_range_m > 0"),
        (lambda root: Collaboration(agents=("*",), rate_hz={"infra_*": 0.0}), "positive rate for agents 'infra_\\*'"),
        (lambda root: FrameDataset(root, agents=["infra_*"]), "ego agent"),
        (lambda root: FrameDataset(root, FrameOptions(collaboration=Collaboration(agents=("*",), fusion="mid"))),
         "fusion"),
        (lambda root: FrameDataset(root, {"frame": "world"}), "expected options as a FrameOptions, got dict"),
        (lambda root: FrameDataset(root, FrameOptions(frame="")), "frame name"),
        (lambda root: FrameDataset(root, scenes=["nope"]), "nope"),
    ],
)
def test_bad_options_raise_clear_errors(dataset: Path, make, message: str) -> None:
    with pytest.raises(AvdataError, match=message):
        make(dataset)


def test_default_items_hold_the_ego_point_clouds(dataset: Path) -> None:
    # No sensors: the ego's lidar (not its camera, not the infrastructure lidars), boxes in the ego frame.
    item = FrameDataset(dataset, scenes=["v2i"])[0]
    assert list(item["points"]) == ["ego/lidar_top"] and item["images"] == {}
    explicit = FrameDataset(dataset, sensors="ego/lidar_top", scenes=["v2i"])[0]
    assert torch.equal(item["points"]["ego/lidar_top"], explicit["points"]["ego/lidar_top"])
    assert torch.equal(item["boxes"], explicit["boxes"]) and item["frame"] == "ego"
    # collaborative without sensors: every agent's point clouds
    collaborative = FrameDataset(dataset, agents=["*"], scenes=["v2i"])[0]
    assert sorted(collaborative["points"]) == ["ego/lidar_top", "infra_00/lidar", "infra_01/lidar", "infra_02/lidar"]
    # labels only stays one explicit word away
    assert FrameDataset(dataset, sensors=[], scenes=["v2i"])[0]["points"] == {}


def test_default_sensors_on_a_dataset_without_point_clouds_give_labels(tmp_path: Path) -> None:
    with DatasetWriter(tmp_path / "ds", source="test") as writer, writer.scene("cams") as scene:
        scene.add_agent("ego", kind="vehicle", origin="rear axle")
        scene.add_sensor("ego/cam", kind="camera", width=8, height=6)
        scene.add_static_transform("ego", "ego/cam", EGO_T_CAMERA)
        scene.add_transform("world", "ego", T0_NS, world_T_ego(T0_NS))
        scene.add_image("ego/cam", T0_NS, b"not decoded here", "png")
        scene.add_frame(0, T0_NS, ObjectLabels(boxes=boxes_world(0)), {"ego/cam": T0_NS})
    item = FrameDataset(tmp_path / "ds")[0]
    assert item["points"] == {} and item["images"] == {} and item["object_ids"] == ["a", "b", "c", "d"]
    # asking for a point cloud by name still requires it in every frame
    with pytest.raises(AvdataError, match=r"scene 'cams' frame 0: expected a sensor matching 'ego/lidar\*', got \['ego/cam'\]"):
        FrameDataset(tmp_path / "ds", sensors="ego/lidar*")


def test_option_objects_and_shortcuts_give_the_same_items(dataset: Path) -> None:
    typed = FrameDataset(dataset, FrameOptions(sensors=("ego/lidar_top",), frame="world",
                                               labels=LabelFilter(classes=("car", "truck"))), scenes=["v2i"])
    shortcuts = FrameDataset(dataset, sensors="ego/lidar_top", frame="world", classes=["car", "truck"],
                             with_velocity=False, scenes=["v2i"])
    assert typed.options == shortcuts.options
    for k in range(3):
        assert torch.equal(typed[k]["points"]["ego/lidar_top"], shortcuts[k]["points"]["ego/lidar_top"])
        assert torch.equal(typed[k]["boxes"], shortcuts[k]["boxes"])
    # a shortcut replaces that one field of the options it is given with
    base = FrameOptions(frame="world", labels=LabelFilter(classes=("car",), max_range_m=30.0))
    mixed = FrameDataset(dataset, base, classes=["truck", "car"], agents=["ego", "infra_*"], with_quaternions=True,
                         scenes=["v2i"])
    assert mixed.options.labels == LabelFilter(classes=("truck", "car"), max_range_m=30.0)
    assert mixed.options.with_quaternions and not mixed.options.with_velocity
    assert mixed.options.frame == "world" and mixed.options.collaboration == Collaboration(agents=("ego", "infra_*"))
    assert Collaboration(agents="ego", rate_hz=5.0, noise_std_m={"infra_*": 0.1}) == Collaboration(
        agents=("ego",), rate_hz=(("*", 5.0),), noise_std_m=(("infra_*", 0.1),))


def test_getitem_has_no_side_effects(dataset: Path) -> None:
    ds = FrameDataset(dataset, sensors=["ego/lidar_top"], scenes=["v2i"])
    first = ds[2]
    ds[0]
    again = ds[2]
    assert torch.equal(first["points"]["ego/lidar_top"], again["points"]["ego/lidar_top"])
    assert torch.equal(first["boxes"], again["boxes"])
    assert ds[-1]["frame_index"] == 2
    with pytest.raises(IndexError):
        ds[3]


@pytest.mark.parametrize("frame", FRAMES)
def test_box_orientations_in_each_frame_equal_boxes3d_moved_through_the_graph(dataset: Path, frame: str) -> None:
    ds = FrameDataset(dataset, FrameOptions(sensors=(), frame=frame, with_quaternions=True), scenes=["v2i"])
    graph = DatasetReader(dataset).scene("v2i").graph
    for k in range(3):
        item = ds[k]
        expected = boxes_world(k).to(frame, graph, T0_NS + k * PERIOD_NS)
        np.testing.assert_allclose(item["boxes_quat_wxyz"].numpy(), expected.quat_wxyz, atol=1e-12)
        np.testing.assert_allclose(item["boxes"][:, 6].numpy(), expected.yaw(), atol=1e-6)
