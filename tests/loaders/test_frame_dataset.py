"""FrameDataset items against DatasetReader, FrameGraph and hand-computed values."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from avdata.errors import AvdataError
from avdata.frames import Boxes3D, Transform
from avdata.loaders import FrameDataset
from avdata.loaders.frame_dataset import move_boxes, rotate_quaternions
from avdata.schema import UNIFIED_CLASSES, DatasetReader
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
    ds = FrameDataset(dataset, frame=frame, scenes=["v2i"], with_velocity=True)
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
    item = FrameDataset(dataset, scenes=["v2i"], with_velocity=True, with_quaternions=True)[0]
    a = item["boxes"][item["object_ids"].index("a")].numpy()
    np.testing.assert_allclose(a, [20.0, 0.0, 0.8, 4.0, 2.0, 1.6, -np.pi / 2, 5.0, 0.0], atol=1e-5)
    np.testing.assert_allclose(item["boxes_quat_wxyz"][0].numpy(), [np.cos(-np.pi / 4), 0, 0, np.sin(-np.pi / 4)],
                               atol=1e-9)


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
    item = FrameDataset(dataset, scenes=["v2i"], **options)[0]
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
    ("options", "message"),
    [
        ({"classes": ["car", "spaceship"]}, "unified taxonomy"),
        ({"min_points": 3}, "visible_to"),
        ({"max_occlusion": 4, "visible_to": "ego/lidar_top"}, "max_occlusion"),
        ({"sensors": ["ego/radar"]}, "ego/radar"),
        ({"comm_range_m": 50.0}, "agents"),
        ({"agents": ["infra_*"]}, "ego agent"),
        ({"agents": ["*"], "fusion": "late"}, "fusion"),
        ({"scenes": ["nope"]}, "nope"),
    ],
)
def test_bad_options_raise_clear_errors(dataset: Path, options: dict, message: str) -> None:
    with pytest.raises(AvdataError, match=message):
        FrameDataset(dataset, **options)


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


def test_move_boxes_equals_boxes3d_transform_for_random_poses() -> None:
    rng = np.random.default_rng(11)
    for _ in range(20):
        n = int(rng.integers(0, 8))
        boxes = Boxes3D(center=rng.normal(scale=20, size=(n, 3)), size_lwh=rng.uniform(0.5, 5, (n, 3)),
                        quat_wxyz=rng.normal(size=(n, 4)), frame="a", velocity=rng.normal(size=(n, 3)))
        target_T_a = Transform.from_quat_wxyz(rng.normal(size=4), rng.normal(scale=50, size=3))
        expected = boxes.transform(target_T_a, "b")
        center, yaw, velocity = move_boxes(target_T_a, boxes.center, boxes.quat_wxyz, boxes.velocity)
        np.testing.assert_allclose(center, expected.center, atol=1e-9)
        np.testing.assert_allclose(np.cos(yaw), np.cos(expected.yaw()), atol=1e-9)
        np.testing.assert_allclose(np.sin(yaw), np.sin(expected.yaw()), atol=1e-9)
        np.testing.assert_allclose(velocity, expected.velocity, atol=1e-9)
        np.testing.assert_allclose(rotate_quaternions(target_T_a, boxes.quat_wxyz), expected.quat_wxyz, atol=1e-9)
