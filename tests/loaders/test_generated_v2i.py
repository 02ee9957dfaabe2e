"""Collaborative items on a generated V2I scene (ego + 8 infrastructure LiDARs, ``v2i-intersection``).

Checks against the reader and the frame graph directly, and a physical cross-check: every ray-cast
point carries the id of the object it hit, so once points and boxes are in the ego frame, the points
of object X must lie inside box X whichever agent saw them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from avdata.frames import Boxes3D
from avdata.generators import config as config_module
from avdata.generators import driver as generators
from avdata.loaders import Collaboration, FrameDataset, FrameOptions, LabelFilter
from avdata.schema import DatasetReader


@pytest.fixture(scope="module")
def v2i(tmp_path_factory: pytest.TempPathFactory) -> Path:
    dst = tmp_path_factory.mktemp("v2i") / "ds"
    config = config_module.load_preset("v2i-intersection")
    config = config_module.scenario_from_dict({**config.to_dict(), "scenes": 1, "frames": 2, "seed": 7}, "test")
    generators.generate(config, dst, workers=1, progress=False)
    return dst


def test_infra_points_in_ego_frame_equal_graph_products(v2i: Path) -> None:
    reader = DatasetReader(v2i)
    scene = reader.scenes[0]
    graph = reader.scene(scene).graph
    ds = FrameDataset(v2i, sensors=["*/lidar*"], agents=["ego", "infra_*"])
    item = ds[1]
    assert item["agents"][0] == "ego" and len(item["agents"]) == 9
    t = item["timestamp_ns"]
    for sensor in ("ego/lidar_top", "infra_03/lidar"):
        raw = reader.points(scene, 1, sensor)
        xyz = np.stack([raw["x"], raw["y"], raw["z"]], axis=1).astype(np.float64)
        matrix = graph.lookup("ego", sensor, reader.sensor_time(scene, 1, sensor)).as_matrix()
        expected = (matrix @ np.c_[xyz, np.ones(len(xyz))].T).T[:, :3]
        cloud = item["points"][sensor].numpy()
        np.testing.assert_allclose(cloud[:, :3], expected, atol=1e-3)
        assert item["point_fields"][sensor][-1] == "object_id"
        np.testing.assert_array_equal(cloud[:, -1], raw["object_id"].astype(np.float32))
    distances = [np.linalg.norm(graph.lookup("ego", a, t).translation) for a in item["agents"]]
    np.testing.assert_allclose(item["agent_distance_m"].numpy(), distances, atol=1e-9)


def test_points_of_each_object_fall_inside_its_box_for_every_agent(v2i: Path) -> None:
    options = FrameOptions(sensors=("*/lidar*",), with_quaternions=True,
                           collaboration=Collaboration(agents=("ego", "infra_*"), fusion="early"))
    item = FrameDataset(v2i, options)[0]
    cloud = item["points"]["fused"].numpy()
    fields = item["point_fields"]["fused"]
    object_id = cloud[:, fields.index("object_id")].astype(np.int64)
    boxes = item["boxes"].numpy().astype(np.float64)
    ids = item["object_ids"]
    boxes_ego = Boxes3D(center=boxes[:, :3], size_lwh=boxes[:, 3:6], quat_wxyz=item["boxes_quat_wxyz"].numpy(),
                        frame="ego")
    checked = 0
    for agent_index in range(len(item["agents"])):
        mine = cloud[:, fields.index("agent_index")] == agent_index
        for i, oid in enumerate(ids):
            hits = mine & (object_id == int(oid))
            if hits.sum() < 5:
                continue
            inside = boxes_ego[i].contains(cloud[hits, :3], margin_m=0.05)[0]
            assert inside.mean() > 0.98, (item["agents"][agent_index], oid, inside.mean())
            checked += 1
    assert checked >= 20


def test_visible_by_and_comm_range_follow_the_index(v2i: Path) -> None:
    reader = DatasetReader(v2i)
    visibility = reader.visibility().to_pylist()
    options = FrameOptions(sensors=("*/lidar*",), labels=LabelFilter(min_points=1, visible_to="*/lidar*"),
                           collaboration=Collaboration(agents=("ego", "infra_*"), comm_range_m=60.0))
    item = FrameDataset(v2i, options)[0]
    received = item["agent_received"].numpy()
    assert received.tolist() == (item["agent_distance_m"].numpy() <= 60.0).tolist()
    for a, agent in enumerate(item["agents"]):
        seen = {r["object_id"] for r in visibility
                if r["frame_index"] == 0 and r["sensor"].startswith(agent + "/") and r["in_fov"] and r["n_points"] >= 1}
        got = {oid for oid, v in zip(item["object_ids"], item["visible_by"][a].tolist(), strict=True) if v}
        assert got == (seen & set(item["object_ids"]) if received[a] else set())
    kept = set().union(*({r["object_id"] for r in visibility if r["frame_index"] == 0 and r["in_fov"]
                          and r["n_points"] >= 1 and r["sensor"].split("/")[0] == agent and "lidar" in r["sensor"]}
                         for agent, ok in zip(item["agents"], received, strict=True) if ok))
    assert set(item["object_ids"]) == kept


def test_the_ego_vehicle_is_not_its_own_target(v2i: Path) -> None:
    reader = DatasetReader(v2i)
    scene = reader.scene(reader.scenes[0])
    own_id = scene.metadata["agents"]["ego"]["object_id"]
    assert own_id in scene.labels(0)[1].boxes.ids.tolist()
    item = FrameDataset(v2i, sensors=["ego/*"], frame="ego")[0]
    assert own_id not in item["object_ids"]
    assert len(item["object_ids"]) == len(scene.labels(0)[1].boxes) - 1
