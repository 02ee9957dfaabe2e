"""nuScenes / Lyft converter against the real sample files and against nuscenes-devkit 1.2.0.

Real inputs (read in place): the 13 Lyft tables in ../shared/realdata/nuscenes_schema/lyft, the
partial nuScenes v1.0-mini tables, a full LIDAR_TOP sweep and camera JPEGs. The synthetic table set
is built in a tmp folder from real v1.0-mini rows (scenes, samples, logs, sensors, calibrations,
categories, attributes, visibility) plus made-up sample_data, ego poses and annotations that point
at the real sensor files (and one synthetic radar PCD); the devkit converts it too.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.base import StrictError
from avdata.converters.nuscenes import NuScenesConverter
from avdata.errors import InputError
from avdata.frames import Transform
from avdata.schema import DatasetReader
from avdata.sources.nuscenes import iter_json_array, read_lidar_bin, us_to_ns
from avdata.sources.nuscenes.jsonio import RepeatedKeyRecord
from avdata.sources.pcd import decode_pcd
from tests.realdata import REALDATA

REPO = Path(__file__).resolve().parents[2]
LYFT_ROOT = REALDATA / "nuscenes_schema" / "lyft" / "v1.01-train"
LYFT_SCENE = "host-a101-lidar0-1240710366399037786-1240710391298976894"
NUSCENES = REALDATA / "nuscenes"
MINI = NUSCENES / "v1.0-mini"
LIDAR_FILE = "samples/LIDAR_TOP/n015-2018-07-24-11-22-45+0800__LIDAR_TOP__1532402927647951.pcd.bin"
ORACLE_PYTHON = REPO / ".oracle-envs" / "nuscenes" / "bin" / "python"
TOL_M = 1e-6
TOL_RAD = 1e-6


def run_devkit(version: str, dataroot: Path) -> dict:
    """The devkit's reference values (tests/oracles/nuscenes_boxes.py); fails if the venv is missing."""
    if not ORACLE_PYTHON.exists():
        pytest.fail(f"oracle env missing at {ORACLE_PYTHON}; run tests/oracles/make_envs.sh")
    proc = subprocess.run(
        [str(ORACLE_PYTHON), str(REPO / "tests" / "oracles" / "nuscenes_boxes.py"), version, str(dataroot)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout)


def convert(src: Path, dst: Path, version: str | None, strict: bool = False):
    config = ConvertConfig(src=src, dst=dst, quiet=True, strict=strict, options={"version": version})
    return run_conversion(NuScenesConverter(config))


def rotation_angle(quat_a: np.ndarray, quat_b: np.ndarray) -> np.ndarray:
    """(N,) angle in radians of the rotation between scalar-first quaternions (N, 4) a and b."""
    a = Rotation.from_quat(np.asarray(quat_a, dtype=np.float64).reshape(-1, 4), scalar_first=True)
    b = Rotation.from_quat(np.asarray(quat_b, dtype=np.float64).reshape(-1, 4), scalar_first=True)
    return (a.inv() * b).magnitude()


def sensor_frame(channel: str) -> str:
    return f"ego/{channel.lower()}"


def compare_with_devkit(dataset: Path, scenes: list[str], oracle: dict, tables: Path | None = None) -> dict[str, float]:
    """Asserts boxes, ego poses and calibrations equal the devkit's; returns the largest differences.

    A frame lists only the sensor messages that were written; with ``tables`` (the source's), the key-frame
    sample_data rows whose files are absent (the real Lyft sample ships none) are compared too, at their
    sample's frame.
    """
    reader = DatasetReader(dataset)
    ours: dict[str, tuple] = {}
    graphs = {}
    at_time: dict[int, tuple] = {}
    for name in scenes:
        scene = reader.scene(name)
        graphs[name] = scene.graph
        for info in scene.frame_infos():
            _, labels = scene.labels(info.frame_index)
            at_time[info.timestamp_ns] = (name, labels)
            for frame, time_ns in info.sensor_timestamps_ns.items():
                ours[(frame, time_ns)] = (name, labels)
    if tables is not None:
        sample_ns = {row["token"]: us_to_ns(row["timestamp"]) for row in json.loads((tables / "sample.json").read_text())}
        key_rows = {row["token"]: sample_ns[row["sample_token"]]
                    for row in json.loads((tables / "sample_data.json").read_text()) if row["is_key_frame"]}
        for record in oracle["sample_data"]:
            key = (sensor_frame(record["channel"]), us_to_ns(json.loads(record["timestamp"])))
            if key not in ours and key_rows.get(record["token"]) in at_time:
                ours[key] = at_time[key_rows[record["token"]]]
    worst = {
        "center_m": 0.0,
        "size_m": 0.0,
        "angle_rad": 0.0,
        "ego_m": 0.0,
        "ego_rad": 0.0,
        "calib_m": 0.0,
        "calib_rad": 0.0,
    }
    n_boxes = 0
    n_key = 0
    for record in oracle["sample_data"]:
        frame = sensor_frame(record["channel"])
        time_ns = us_to_ns(json.loads(record["timestamp"]))
        key = (frame, time_ns)
        if key not in ours:  # a sweep: not a frame, its boxes are the devkit's interpolation
            continue
        n_key += 1
        name, labels = ours[key]
        graph = graphs[name]
        world_T_ego = graph.lookup("world", "ego", time_ns)
        expected = Transform.from_quat_wxyz(record["ego_rotation"], record["ego_translation"])
        worst["ego_m"] = max(worst["ego_m"], float(np.abs(world_T_ego.translation - expected.translation).max()))
        worst["ego_rad"] = max(worst["ego_rad"], float(rotation_angle(world_T_ego.quat_wxyz(), record["ego_rotation"])[0]))
        ego_T_sensor = graph.lookup("ego", frame)
        worst["calib_m"] = max(worst["calib_m"], float(np.abs(ego_T_sensor.translation - record["sensor_translation"]).max()))
        worst["calib_rad"] = max(
            worst["calib_rad"], float(rotation_angle(ego_T_sensor.quat_wxyz(), record["sensor_rotation"])[0])
        )
        if record["camera_intrinsic"] is not None:
            calibration = reader.scene(name).camera_calibration(frame)
            np.testing.assert_array_equal(np.reshape(calibration.K, (3, 3)), record["camera_intrinsic"])
        boxes = labels.boxes.to(frame, graph, time_ns)
        row_of = {attrs["annotation_token"]: i for i, attrs in enumerate(labels.attributes or [])}
        assert sorted(row_of) == sorted(box["token"] for box in record["boxes"])
        for box in record["boxes"]:
            i = row_of[box["token"]]
            center, wlh, quat = boxes[i].to_nuscenes()
            worst["center_m"] = max(worst["center_m"], float(np.abs(center[0] - box["center"]).max()))
            worst["size_m"] = max(worst["size_m"], float(np.abs(wlh[0] - box["wlh"]).max()))
            worst["angle_rad"] = max(worst["angle_rad"], float(rotation_angle(quat, box["orientation"])[0]))
            n_boxes += 1
    assert n_key and n_boxes
    for name, value in worst.items():
        assert value <= (TOL_RAD if name.endswith("rad") else TOL_M), (name, value)
    return worst


# ----------------------------------------------------------------------------- real Lyft tables
@pytest.fixture(scope="module")
def lyft(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    dst = tmp_path_factory.mktemp("lyft")
    return dst, convert(LYFT_ROOT, dst, "v1.01-train")


@pytest.mark.oracle
def test_lyft_boxes_poses_calibrations_equal_devkit(lyft: tuple[Path, object]) -> None:
    dataset, result = lyft
    assert result.written == [LYFT_SCENE]
    oracle = run_devkit("v1.01-train", LYFT_ROOT)
    assert len(oracle["sample_data"]) == 10
    worst = compare_with_devkit(dataset, [LYFT_SCENE], oracle, LYFT_ROOT / "v1.01-train")
    print("max differences vs devkit (Lyft):", worst)


def test_lyft_missing_sensor_files_are_warnings_and_labels_still_convert(lyft: tuple[Path, object]) -> None:
    dataset, result = lyft
    assert result.failed == []
    missing = [p for p in result.problems if "sensor file missing" in p.message]
    assert {p.severity for p in missing} == {"warning"} and len(missing) == 10
    assert any(p.file == "lidar/host-a101_lidar1_1240710385903083166.bin" for p in missing)
    info, labels = DatasetReader(dataset).scene(LYFT_SCENE).labels(0)
    assert len(labels) == 4 and labels.boxes.frame == "world"
    assert labels.boxes.classes.tolist() == ["car"] * 4
    row = [a["annotation_token"] for a in labels.attributes].index(
        "c18679b6bd6c643cddec8b6c0d8cedf1ee92d10ce6861faaf3db8b30f541f5e7"
    )
    np.testing.assert_allclose(labels.boxes.size_lwh[row], [4.495, 2.046, 1.849])  # w-l-h -> l-w-h
    np.testing.assert_allclose(labels.boxes.center[row], [429.0921186021758, 2702.055704889004, -17.146943716495205])
    assert labels.attributes[row]["object_action_driving_straight_forward"] == "true"
    assert labels.extras[row] == {"num_lidar_pts": -1.0, "num_radar_pts": 0.0}
    assert labels.boxes.ids[row] == "9a0abe5b2b13aad45262f06461914db4484e34d4df889872a389212bc404b9c3"
    # prev/next point at annotations the excerpt does not hold: no neighbour, no velocity
    assert np.isnan(labels.boxes.velocity).all()
    assert info.timestamp_ns == 1556675185903083200
    meta = DatasetReader(dataset).scene(LYFT_SCENE).metadata
    assert (meta["location"], meta["vehicle"], meta["date_captured"]) == ("Palo Alto", "a101", "2019-05-01")
    assert meta["map"] == "maps/map_raster_palo_alto.png" and meta["split"] == "v1.01-train"


def test_lyft_float_microseconds_round_to_the_json_text() -> None:
    assert us_to_ns(1556675185903083.2) == 1556675185903083200  # the float itself is ...083.25
    assert us_to_ns(1556675185866660.0) == 1556675185866660000
    assert us_to_ns(1532402927647951) == 1532402927647951000
    assert us_to_ns(0.0005) == 0  # half a nanosecond: round half to even
    assert us_to_ns(0.0015) == 2
    with pytest.raises(InputError):
        us_to_ns(float("nan"))


def test_lyft_seven_poses_one_timestamp_lookups_at_camera_times(lyft: tuple[Path, object]) -> None:
    dataset, _ = lyft
    table = LYFT_ROOT / "v1.01-train"
    poses = {p["token"]: p for p in json.loads((table / "ego_pose.json").read_text())}
    assert len(poses) == 7 and len({p["timestamp"] for p in poses.values()}) == 1  # the quirk
    sensors = {s["token"]: s for s in json.loads((table / "sensor.json").read_text())}
    calibrations = {c["token"]: c for c in json.loads((table / "calibrated_sensor.json").read_text())}
    graph = DatasetReader(dataset).scene(LYFT_SCENE).graph
    assert len(graph.stamped_edge("ego").timestamps_ns) == 7
    for record in json.loads((table / "sample_data.json").read_text()):
        channel = sensors[calibrations[record["calibrated_sensor_token"]]["sensor_token"]]["channel"]
        pose = poses[record["ego_pose_token"]]
        world_T_ego = graph.lookup("world", "ego", us_to_ns(record["timestamp"]))
        np.testing.assert_allclose(world_T_ego.translation, pose["translation"], atol=1e-9, rtol=0)
        assert rotation_angle(world_T_ego.quat_wxyz(), pose["rotation"])[0] < 1e-9, channel


# ----------------------------------------------------------------------------- real nuScenes files
def test_partial_mini_tables_give_one_clear_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="missing ego_pose, sample_annotation, sample_data$"):
        convert(NUSCENES, tmp_path / "out", "v1.0-mini")


def _write_radar_pcd(path: Path) -> np.ndarray:
    """A binary PCD with the nuScenes radar header (18 fields); returns the points written."""
    fields = (
        "x y z dyn_prop id rcs vx vy vx_comp vy_comp is_quality_valid ambig_state x_rms y_rms "
        "invalid_state pdh0 vx_rms vy_rms".split()
    )
    sizes = [4, 4, 4, 1, 2, 4, 4, 4, 4, 4, 1, 1, 1, 1, 1, 1, 1, 1]
    types = "F F F I I F F F F F I I I I I I I I".split()
    codes = {("F", 4): "<f4", ("I", 1): "i1", ("I", 2): "<i2"}
    dtype = np.dtype([(f, codes[(t, s)]) for f, s, t in zip(fields, sizes, types, strict=True)])
    points = np.zeros(3, dtype=dtype)
    points["x"], points["y"], points["z"] = [10.5, 20.25, 30.0], [-1.0, 0.5, 2.0], 0.0
    points["id"], points["rcs"], points["dyn_prop"] = [7, 300, -2], [5.5, -3.0, 1.0], [1, 3, 0]
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        f"FIELDS {' '.join(fields)}\nSIZE {' '.join(map(str, sizes))}\nTYPE {' '.join(types)}\n"
        f"COUNT {' '.join(['1'] * 18)}\nWIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA binary\n"
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(header.encode() + points.tobytes())
    return points


def build_synthetic_nuscenes(root: Path) -> dict:
    """A v1.0-mini table set around the real sensor files; returns facts the tests check.

    Real rows: scenes 0061 and 0103 with their first three samples, their logs and maps, sensors, one
    calibration per channel, categories, attributes, visibility. Made up: sample_data (key frames of
    LIDAR_TOP, CAM_FRONT, CAM_BACK, RADAR_FRONT; one LIDAR_TOP sweep), an ego pose per sample_data
    (token = sample_data token, as in nuScenes), instances and annotations with prev/next chains.
    """
    tables = root / "v1.0-mini"
    tables.mkdir(parents=True)
    real = {
        name: json.loads((MINI / f"{name}.json").read_text())
        for name in (
            "scene",
            "sample",
            "log",
            "map",
            "sensor",
            "calibrated_sensor",
            "category",
            "attribute",
            "visibility",
        )
    }
    scenes = [s for s in real["scene"] if s["name"] in ("scene-0061", "scene-0103")]
    samples = []
    for scene in scenes:
        rows = sorted((s for s in real["sample"] if s["scene_token"] == scene["token"]), key=lambda s: s["timestamp"])
        rows = [dict(r) for r in rows[:3]]
        rows[-1]["next"] = ""
        scene.update(last_sample_token=rows[-1]["token"], nbr_samples=3)
        samples += rows
    logs = [log for log in real["log"] if log["token"] in {s["log_token"] for s in scenes}]
    maps = [dict(m, log_tokens=[t for t in m["log_tokens"] if t in {log["token"] for log in logs}]) for m in real["map"]]
    maps = [m for m in maps if m["log_tokens"]]
    channel_of = {s["token"]: s["channel"] for s in real["sensor"]}
    calibration = {}
    for row in real["calibrated_sensor"]:
        calibration.setdefault(channel_of[row["sensor_token"]], row)
    files = {  # real key-frame files, by (scene, sample index, channel)
        ("scene-0061", 0, "LIDAR_TOP"): LIDAR_FILE,
        (
            "scene-0061",
            0,
            "CAM_FRONT",
        ): "samples/CAM_FRONT/n015-2018-07-24-11-22-45+0800__CAM_FRONT__1532402927612460.jpg",
        (
            "scene-0061",
            0,
            "CAM_BACK",
        ): "samples/CAM_BACK/n015-2018-07-24-11-22-45+0800__CAM_BACK__1532402927637525.jpg",
        (
            "scene-0103",
            0,
            "CAM_FRONT",
        ): "samples/CAM_FRONT/n008-2018-08-01-15-16-36-0400__CAM_FRONT__1533151603512404.jpg",
        (
            "scene-0103",
            1,
            "CAM_FRONT",
        ): "samples/CAM_FRONT/n008-2018-08-01-15-16-36-0400__CAM_FRONT__1533151604012404.jpg",
        (
            "scene-0103",
            0,
            "CAM_BACK",
        ): "samples/CAM_BACK/n008-2018-08-01-15-16-36-0400__CAM_BACK__1533151603537558.jpg",
        (
            "scene-0103",
            1,
            "CAM_BACK",
        ): "samples/CAM_BACK/n008-2018-08-01-15-16-36-0400__CAM_BACK__1533151604037558.jpg",
    }
    for relative in set(files.values()):
        (root / relative).parent.mkdir(parents=True, exist_ok=True)
        (root / relative).symlink_to(NUSCENES / relative)
    sweep_file = "sweeps/LIDAR_TOP/n015-2018-07-24-11-22-45+0800__LIDAR_TOP__1532402927697951.pcd.bin"
    (root / sweep_file).parent.mkdir(parents=True)
    (root / sweep_file).symlink_to(NUSCENES / LIDAR_FILE)
    radar_file = "samples/RADAR_FRONT/n015-2018-07-24-11-22-45+0800__RADAR_FRONT__1532402927664178.pcd"
    radar_points = _write_radar_pcd(root / radar_file)
    offsets_us = {"LIDAR_TOP": 0, "CAM_FRONT": -35491, "CAM_BACK": -10426, "RADAR_FRONT": 16227}
    scene_name = {s["token"]: s["name"] for s in scenes}
    sample_data, ego_pose = [], []
    for sample in samples:
        index = [s["token"] for s in samples if s["scene_token"] == sample["scene_token"]].index(sample["token"])
        name = scene_name[sample["scene_token"]]
        for channel, offset in offsets_us.items():
            timestamp = sample["timestamp"] + offset
            filename = files.get((name, index, channel), f"samples/{channel}/{name}_{index}_{channel}.missing")
            if (name, index, channel) == ("scene-0061", 0, "RADAR_FRONT"):
                filename = radar_file
            if (root / filename).exists():  # a real file's name holds its capture time
                timestamp = int(filename.rsplit("__", 1)[1].split(".")[0])
            sample_data.append(
                {
                    "token": f"sd-{name}-{index}-{channel}",
                    "sample_token": sample["token"],
                    "ego_pose_token": f"sd-{name}-{index}-{channel}",
                    "calibrated_sensor_token": calibration[channel]["token"],
                    "timestamp": timestamp,
                    "fileformat": "jpg" if channel.startswith("CAM") else "pcd",
                    "is_key_frame": True,
                    "height": 900 if channel.startswith("CAM") else 0,
                    "width": 1600 if channel.startswith("CAM") else 0,
                    "filename": filename,
                    "prev": "",
                    "next": "",
                }
            )
        if (name, index) == ("scene-0061", 0):
            sample_data.append(
                {
                    "token": "sd-sweep",
                    "sample_token": samples[1]["token"],
                    "ego_pose_token": "sd-sweep",
                    "calibrated_sensor_token": calibration["LIDAR_TOP"]["token"],
                    "timestamp": sample["timestamp"] + 50000,
                    "fileformat": "pcd",
                    "is_key_frame": False,
                    "height": 0,
                    "width": 0,
                    "filename": sweep_file,
                    "prev": "",
                    "next": "",
                }
            )
    for row in sample_data:
        t = (row["timestamp"] - samples[0]["timestamp"]) * 1e-6
        yaw = 0.1 * t
        ego_pose.append(
            {
                "token": row["ego_pose_token"],
                "timestamp": row["timestamp"],
                "rotation": [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)],
                "translation": [400.0 + 5.0 * t, 1100.0 + 0.5 * t, 0.0],
            }
        )
    category = {c["name"]: c["token"] for c in real["category"]}
    attribute = {a["name"]: a["token"] for a in real["attribute"]}
    instances, annotations = [], []
    specs = [
        ("car-a", "vehicle.car", "vehicle.moving", [3, 3]),
        ("ped-b", "human.pedestrian.adult", "pedestrian.standing", [3, 0]),
        ("bus-c", "vehicle.bus.rigid", "vehicle.parked", [1, 0]),
    ]
    for instance, cat, attr, counts in specs:
        for scene_i, scene in enumerate(scenes):
            scene_samples = [s for s in samples if s["scene_token"] == scene["token"]][: counts[scene_i]]
            if not scene_samples:
                continue
            tokens = [f"ann-{instance}-{scene_i}-{k}" for k in range(len(scene_samples))]
            instances.append(
                {
                    "token": f"{instance}-{scene_i}",
                    "category_token": category[cat],
                    "nbr_annotations": len(tokens),
                    "first_annotation_token": tokens[0],
                    "last_annotation_token": tokens[-1],
                }
            )
            for k, (token, sample) in enumerate(zip(tokens, scene_samples, strict=True)):
                yaw = 0.3 + 0.05 * k
                annotations.append(
                    {
                        "token": token,
                        "sample_token": sample["token"],
                        "instance_token": f"{instance}-{scene_i}",
                        "visibility_token": "4",
                        "attribute_tokens": [attribute[attr]],
                        "translation": [410.0 + 3.0 * k + scene_i, 1102.0 - 0.7 * k, 1.1 + 0.01 * k],
                        "size": [1.9, 4.6, 1.7],
                        "rotation": [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)],
                        "prev": tokens[k - 1] if k else "",
                        "next": tokens[k + 1] if k + 1 < len(tokens) else "",
                        "num_lidar_pts": 10 + k,
                        "num_radar_pts": k,
                    }
                )
    out = {
        "scene": scenes,
        "sample": samples,
        "log": logs,
        "map": maps,
        "sensor": real["sensor"],
        "calibrated_sensor": list(calibration.values()),
        "category": real["category"],
        "attribute": real["attribute"],
        "visibility": real["visibility"],
        "instance": instances,
        "sample_annotation": annotations,
        "sample_data": sample_data,
        "ego_pose": ego_pose,
    }
    for name, rows in out.items():
        (tables / f"{name}.json").write_text(json.dumps(rows, indent=1))
    for m in maps:
        (root / m["filename"]).parent.mkdir(parents=True, exist_ok=True)
        (root / m["filename"]).symlink_to(NUSCENES / m["filename"])
    return {"radar_points": radar_points, "samples": samples}


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict, object]:
    src = tmp_path_factory.mktemp("nuscenes_src")
    facts = build_synthetic_nuscenes(src)
    dst = tmp_path_factory.mktemp("nuscenes_out")
    return src, dst, facts, convert(src, dst, "v1.0-mini")


def test_real_lidar_sweep_and_jpegs_are_stored_untouched(synthetic) -> None:
    src, dst, facts, result = synthetic
    assert sorted(result.written) == ["scene-0061", "scene-0103"] and result.failed == []
    scene = DatasetReader(dst).scene("scene-0061")
    raw = np.fromfile(NUSCENES / LIDAR_FILE, dtype="<f4").reshape(-1, 5)
    assert raw.shape == (34688, 5)
    points = scene.points("ego/lidar_top", 1532402927647951000)
    assert points.dtype.names == ("x", "y", "z", "intensity", "ring") and len(points) == 34688
    for i, name in enumerate(("x", "y", "z", "intensity", "ring")):
        np.testing.assert_array_equal(points[name], raw[:, i])
    data, fmt = scene.image("ego/cam_front", 1532402927612460000)
    assert (
        fmt == "jpeg"
        and data
        == (NUSCENES / "samples/CAM_FRONT" / "n015-2018-07-24-11-22-45+0800__CAM_FRONT__1532402927612460.jpg").read_bytes()
    )
    second = DatasetReader(dst).scene("scene-0103")
    data, _ = second.image("ego/cam_back", 1533151604037558000)
    assert data[:2] == b"\xff\xd8" and len(data) == 109601


def test_sweeps_are_messages_not_frames_and_radar_keeps_every_field(synthetic) -> None:
    src, dst, facts, _ = synthetic
    scene = DatasetReader(dst).scene("scene-0061")
    lidar_times = scene.times("/ego/lidar_top/points").tolist()
    assert lidar_times == [1532402927647951000, 1532402927697951000]  # key frame + sweep (others missing)
    infos = scene.frame_infos()
    assert [i.timestamp_ns for i in infos] == [us_to_ns(s["timestamp"]) for s in facts["samples"][:3]]
    assert infos[0].sensor_timestamps_ns["ego/lidar_top"] == 1532402927647951000
    assert infos[0].sensor_timestamps_ns["ego/cam_front"] == 1532402927612460000
    radar = scene.points("ego/radar_front", 1532402927664178000)
    expected = facts["radar_points"]
    assert radar.dtype.names == expected.dtype.names and len(radar.dtype.names) == 18
    for name in expected.dtype.names:
        np.testing.assert_array_equal(radar[name], expected[name])


@pytest.mark.oracle
def test_synthetic_boxes_and_velocities_equal_devkit(synthetic) -> None:
    src, dst, facts, _ = synthetic
    oracle = run_devkit("v1.0-mini", src)
    worst = compare_with_devkit(dst, ["scene-0061", "scene-0103"], oracle)
    print("max differences vs devkit (synthetic nuScenes):", worst)
    reader = DatasetReader(dst)
    checked = 0
    for name in ("scene-0061", "scene-0103"):
        scene = reader.scene(name)
        for info in scene.frame_infos():
            _, labels = scene.labels(info.frame_index)
            for i, attrs in enumerate(labels.attributes or []):
                expected = oracle["velocity"][attrs["annotation_token"]]
                np.testing.assert_allclose(
                    labels.boxes.velocity[i],
                    np.asarray(expected, dtype=float),
                    rtol=0,
                    atol=1e-12,
                    equal_nan=True,
                )
                checked += 1
    assert checked == 10
    _, labels = reader.scene("scene-0061").labels(1)
    row = [a["annotation_token"] for a in labels.attributes].index("ann-car-a-0-1")
    assert np.all(np.isfinite(labels.boxes.velocity[row]))
    _, labels = reader.scene("scene-0061").labels(0)
    bus = labels.boxes.classes.tolist().index("bus")
    assert np.isnan(labels.boxes.velocity[bus]).all()  # single annotation: NaN, as the devkit
    assert labels.source_classes[bus] == "vehicle.bus.rigid"
    assert labels.attributes[bus]["visibility"] == "v80-100" and labels.attributes[bus]["vehicle.parked"] == "true"


def test_synthetic_metadata_and_missing_files_warn(synthetic) -> None:
    _, dst, _, result = synthetic
    meta = DatasetReader(dst).scene("scene-0103").metadata
    assert meta["log"] == "n008-2018-08-01-15-16-36-0400" and meta["location"] == "boston-seaport"
    assert meta["map"].startswith("maps/") and meta["date_captured"] == "2018-08-01"
    missing = [p for p in result.problems if "sensor file missing" in p.message]
    assert missing and all(p.severity == "warning" and p.file.endswith(".missing") for p in missing)
    assert all(p.severity == "warning" for p in result.problems)


# ----------------------------------------------------------------------------- bad input
def _copy_tables(src: Path, dst: Path) -> Path:
    """The synthetic tables (not the sensor files) under a new dataroot, for breaking them."""
    (dst / "v1.0-mini").mkdir(parents=True)
    for table in (src / "v1.0-mini").glob("*.json"):
        (dst / "v1.0-mini" / table.name).write_text(table.read_text())
    for linked in ("samples", "sweeps", "maps"):
        (dst / linked).symlink_to(src / linked)
    return dst


def test_missing_table_names_it(synthetic, tmp_path: Path) -> None:
    src = _copy_tables(synthetic[0], tmp_path / "src")
    (src / "v1.0-mini" / "instance.json").unlink()
    with pytest.raises(InputError, match="missing instance$"):
        convert(src, tmp_path / "out", "v1.0-mini")


def _break_ego_pose_link(src: Path) -> str:
    path = src / "v1.0-mini" / "sample_data.json"
    rows = json.loads(path.read_text())
    row = next(r for r in rows if r["token"] == "sd-scene-0103-1-CAM_FRONT")
    row["ego_pose_token"] = "no-such-pose"
    path.write_text(json.dumps(rows))
    return row["token"]


def test_dangling_token_is_an_error_of_its_scene_and_other_scenes_convert(synthetic, tmp_path: Path) -> None:
    src = _copy_tables(synthetic[0], tmp_path / "src")
    token = _break_ego_pose_link(src)
    result = convert(src, tmp_path / "out", "v1.0-mini")
    errors = [p for p in result.problems if p.severity == "error"]
    assert [(p.scene, p.file) for p in errors] == [("scene-0103", "sample_data.json")]
    assert token in errors[0].message and "no-such-pose" in errors[0].message
    assert sorted(result.written) == ["scene-0061", "scene-0103"]
    scene = DatasetReader(tmp_path / "out").scene("scene-0103")
    assert scene.times("/ego/cam_front/image").tolist() == [1533151603512404000]  # the broken one skipped


def test_an_image_of_another_size_than_its_row_states_costs_that_image(synthetic, tmp_path: Path) -> None:
    # Was silent: a width of 7 on the camera's first row became the camera's calibration (1600 px images, 7 px K).
    src = _copy_tables(synthetic[0], tmp_path / "src")
    path = src / "v1.0-mini" / "sample_data.json"
    rows = json.loads(path.read_text())
    row = next(r for r in rows if r["token"] == "sd-scene-0103-0-CAM_FRONT")
    row["width"] = 7
    path.write_text(json.dumps(rows))
    result = convert(src, tmp_path / "out", "v1.0-mini")
    errors = [p for p in result.problems if p.severity == "error"]
    assert [(p.scene, p.file) for p in errors] == [("scene-0103", row["filename"])]
    assert errors[0].message.endswith("expected the 7 x 900 px that sample_data.json states (width, height), "
                                      "got a 1600 x 900 px JPEG")
    scene = DatasetReader(tmp_path / "out").scene("scene-0103")
    assert scene.times("/ego/cam_front/image").tolist() == [1533151604012404000]  # the other image kept
    calibration = scene.camera_calibration("ego/cam_front")
    assert (calibration.width, calibration.height) == (1600, 900)


def test_missing_sensor_file_warns_and_strict_stops_on_dangling_token(synthetic, tmp_path: Path) -> None:
    src = _copy_tables(synthetic[0], tmp_path / "src")
    result = convert(src, tmp_path / "lenient", "v1.0-mini", strict=True)  # warnings do not stop strict mode
    assert sorted(result.written) == ["scene-0061", "scene-0103"]
    _break_ego_pose_link(src)
    with pytest.raises(StrictError, match="dangling ego_pose_token no-such-pose"):
        convert(src, tmp_path / "strict", "v1.0-mini", strict=True)


def test_stream_parser_equals_json_load_across_chunk_boundaries(tmp_path: Path) -> None:
    for table in ("sample_data", "ego_pose", "calibrated_sensor"):
        path = LYFT_ROOT / "v1.01-train" / f"{table}.json"
        assert list(iter_json_array(path, chunk_chars=7)) == json.loads(path.read_text())
    braces = tmp_path / "braces.json"  # a "}" inside a string: the one-record-at-a-time path
    rows = [{"token": f"t{i}", "description": "left } right {" * (i % 3), "size": [1.0, 2.5]} for i in range(40)]
    braces.write_text(json.dumps(rows, indent=1))
    for chunk_chars in (7, 50, 1 << 20):
        assert list(iter_json_array(braces, chunk_chars=chunk_chars)) == rows
    broken = tmp_path / "broken.json"
    broken.write_text('[{"token": "a"}, {"token": ')
    with pytest.raises(InputError, match="malformed JSON"):
        list(iter_json_array(broken, chunk_chars=5))


def test_stream_parser_marks_a_record_with_a_key_given_twice(tmp_path: Path) -> None:
    # Both decoding paths (whole chunks; one record at a time when a string holds "}") and any chunk size: the
    # record with two different values for one key comes out marked, the others as json.load gives them.
    rows = [{"token": f"t{i}", "description": "left } right {" * (i % 2), "size": [1.0, 2.5]} for i in range(30)]
    texts = [json.dumps(row) for row in rows]
    texts[7] = texts[7][:-1] + ', "size": [3.0, 4.0]}'
    texts[9] = texts[9][:-1] + ', "token": "t9"}'  # the same value again: not ambiguous
    path = tmp_path / "repeated.json"
    path.write_text("[" + ",\n".join(texts) + "]")
    for chunk_chars in (7, 50, 1 << 20):
        parsed = list(iter_json_array(path, chunk_chars=chunk_chars))
        assert [type(row).__name__ for row in parsed].count("RepeatedKeyRecord") == 1
        assert isinstance(parsed[7], RepeatedKeyRecord) and parsed[7].repeated == ("size", [1.0, 2.5], [3.0, 4.0])
        assert parsed[:7] == rows[:7] and parsed[8:] == rows[8:]


def test_orphan_annotation_and_changed_calibration_are_errors(synthetic, tmp_path: Path) -> None:
    src = _copy_tables(synthetic[0], tmp_path / "src")
    path = src / "v1.0-mini" / "sample_annotation.json"
    rows = json.loads(path.read_text())
    rows[0]["sample_token"] = "no-such-sample"
    path.write_text(json.dumps(rows))
    calibrations = json.loads((src / "v1.0-mini" / "calibrated_sensor.json").read_text())
    sensors = json.loads((src / "v1.0-mini" / "sensor.json").read_text())
    front_sensor = next(s["token"] for s in sensors if s["channel"] == "CAM_FRONT")
    front = next(c for c in calibrations if c["sensor_token"] == front_sensor)
    moved = dict(front, token="moved-calibration", translation=[front["translation"][0] + 0.5, *front["translation"][1:]])
    calibrations.append(moved)
    (src / "v1.0-mini" / "calibrated_sensor.json").write_text(json.dumps(calibrations))
    data_path = src / "v1.0-mini" / "sample_data.json"
    sample_data = json.loads(data_path.read_text())
    late = [r for r in sample_data if r["calibrated_sensor_token"] == front["token"] and "scene-0103-2" in r["token"]]
    late[0]["calibrated_sensor_token"] = "moved-calibration"
    data_path.write_text(json.dumps(sample_data))
    result = convert(src, tmp_path / "out", "v1.0-mini")
    errors = sorted((p.scene, p.file, p.message) for p in result.problems if p.severity == "error")
    assert len(errors) == 2
    assert errors[0][:2] == ("scene-0061", "sample_annotation.json") and "no-such-sample" in errors[0][2]
    assert errors[1][:2] == ("scene-0103", "calibrated_sensor.json")
    assert "calibration changes within the scene" in errors[1][2] and "moved-calibration" in errors[1][2]
    assert sorted(result.written) == ["scene-0061", "scene-0103"]


def test_two_different_poses_at_one_time_warn_and_keep_the_first(synthetic, tmp_path: Path) -> None:
    src = _copy_tables(synthetic[0], tmp_path / "src")
    data_path = src / "v1.0-mini" / "sample_data.json"
    rows = json.loads(data_path.read_text())
    lidar = next(r for r in rows if r["token"] == "sd-scene-0103-1-LIDAR_TOP")
    camera = next(r for r in rows if r["token"] == "sd-scene-0103-1-CAM_BACK")
    camera["timestamp"] = lidar["timestamp"]  # same time, its own (different) pose
    camera["filename"] = "samples/CAM_BACK/moved.missing"
    data_path.write_text(json.dumps(rows))
    poses = {p["token"]: p for p in json.loads((src / "v1.0-mini" / "ego_pose.json").read_text())}
    result = convert(src, tmp_path / "out", "v1.0-mini")
    warnings = [p for p in result.problems if p.file == "ego_pose.json"]
    assert len(warnings) == 1 and f"two different ego poses at {lidar['timestamp'] * 1000} ns" in warnings[0].message
    world_T_ego = DatasetReader(tmp_path / "out").scene("scene-0103").graph.lookup("world", "ego", lidar["timestamp"] * 1000)
    kept = poses[lidar["ego_pose_token"]]  # the lidar's pose comes first in ego_pose.json
    np.testing.assert_allclose(world_T_ego.translation, kept["translation"], atol=1e-9, rtol=0)


def test_real_lyft_lidar_bin_is_five_float32_per_point_and_a_torn_file_is_rejected() -> None:
    path = LYFT_ROOT.parent / "lidar" / "host-a017_lidar1_1236118886501000046.bin"
    columns = read_lidar_bin(path.read_bytes(), path.name)
    assert columns.dtype.names == ("x", "y", "z", "intensity", "ring") and len(columns) == 5
    assert all(columns.dtype.fields[name][0] == np.dtype("<f4") for name in columns.dtype.names)
    np.testing.assert_array_equal(columns["intensity"], np.full(5, 100.0, dtype=np.float32))
    np.testing.assert_array_equal(columns["ring"], np.ones(5, dtype=np.float32))
    np.testing.assert_allclose(columns["x"][0], 50.65190887451172)
    with pytest.raises(InputError, match="expected a multiple of 20 bytes .* got 99 bytes"):
        read_lidar_bin(path.read_bytes()[:99], path.name)


@pytest.mark.parametrize(("value", "shown"), [(np.nan, "nan"), (np.inf, "inf"), (1e30, "1.0000000150474662e+30")])
def test_real_lyft_lidar_bin_value_no_lidar_measures_is_rejected(value, shown) -> None:
    # A damaged float (a flipped exponent bit) was stored as is: these formats have no checksum.
    path = LYFT_ROOT.parent / "lidar" / "host-a017_lidar1_1236118886501000046.bin"
    values = np.frombuffer(path.read_bytes(), dtype="<f4").copy()
    values[11] = value  # point 2, y
    message = rf"^x.bin: point 2, y: expected a finite value within \+-1e\+07, got {re.escape(shown)} "
    with pytest.raises(InputError, match=message):
        read_lidar_bin(values.tobytes(), "x.bin")


def test_radar_pcd_header_numbers_and_point_values_are_checked() -> None:
    # Radar files go through the one PCD reader (avdata.sources.pcd), as OPV2V's and DAIR-V2X's do.
    header = "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA binary\n"
    points = np.array([[1.0, 2.0, 0.0], [3.0, np.nan, 0.0]], dtype="<f4")
    with pytest.raises(InputError, match=r"^r.pcd: point 1, y: expected a finite value"):
        decode_pcd(header.encode() + points.tobytes(), "r.pcd")
    np.testing.assert_array_equal(decode_pcd(header.encode() + points[:1].tobytes() * 2, "r.pcd")["x"], [1.0, 1.0])
    # int("abc") was a ValueError traceback.
    with pytest.raises(InputError, match=r"^r.pcd: malformed PCD header \(invalid literal for int\(\) .*'abc'\)$"):
        decode_pcd(header.replace("SIZE 4 4 4", "SIZE 4 abc 4").encode() + points.tobytes(), "r.pcd")
    with pytest.raises(InputError, match=r"^r.pcd: binary data: expected 2 points x 12 bytes = 24 bytes, got 23$"):
        decode_pcd(header.encode() + (points[:1].tobytes() * 2)[:-1], "r.pcd")
