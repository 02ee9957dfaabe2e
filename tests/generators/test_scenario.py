"""Whole scenes through the dataset writer: point ids against boxes, n_points, reproducibility, CLI."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest
import yaml

from avdata.errors import InputError
from avdata.generators.cli import add_generate_subparser
from avdata.generators.config import load_scenario, scenario_from_dict
from avdata.generators.driver import generate
from avdata.schema import DatasetReader

SMALL = {
    "scenes": 1,
    "frames": 3,
    "seed": 3,
    "town": {"grid": [2, 2], "block_pitch_m": 70},
    "traffic": {"vehicles": 12, "pedestrians": 10, "warmup_s": 4.0},
    "egos": [{
        "name": "ego",
        "sensors": [
            {"name": "lidar_top", "kind": "lidar", "mount_xyz_m": [0, 0, 1.73],
             "lidar": {"model": "vlp32c", "azimuth_steps": 720, "max_range_m": 60}},
            {"name": "cam_front", "kind": "camera", "mount_xyz_m": [2.0, 0, 1.65],
             "camera": {"width": 320, "height": 120, "horizontal_fov_deg": 81}},
        ],
    }],
    "infrastructure": {
        "count": 2, "placement": "intersections", "height_m": 15, "pitch_deg": 30,
        "sensors": [{"name": "lidar", "kind": "lidar",
                     "lidar": {"model": "hdl64e", "azimuth_steps": 512, "horizontal_fov_deg": 180,
                               "max_range_m": 80}}],
    },
}


@pytest.fixture(scope="module")
def small_dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("gen") / "a"
    generate(scenario_from_dict(SMALL, "test"), root, progress=False)
    return root


def test_every_point_with_object_id_k_lies_in_box_k_and_n_points_counts_them(small_dataset):
    reader = DatasetReader(small_dataset)
    (scene_name,) = {str(s) for s in reader.frames().column("scene").to_pylist()}
    scene = reader.scene(scene_name)
    graph = scene.graph
    lidars = [f for f, spec in scene.sensors().items() if spec["kind"] == "lidar"]
    assert sorted(lidars) == ["ego/lidar_top", "infra_00/lidar", "infra_01/lidar"]
    on_objects = 0
    for info in scene.frame_infos():
        _, labels = scene.labels(info.frame_index)
        boxes = labels.boxes
        ids = boxes.ids.astype(np.int64)
        for sensor in lidars:
            time_ns = info.sensor_timestamps_ns[sensor]
            points = scene.points(sensor, time_ns)
            assert points.dtype["object_id"] == np.int32
            xyz = np.stack([points["x"], points["y"], points["z"]], axis=-1).astype(np.float64)
            xyz_world = graph.lookup("world", sensor, time_ns).apply(xyz)
            vis = scene.visibility(sensor, info.frame_index)
            counts = np.bincount(points["object_id"][points["object_id"] >= 0], minlength=len(ids))
            np.testing.assert_array_equal(vis.n_points, counts[vis.object_ids.astype(np.int64)])
            for k in np.unique(points["object_id"][points["object_id"] >= 0]):
                box = boxes[np.flatnonzero(ids == k)]
                inside = box.contains(xyz_world[points["object_id"] == k], margin_m=0.05)
                assert inside.all(), f"{sensor} frame {info.frame_index}: points of object {k} outside its box"
                on_objects += int(inside.sum())
            # Every object with points is in the field of view and seen.
            seen = vis.n_points > 0
            assert np.all(vis.in_fov[seen]) and np.all(vis.visible_fraction[seen] > 0)
    assert on_objects > 500


def test_same_config_and_seed_give_byte_identical_files_and_the_config_is_stored(small_dataset, tmp_path):
    again = tmp_path / "b"
    generate(scenario_from_dict(SMALL, "test"), again, progress=False)
    (first,) = sorted((small_dataset / "scenes").glob("*.mcap"))
    (second,) = sorted((again / "scenes").glob("*.mcap"))
    assert first.read_bytes() == second.read_bytes()
    scene = DatasetReader(again).scene(second.stem)
    stored = scene.metadata()["config"] if callable(scene.metadata) else scene.metadata["config"]
    assert stored["traffic"]["vehicles"] == 12 and stored["seed"] == 3


def test_config_errors_name_the_file_and_field(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("frames: 2\ninfrastructure:\n  placement: everywhere\n")
    with pytest.raises(InputError, match=r"bad.yaml: field infrastructure.placement: .*'everywhere'"):
        load_scenario(path)
    path.write_text("frames: 2\negos:\n  - name: ego\n    sensors:\n      - {name: x, kind: radar}\n")
    with pytest.raises(InputError, match=r"egos\[0\].sensors\[0\].kind: expected 'lidar' or 'camera', got 'radar'"):
        load_scenario(path)
    with pytest.raises(InputError, match=r"lidar model: expected one of .*got 'hdl128'"):
        scenario_from_dict({"egos": [{"name": "e", "sensors": [{"name": "l", "kind": "lidar",
                                                                 "lidar": {"model": "hdl128"}}]}]}, "x.yaml")


def test_generate_command_with_preset_and_overrides(tmp_path):
    parser = argparse.ArgumentParser()
    add_generate_subparser(parser.add_subparsers())
    args = parser.parse_args(["generate", "--preset", "v2i-intersection", "--scenes", "1", "--frames", "2",
                              "--seed", "7", "--quiet", str(tmp_path / "out")])
    assert args.run(args) == 0
    reader = DatasetReader(tmp_path / "out")
    assert reader.frames().num_rows == 2
    scene = reader.scene(str(reader.frames().column("scene")[0].as_py()))
    points = scene.points("infra_00/lidar", scene.frame_infos()[0].sensor_timestamps_ns["infra_00/lidar"])
    assert points.dtype.names == ("x", "y", "z", "intensity", "ring", "object_id")
    assert len(points) > 30_000


def test_workers_generate_scenes_in_parallel_with_the_same_bytes_as_one_worker(tmp_path):
    config = {**SMALL, "scenes": 2, "frames": 2,
              "egos": [{"name": "ego", "sensors": [SMALL["egos"][0]["sensors"][0]]}],
              "infrastructure": {**SMALL["infrastructure"], "count": 1}}
    generate(scenario_from_dict(config, "test"), tmp_path / "serial", workers=1, progress=False)
    generate(scenario_from_dict(config, "test"), tmp_path / "parallel", workers=2, progress=False)
    serial = sorted((tmp_path / "serial" / "scenes").glob("*.mcap"))
    parallel = sorted((tmp_path / "parallel" / "scenes").glob("*.mcap"))
    assert [p.name for p in serial] == [p.name for p in parallel] and len(serial) == 2
    assert all(a.read_bytes() == b.read_bytes() for a, b in zip(serial, parallel, strict=True))


def test_a_sensor_slower_than_the_frame_rate_records_every_other_frame(tmp_path):
    sensors = [{**SMALL["egos"][0]["sensors"][0], "lidar": {**SMALL["egos"][0]["sensors"][0]["lidar"], "rate_hz": 5}}]
    config = {**SMALL, "frames": 4, "egos": [{"name": "ego", "sensors": sensors}],
              "infrastructure": {"count": 0}}
    generate(scenario_from_dict(config, "test"), tmp_path / "d", progress=False)
    reader = DatasetReader(tmp_path / "d")
    scene = reader.scene(str(reader.frames().column("scene")[0].as_py()))
    recorded = [info.frame_index for info in scene.frame_infos() if "ego/lidar_top" in info.sensor_timestamps_ns]
    assert recorded == [0, 2]


def test_generate_command_reads_a_config_file(tmp_path):
    config_path = tmp_path / "scenario.yaml"
    config_path.write_text(yaml.safe_dump({**SMALL, "frames": 1}))
    parser = argparse.ArgumentParser()
    add_generate_subparser(parser.add_subparsers())
    args = parser.parse_args(["generate", str(config_path), str(tmp_path / "out"), "--quiet"])
    assert args.run(args) == 0
    assert DatasetReader(tmp_path / "out").frames().num_rows == 1
    bad = parser.parse_args(["generate", str(config_path), "--quiet"])
    with pytest.raises(InputError, match="expected CONFIG.yaml DST"):
        bad.run(bad)


def test_labelled_velocity_matches_the_motion_between_frames(small_dataset):
    reader = DatasetReader(small_dataset)
    scene = reader.scene(str(reader.frames().column("scene")[0].as_py()))
    (_, first), (_, second) = scene.labels(1), scene.labels(2)
    dt_s = 0.1
    moved = (second.boxes.center - first.boxes.center) / dt_s
    mean_velocity = (first.boxes.velocity + second.boxes.velocity) / 2
    # Central difference of positions against the mean of the two labelled velocities.
    np.testing.assert_allclose(moved, mean_velocity, atol=0.35)
    assert np.abs(first.boxes.velocity).max() > 3.0  # something is actually moving
    # Modulo pi: a crossing pedestrian turns around on the spot at the curb (its heading flips by pi).
    yaw_change = np.angle(np.exp(2j * (second.boxes.yaw() - first.boxes.yaw()))) / 2 / dt_s
    np.testing.assert_allclose(yaw_change, (first.angular_velocity[:, 2] + second.angular_velocity[:, 2]) / 2,
                               atol=0.35)


def test_a_rerun_skips_complete_scenes(small_dataset):
    (path,) = sorted((small_dataset / "scenes").glob("*.mcap"))
    before = path.stat().st_mtime_ns
    names = generate(scenario_from_dict(SMALL, "test"), small_dataset, progress=False)
    assert names == [path.stem] and path.stat().st_mtime_ns == before


def test_vehicle_agents_name_their_own_object_id(tmp_path):
    import numpy as np

    from avdata.generators.config import load_preset, scenario_from_dict
    from avdata.generators.driver import generate
    from avdata.schema import DatasetReader

    config = load_preset("v2i-intersection")
    config = scenario_from_dict({**config.to_dict(), "scenes": 1, "frames": 1, "seed": 3}, "test")
    generate(config, tmp_path / "ds", workers=1, progress=False)
    reader = DatasetReader(tmp_path / "ds")
    scene = reader.scene(reader.scenes[0])
    agents = scene.metadata["agents"]
    ego_id = agents["ego"]["object_id"]
    assert all("object_id" not in spec for name, spec in agents.items() if spec["kind"] == "infrastructure")
    info, labels = scene.labels(0)
    ego_box = labels.boxes[labels.boxes.ids == ego_id]
    world_T_ego = scene.graph.lookup("world", "ego", info.timestamp_ns)
    # The ego's labelled box sits on the ego's body frame origin (bottom centre), half its height up.
    assert len(ego_box) == 1
    np.testing.assert_allclose(ego_box.center[0, :2], world_T_ego.translation[:2], atol=1e-6)


@pytest.mark.parametrize(("edit", "message"), [
    # Frames are whole 50 ms steps: 30 Hz was simulated as one step (50 ms) per frame while its times said 33 ms.
    ({"frame_rate_hz": 30}, "field frame_rate_hz: expected 20 Hz divided by a whole number (frames are whole 0.05 s "
                            "simulation steps), got 30"),
    ({"frame_rate_hz": 1000}, "field frame_rate_hz: expected 20 Hz divided by a whole number"),
    # The first frame's labels difference three steps: a shorter warm-up was an IndexError traceback.
    ({"traffic": {**SMALL["traffic"], "warmup_s": 0}},
     "field traffic.warmup_s: expected a multiple of 0.05 s of at least 0.15 s (the first labels difference 3 "
     "simulation steps), got 0"),
    ({"traffic": {**SMALL["traffic"], "warmup_s": 1.07}}, "field traffic.warmup_s: expected a multiple of 0.05 s"),
    # A pole no taller than the curb it stands on was a pybullet.error traceback (a cylinder of negative height).
    ({"infrastructure": {**SMALL["infrastructure"], "height_m": 0.1}},
     "field infrastructure.height_m: expected more than the 0.15 m curb the poles stand on, got 0.1"),
    # The scene metadata said 100 Hz for a LiDAR that recorded once per 10 Hz frame.
    ({"egos": [{"name": "ego", "sensors": [{**SMALL["egos"][0]["sensors"][0],
                                            "lidar": {**SMALL["egos"][0]["sensors"][0]["lidar"], "rate_hz": 100}}]}]},
     "sensor lidar_top: expected rate_hz <= frame_rate_hz=10 (a sensor records at most once per frame), got 100"),
])
def test_timing_and_poles_the_simulation_cannot_honour_are_refused(edit, message):
    with pytest.raises(InputError) as error:
        scenario_from_dict({**SMALL, **edit}, "s.yaml")
    assert str(error.value).startswith(f"s.yaml: {message}")


def test_the_shortest_warmup_and_the_fastest_frame_rate_generate(tmp_path):
    config = {**SMALL, "frames": 2, "frame_rate_hz": 20, "traffic": {**SMALL["traffic"], "warmup_s": 0.15},
              "egos": [{"name": "ego", "sensors": [{**SMALL["egos"][0]["sensors"][0],
                                                    "lidar": {**SMALL["egos"][0]["sensors"][0]["lidar"], "rate_hz": 20}}]}],
              "infrastructure": {"count": 0}}
    generate(scenario_from_dict(config, "test"), tmp_path / "d", progress=False)
    reader = DatasetReader(tmp_path / "d")
    assert reader.frames().column("timestamp_ns").to_pylist() == [0, 50_000_000]


@pytest.mark.parametrize(("edit", "message"), [
    # Each failed only after the town was built and the scene simulated (two poses of one frame, a frame tree
    # error), or wrote frames like 'ego/x/y' and 'ego/' that break the <agent>/<sensor> naming.
    ({"egos": [{"name": "ego"}, {"name": "ego"}]}, "field egos[1].name: expected a name without '/' that no other "
                                                   "agent or sensor of its agent has, got 'ego'"),
    ({"egos": [{"name": "infra_01"}]}, "field egos[0].name: expected a name without '/'"),
    ({"egos": [{"name": "a/b"}]}, "field egos[0].name: expected a name without '/'"),
    ({"egos": [{"name": "ego", "sensors": [SMALL["egos"][0]["sensors"][0], {**SMALL["egos"][0]["sensors"][1],
                                                                            "name": "lidar_top"}]}]},
     "field egos[0].sensors[1].name: expected a name without '/' that no other agent or sensor of its agent has, got "
     "'lidar_top'"),
    ({"egos": [{"name": "ego", "sensors": [{**SMALL["egos"][0]["sensors"][0], "name": ""}]}]},
     "field egos[0].sensors[0].name: expected a name without '/'"),
    ({"bogus": 1}, "field bogus: expected one of"),
])
def test_names_that_break_the_frame_tree_are_refused_before_any_work(edit, message):
    with pytest.raises(InputError) as error:
        scenario_from_dict({**SMALL, **edit}, "s.yaml")
    assert str(error.value).startswith(f"s.yaml: {message}")
