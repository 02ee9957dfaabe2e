"""DAIR-V2X-C pairs grouped into sequences by ``batch_id``, on a fixture built around the real files.

DAIR-V2X's ``data/README.md`` lists ``batch_id`` (with ``batch_start_id``, ``batch_end_id``,
``intersection_loc``) among the fields of ``vehicle-side/data_info.json`` and
``infrastructure-side/data_info.json`` ("Infrastructure and vehicle frame with the same batch_id share the
same segments"); the devkit groups frames by it (``v2x/dataset/dair_v2x_for_detection.py``
``VICDataset.veh_frames``). Values are strings ("34"), timestamps µs strings.

The fixture: :func:`tests.converters.test_dair_v2x.build_dair` lays out the real pair (vehicle 017314,
infrastructure 001366) with calibrations and cameras; here more pairs are added in the official layout,
their PCDs, labels, images and camera calibrations linked to the real pair's files under new frame ids,
each vehicle frame with its own ``novatel_to_world`` on a straight drive at 10 m/s:

- batch "12": vehicle frames 017314, 017316, 017315 at T0, T0 + 0.1 s, T0 + 0.2 s (ids out of time order
  on purpose: the order is the timestamps'), one infrastructure pose for all three;
- batch "13": 017320, 017321 a minute later, their pairs with different ``system_error_offset``;
- 017330: a row without ``batch_id``.

``cooperative/data_info.json`` lists the pairs shuffled.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.dair_v2x import DairV2xConverter
from avdata.schema import DatasetReader
from avdata.schema.validate import validate_dataset
from tests.converters.test_dair_v2x import REAL, build_dair, homogeneous, yaw_matrix

T0_US = 1626155145901946
SPEED_M_S = 10.0
HEADING_RAD = 1.234
#: vehicle frame -> (batch_id or None, time offset from T0 in µs, infrastructure frame, system_error_offset)
PAIRS = {
    "017314": ("12", 0, "001366", (-0.7, -0.54)),
    "017316": ("12", 100_000, "001367", (-0.7, -0.54)),
    "017315": ("12", 200_000, "001368", (-0.7, -0.54)),
    "017320": ("13", 60_000_000, "001370", (-0.7, -0.54)),
    "017321": ("13", 60_100_000, "001371", (-0.2, 0.3)),
    "017330": (None, 90_000_000, "001380", (-0.7, -0.54)),
}
LIST_ORDER = ["017316", "017330", "017321", "017314", "017320", "017315"]
INFRA_DELAY_US = 58_736  # the real pair's infrastructure sweep is this much before the vehicle's
IMAGE_DELAY_US = 38_416


def novatel_to_world(offset_us: int) -> np.ndarray:
    roll = np.array([[1, 0, 0], [0, np.cos(0.01), -np.sin(0.01)], [0, np.sin(0.01), np.cos(0.01)]])
    position = np.array([2043.71, -1287.45, 19.8]) + SPEED_M_S * offset_us / 1e6 * np.array(
        [np.cos(HEADING_RAD), np.sin(HEADING_RAD), 0.0])
    return homogeneous(yaw_matrix(HEADING_RAD) @ roll, position)


def link(path: Path, target: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.is_symlink() or path.exists():
        path.unlink()
    os.symlink(target.resolve(), path)


def write_json(path: Path, content: object) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.is_symlink() or path.exists():
        path.unlink()
    path.write_text(json.dumps(content))


def build_sequences(root: Path, pairs: dict = PAIRS) -> dict[str, np.ndarray]:
    """The layout above; returns each vehicle frame's devkit lidar-to-world 4x4 (novatel_to_world @ lidar_to_novatel)."""
    build_dair(root, skew=0.0)
    vehicle, infra = root / "vehicle-side", root / "infrastructure-side"
    lidar_to_novatel = json.loads((vehicle / "calib/lidar_to_novatel/017314.json").read_text())["transform"]
    novatel_T_lidar = homogeneous(np.array(lidar_to_novatel["rotation"]), np.ravel(lidar_to_novatel["translation"]))
    labels = json.loads((REAL / "vehicle-side/label/lidar/017314.json").read_text())
    base_rows = {side: json.loads((root / side / "data_info.json").read_text())[0]
                 for side in ("vehicle-side", "infrastructure-side")}
    vehicle_rows, infra_rows, cooperative, chains = [], [], {}, {}
    for frame, (batch, offset_us, infra_frame, offset_xy) in pairs.items():
        for side, side_frame, base in (("vehicle-side", frame, "017314"), ("infrastructure-side", infra_frame, "001366")):
            lidar_label = "lidar" if side == "vehicle-side" else "virtuallidar"
            extrinsic = "lidar_to_camera" if side == "vehicle-side" else "virtuallidar_to_camera"
            for rel in ("velodyne/{}.pcd", f"label/{lidar_label}/{{}}.json", "image/{}.jpg",
                        "calib/camera_intrinsic/{}.json", f"calib/{extrinsic}/{{}}.json"):
                if side_frame != base:
                    link(root / side / rel.format(side_frame), root / side / rel.format(base))
        if infra_frame != "001366":
            link(infra / f"calib/virtuallidar_to_world/{infra_frame}.json",
                 infra / "calib/virtuallidar_to_world/001366.json")
        if frame != "017314":
            link(vehicle / f"calib/lidar_to_novatel/{frame}.json", vehicle / "calib/lidar_to_novatel/017314.json")
        world_T_novatel = novatel_to_world(offset_us)
        write_json(vehicle / f"calib/novatel_to_world/{frame}.json",
                   {"rotation": world_T_novatel[:3, :3].tolist(), "translation": world_T_novatel[:3, 3:].tolist()})
        chains[frame] = world_T_novatel @ novatel_T_lidar
        heading = np.arctan2(chains[frame][1, 0], chains[frame][0, 0])
        world_labels = []
        for entry in labels:
            centre = chains[frame] @ np.array([*(entry["3d_location"][k] for k in "xyz"), 1.0])
            world_labels.append({**entry, "3d_location": dict(zip("xyz", centre[:3].tolist(), strict=True)),
                                 "rotation": float(entry["rotation"]) + float(heading)})
        write_json(root / f"cooperative/label_world/{frame}.json", world_labels)
        batch_fields = {} if batch is None else {"batch_id": batch, "intersection_loc": "yizhuang08"}
        time_us = T0_US + offset_us
        vehicle_rows.append({**base_rows["vehicle-side"], "image_path": f"image/{frame}.jpg",
                             "image_timestamp": str(time_us - IMAGE_DELAY_US), "pointcloud_path": f"velodyne/{frame}.pcd",
                             "pointcloud_timestamp": str(time_us),
                             "calib_camera_intrinsic_path": f"calib/camera_intrinsic/{frame}.json",
                             "calib_lidar_to_camera_path": f"calib/lidar_to_camera/{frame}.json", **batch_fields})
        infra_rows.append({**base_rows["infrastructure-side"], "image_path": f"image/{infra_frame}.jpg",
                           "image_timestamp": str(time_us - INFRA_DELAY_US - 27_000),
                           "pointcloud_path": f"velodyne/{infra_frame}.pcd",
                           "pointcloud_timestamp": str(time_us - INFRA_DELAY_US),
                           "calib_camera_intrinsic_path": f"calib/camera_intrinsic/{infra_frame}.json",
                           "calib_virtuallidar_to_camera_path": f"calib/virtuallidar_to_camera/{infra_frame}.json",
                           **batch_fields})
        cooperative[frame] = {
            "infrastructure_image_path": f"infrastructure-side/image/{infra_frame}.jpg",
            "infrastructure_pointcloud_path": f"infrastructure-side/velodyne/{infra_frame}.pcd",
            "vehicle_image_path": f"vehicle-side/image/{frame}.jpg",
            "vehicle_pointcloud_path": f"vehicle-side/velodyne/{frame}.pcd",
            "cooperative_label_path": f"cooperative/label_world/{frame}.json",
            "system_error_offset": {"delta_x": offset_xy[0], "delta_y": offset_xy[1]},
        }
    write_json(vehicle / "data_info.json", vehicle_rows)
    write_json(infra / "data_info.json", infra_rows)
    write_json(root / "cooperative/data_info.json", [cooperative[f] for f in LIST_ORDER if f in cooperative])
    return chains


def convert(src: Path, dst: Path):
    return run_conversion(DairV2xConverter(ConvertConfig(src=src, dst=dst, quiet=True)))


def test_scenes_are_batches_in_time_order_with_continuous_poses(tmp_path: Path) -> None:
    chains = build_sequences(tmp_path / "src")
    result = convert(tmp_path / "src", tmp_path / "dst")
    assert result.problems == []
    assert result.written == ["coop_017330", "coop_batch_12", "coop_batch_13"]
    assert validate_dataset(tmp_path / "dst") == []
    dataset = DatasetReader(tmp_path / "dst")
    expected = {"coop_batch_12": ["017314", "017316", "017315"], "coop_batch_13": ["017320", "017321"],
                "coop_017330": ["017330"]}
    for scene_name, frames in expected.items():
        scene = dataset.scene(scene_name)
        assert [pair["vehicle_frame"] for pair in scene.metadata["pairs"]] == frames
        assert scene.metadata["batch_id"] == (None if scene_name == "coop_017330" else scene_name[-2:])
        times = [info.timestamp_ns for info in scene.frame_infos()]
        assert times == [(T0_US + PAIRS[f][1]) * 1000 for f in frames]  # frame k is the k-th in time
        graph = dataset.frame_graph(scene_name)
        ids = set()
        for index, (frame, time_ns) in enumerate(zip(frames, times, strict=True)):
            world_T_lidar = graph.lookup("world", "ego/lidar", time_ns).as_matrix()
            np.testing.assert_allclose(world_T_lidar, chains[frame], atol=1e-9)  # each frame its own pose
            sensor_times = scene.frame_infos()[index].sensor_timestamps_ns
            assert sensor_times["ego/camera"] == time_ns - IMAGE_DELAY_US * 1000  # every frame's images kept
            assert sensor_times["infra/lidar"] == time_ns - INFRA_DELAY_US * 1000 and "infra/camera" in sensor_times
            labels = scene.labels(index)[1]
            assert len(labels) == 23 and not ids & set(labels.boxes.ids.tolist())  # no id across frames
            ids |= set(labels.boxes.ids.tolist())
        # Continuity: consecutive ego poses are the drive's 10 m/s apart, and halfway the pose is halfway.
        for before, after in zip(times, times[1:], strict=False):
            if after - before > 1e9:
                continue
            a, b = (graph.lookup("world", "ego", t).translation for t in (before, after))
            assert abs(np.linalg.norm(b - a) - SPEED_M_S * (after - before) / 1e9) < 1e-6
            middle = graph.lookup("world", "ego", (before + after) // 2).translation
            np.testing.assert_allclose(middle, (a + b) / 2, atol=1e-6)
        # The first image precedes the first sweep: it takes its frame's pose (the devkit's), not an extrapolation.
        first_image_ns = times[0] - IMAGE_DELAY_US * 1000
        np.testing.assert_allclose(graph.lookup("world", "ego", first_image_ns).as_matrix(),
                                   graph.lookup("world", "ego", times[0]).as_matrix(), atol=0)


def test_infrastructure_pose_static_when_one_stamped_when_the_offset_changes(tmp_path: Path) -> None:
    build_sequences(tmp_path / "src")
    convert(tmp_path / "src", tmp_path / "dst")
    dataset = DatasetReader(tmp_path / "dst")
    raw = json.loads((tmp_path / "src/infrastructure-side/calib/virtuallidar_to_world/001366.json").read_text())
    for scene_name, static in (("coop_batch_12", True), ("coop_batch_13", False)):
        scene = dataset.scene(scene_name)
        assert scene.metadata["infrastructure_pose"].startswith("one pose" if static else "stamped per frame")
        graph = dataset.frame_graph(scene_name)
        assert graph.can_lookup("world", "infra", None) == static
        for pair in scene.metadata["pairs"]:
            infra_time_ns = pair["source_timestamps_us"]["infrastructure"] * 1000
            devkit = np.ravel(raw["translation"]) + [*PAIRS[pair["vehicle_frame"]][3], 0.0]  # t += delta_x, delta_y
            np.testing.assert_allclose(graph.lookup("world", "infra/lidar", infra_time_ns).translation, devkit,
                                       atol=1e-9)


def test_a_bad_pair_costs_its_frame_not_the_sequence(tmp_path: Path) -> None:
    build_sequences(tmp_path / "src")
    pose = tmp_path / "src/vehicle-side/calib/novatel_to_world/017316.json"
    pose.write_text(json.dumps({"rotation": [[1.0, 0.0, 0.0]], "translation": [[0.0], [0.0], [0.0]]}))
    result = convert(tmp_path / "src", tmp_path / "dst")
    assert [(p.severity, p.scene) for p in result.problems] == [("error", "coop_batch_12")]
    assert str(pose) in result.problems[0].message and "pair left out of batch 12" in result.problems[0].message
    scene = DatasetReader(tmp_path / "dst").scene("coop_batch_12")
    assert [pair["vehicle_frame"] for pair in scene.metadata["pairs"]] == ["017314", "017315"]
    assert len(scene.frame_infos()) == 2


def test_interleaved_batches_stay_apart_with_one_warning_each(tmp_path: Path) -> None:
    # 017320 of batch 13 recorded between batch 12's frames: one vehicle cannot drive both segments at once.
    build_sequences(tmp_path / "src", {**PAIRS, "017320": ("13", 150_000, "001370", (-0.7, -0.54))})
    result = convert(tmp_path / "src", tmp_path / "dst")
    assert result.written == ["coop_017330", "coop_batch_12", "coop_batch_13"]
    warnings = [(p.scene, p.message) for p in result.problems]
    assert [scene for scene, _ in warnings] == ["coop_batch_12", "coop_batch_13"]
    assert warnings[0][1] == (f"batch 12: vehicle frames of batch(es) 13 lie inside its time span {T0_US} .. "
                              f"{T0_US + 200_000} µs (1 frames, first 017320); kept as separate sequences by batch_id, "
                              "as the devkit groups them")
    assert "vehicle frames of batch(es) 12 lie inside" in warnings[1][1]
    assert [p["vehicle_frame"] for p in DatasetReader(tmp_path / "dst").scene("coop_batch_13").metadata["pairs"]] == [
        "017320", "017321"]


def test_an_unusable_batch_id_leaves_the_pair_on_its_own_with_a_warning(tmp_path: Path) -> None:
    build_sequences(tmp_path / "src")
    data_info = tmp_path / "src/vehicle-side/data_info.json"
    rows = json.loads(data_info.read_text())
    write_json(data_info, [{**row, "batch_id": "../12"} if row["pointcloud_path"].endswith("017315.pcd") else row
                           for row in rows])
    result = convert(tmp_path / "src", tmp_path / "dst")
    assert result.written == ["coop_017315", "coop_017330", "coop_batch_12", "coop_batch_13"]
    assert [(p.severity, p.scene, p.message) for p in result.problems] == [
        ("warning", "coop_017315", "frame 017315: field batch_id: expected a batch name (1 to 64 letters, digits, _ "
                                   "or -), got '../12'; the pair is its own scene"),
        ("warning", "coop_017315", "frame 001368: field batch_id: expected '../12' (its vehicle frame 017315's), got "
                                   "'12'; the pair follows its vehicle frame's batch")]


def test_latency_takes_the_infrastructure_from_the_previous_frame_of_the_sequence(tmp_path: Path) -> None:
    # What sequences are for: V2X-ViT's 100 ms delay needs an earlier frame of the same scene (10 Hz here).
    from avdata.loaders import Collaboration, FrameDataset, FrameOptions

    build_sequences(tmp_path / "src")
    convert(tmp_path / "src", tmp_path / "dst")

    def items(**link: float) -> list[dict]:
        collaboration = Collaboration(agents=("ego", "infra"), fusion="intermediate", **link)
        dataset = FrameDataset(tmp_path / "dst", FrameOptions(sensors=("*/lidar",), collaboration=collaboration),
                               scenes=["coop_batch_12"])
        return [dataset[i] for i in range(len(dataset))]

    times = [(T0_US + PAIRS[f][1]) * 1000 for f in ("017314", "017316", "017315")]
    clean, delayed = items(), items(latency_ms=100.0)
    assert [item["agent_timestamps_ns"].tolist() for item in clean] == [[t, t] for t in times]
    assert [item["agent_timestamps_ns"].tolist()[1] for item in delayed[1:]] == times[:2]
    assert [item["agent_mask"].tolist()[:2] for item in delayed] == [[True, False], [True, True], [True, True]]


def test_two_sweeps_at_one_time_cost_the_later_pair(tmp_path: Path) -> None:
    build_sequences(tmp_path / "src", {**PAIRS, "017315": ("12", 100_000, "001368", (-0.7, -0.54))})
    result = convert(tmp_path / "src", tmp_path / "dst")
    assert [(p.severity, p.scene, p.message) for p in result.problems] == [
        ("error", "coop_batch_12", f"frame 017316: field pointcloud_timestamp: expected one vehicle sweep per time in "
                                   f"batch 12, got {T0_US + 100_000} µs as frame 017315; pair left out")]
    pairs = DatasetReader(tmp_path / "dst").scene("coop_batch_12").metadata["pairs"]
    assert [pair["vehicle_frame"] for pair in pairs] == ["017314", "017315"]
