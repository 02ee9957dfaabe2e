"""``--variant v2x-sim``: V2X-Sim 2.0's multi-agent channels (``<CHANNEL>_id_<k>``, k = 0 the road-side unit) as agents.

No V2X-Sim file is in ../shared/realdata, so the fixture is the real Lyft table set (nuScenes schema) in
V2X-Sim's shape: Lyft's channels become agent 1's (``LIDAR_TOP_id_1``, ``CAM_FRONT_id_1`` ...),
LIDAR_FRONT_LEFT becomes the road-side unit's ``LIDAR_TOP_id_0`` and LIDAR_FRONT_RIGHT agent 2's
``LIDAR_TOP_id_2``, each with its own ego poses whose ``timestamp`` is a small integer as in V2X-Sim; the
RSU's sweep is a real Lyft lidar file. The oracle is the nuScenes formula written out here:
``global_T_sensor = ego_pose(sample_data) @ calibrated_sensor``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.nuscenes import NuScenesConverter
from avdata.schema import DatasetReader
from avdata.sources.nuscenes import us_to_ns
from tests.realdata import REALDATA

LYFT = REALDATA / "nuscenes_schema" / "lyft"
ROOT = LYFT / "v1.01-train"
VERSION = "v1.01-train"
LIDAR_FILE = "lidar/host-a017_lidar1_1236118886501000046.bin"
RSU_POSE = {"translation": [431.5, 2698.25, 4.5], "rotation": [0.9238795325112867, 0.0, 0.0, 0.3826834323650898]}
CAV_POSE = {"translation": [402.0, 2722.0, 0.0], "rotation": [0.0, 0.0, 0.0, 1.0]}


def matrix(pose: dict) -> np.ndarray:
    out = np.eye(4)
    w, x, y, z = pose["rotation"]
    out[:3, :3] = Rotation.from_quat([x, y, z, w]).as_matrix()
    out[:3, 3] = pose["translation"]
    return out


def v2x_sim_tables(root: Path) -> dict[str, list[dict]]:
    """Writes the fixture dataroot under ``root``; returns its tables."""
    root.mkdir()
    (root / "maps").symlink_to(ROOT / "maps")
    (root / "lidar").symlink_to(LYFT / "lidar")
    tables = {p.stem: json.loads(p.read_text()) for p in (ROOT / VERSION).glob("*.json")}
    agent_of = {"LIDAR_FRONT_LEFT": ("LIDAR_TOP", 0), "LIDAR_FRONT_RIGHT": ("LIDAR_TOP", 2)}
    sensor_agent = {}
    for sensor in tables["sensor"]:
        base, k = agent_of.get(sensor["channel"], (sensor["channel"], 1))
        sensor["channel"] = f"{base}_id_{k}"
        sensor_agent[sensor["token"]] = k
    cs_agent = {cs["token"]: sensor_agent[cs["sensor_token"]] for cs in tables["calibrated_sensor"]}
    for pose in tables["ego_pose"]:
        pose["timestamp"] = 1  # V2X-Sim writes small integers here
    for k, pose in ((0, RSU_POSE), (2, CAV_POSE)):
        tables["ego_pose"].append({"token": f"pose-of-agent-{k}", "timestamp": k, **pose})
    for sd in tables["sample_data"]:
        k = cs_agent[sd["calibrated_sensor_token"]]
        if k != 1:
            sd["ego_pose_token"] = f"pose-of-agent-{k}"
        if k == 0:
            sd["filename"] = LIDAR_FILE
    (root / VERSION).mkdir()
    for name, rows in tables.items():
        (root / VERSION / f"{name}.json").write_text(json.dumps(rows))
    return tables


@pytest.fixture(scope="module")
def converted(tmp_path_factory) -> tuple[DatasetReader, dict[str, list[dict]]]:
    base = tmp_path_factory.mktemp("v2x_sim")
    tables = v2x_sim_tables(base / "src")
    result = run_conversion(NuScenesConverter(ConvertConfig(src=base / "src", dst=base / "out", quiet=True,
                                                            options={"variant": "v2x-sim"})))
    assert result.written and result.n_errors == 0
    return DatasetReader(base / "out"), tables


def test_channels_become_agents(converted):
    dataset, _ = converted
    reader = dataset.scene(dataset.scenes[0])
    agents = reader.metadata["agents"]
    assert {name: spec["kind"] for name, spec in agents.items()} == {
        "ego": "vehicle", "infra_0": "infrastructure", "cav_2": "vehicle"}
    sensors = reader.sensors()
    assert {"ego/lidar_top", "ego/cam_front", "infra_0/lidar_top", "cav_2/lidar_top"} <= set(sensors)
    assert reader.ego_frame() == "ego"
    assert reader.metadata["variant"] == "v2x-sim"


@pytest.mark.parametrize(("agent", "channel", "pose"), [("infra_0", "LIDAR_TOP_id_0", RSU_POSE),
                                                         ("cav_2", "LIDAR_TOP_id_2", CAV_POSE)])
def test_each_agent_sensor_sits_where_its_own_ego_pose_puts_it(converted, agent, channel, pose):
    dataset, tables = converted
    reader = dataset.scene(dataset.scenes[0])
    sensor = next(s for s in tables["sensor"] if s["channel"] == channel)
    cs = next(c for c in tables["calibrated_sensor"] if c["sensor_token"] == sensor["token"])
    sd = next(s for s in tables["sample_data"] if s["calibrated_sensor_token"] == cs["token"])
    expected = matrix(pose) @ matrix(cs)
    time_ns = us_to_ns(sd["timestamp"])  # Lyft float microseconds, exactly (tested in test_nuscenes.py)
    got = reader.graph.lookup("world", f"{agent}/lidar_top", time_ns).as_matrix()
    np.testing.assert_allclose(got, expected, atol=1e-9, rtol=0)


def test_rsu_points_reach_the_world_through_the_rsu_chain(converted):
    dataset, tables = converted
    reader = dataset.scene(dataset.scenes[0])
    points = dataset.points(dataset.scenes[0], 0, "infra_0/lidar_top")
    raw = np.fromfile(LYFT / LIDAR_FILE, dtype="<f4").reshape(-1, 5)
    np.testing.assert_array_equal(points["x"], raw[:, 0])
    sensor = next(s for s in tables["sensor"] if s["channel"] == "LIDAR_TOP_id_0")
    cs = next(c for c in tables["calibrated_sensor"] if c["sensor_token"] == sensor["token"])
    xyz = raw[:, :3].astype(np.float64)
    expected = (matrix(RSU_POSE) @ matrix(cs) @ np.c_[xyz, np.ones(len(xyz))].T).T[:, :3]
    time_ns = dataset.sensor_time(dataset.scenes[0], 0, "infra_0/lidar_top")
    got = reader.graph.lookup("world", "infra_0/lidar_top", time_ns).apply(xyz)
    np.testing.assert_allclose(got, expected, atol=1e-6, rtol=0)


def test_boxes_are_those_of_the_plain_conversion(converted, tmp_path):
    dataset, _ = converted
    plain = run_conversion(NuScenesConverter(ConvertConfig(src=ROOT, dst=tmp_path, quiet=True)))
    assert plain.written
    columns = ["object_id", "x_world_m", "y_world_m", "z_world_m", "qw_world", "qz_world", "length_m"]
    assert DatasetReader(tmp_path).objects().select(columns).equals(dataset.objects().select(columns))
