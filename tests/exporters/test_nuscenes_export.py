"""nuScenes export, loaded by the official devkit (nuscenes-devkit 1.2.0 in .oracle-envs/nuscenes): every
sample_data's boxes in the sensor frame, its calibration and ego pose equal avdata's to 1e-6, on a generated
V2I scene (ego and infrastructure sensors), on the real Lyft tables and on the real KITTI tracking sequence
converted to the unified format; the KITTI export names its channels as nuScenes does (LIDAR_TOP, CAM_FRONT),
so the devkit finds a LIDAR_TOP key frame in every sample and ``avdata eval detection --protocol nuscenes`` reads it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from avdata.converters import ConvertConfig, converter_class, run_conversion
from avdata.errors import AvdataError
from avdata.exporters.nuscenes import CHANNELS_FILE, annotation_token, export_nuscenes
from avdata.frames import Transform
from avdata.schema import DatasetReader
from avdata.sources.nuscenes.channels import channel_map
from tests.realdata import REALDATA

REPO = Path(__file__).resolve().parents[2]
LYFT_ROOT = REALDATA / "nuscenes_schema" / "lyft" / "v1.01-train"


def _devkit(version: str, dataroot: Path) -> dict:
    python = REPO / ".oracle-envs" / "nuscenes" / "bin" / "python"
    assert python.exists(), f"oracle env missing at {python}; run tests/oracles/make_envs.sh"
    proc = subprocess.run([str(python), str(REPO / "tests" / "oracles" / "nuscenes_boxes.py"), version, str(dataroot)],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout)


def _check(root: Path, out: Path, **options) -> int:
    result = export_nuscenes(root, out, version="v1.0-avdata", **options)
    oracle = _devkit("v1.0-avdata", out)
    ds = DatasetReader(root)
    tables = {name: json.loads((out / "v1.0-avdata" / f"{name}.json").read_text())
              for name in ("sample_data", "sample", "sensor")}
    assert len(oracle["sample_data"]) == result.sample_data == len(tables["sample_data"])
    sd_by_token = {r["token"]: r for r in tables["sample_data"]}
    sensor_of = {c: s for s, c in json.loads((out / CHANNELS_FILE).read_text()).items()}
    sample_frame = {}
    for scene in ds.scenes:
        for info in ds.scene(scene).frame_infos():
            sample_frame[(scene, round(info.timestamp_ns / 1000))] = info
    checked = 0
    for record in oracle["sample_data"]:
        sd = sd_by_token[record["token"]]
        scene = sd["filename"].split("/")[-1].split("__")[0]
        reader = ds.scene(scene)
        channel = sd["filename"].split("/")[1]
        sensor = sensor_of[channel]
        t_ns = int(sd["filename"].rsplit("__", 1)[1].split(".")[0])
        agent = sensor.split("/")[0]
        pose = reader.graph.lookup("world", agent, t_ns)
        np.testing.assert_allclose(record["ego_translation"], pose.translation, atol=1e-6)
        np.testing.assert_allclose(Transform.from_quat_wxyz(np.array(record["ego_rotation"])).rotation, pose.rotation, atol=1e-6)
        calib = reader.graph.lookup(agent, sensor, t_ns)
        np.testing.assert_allclose(record["sensor_translation"], calib.translation, atol=1e-6)
        sensor_rotation = Transform.from_quat_wxyz(np.array(record["sensor_rotation"])).rotation
        np.testing.assert_allclose(sensor_rotation, calib.rotation, atol=1e-6)
        if record["camera_intrinsic"] is not None and len(record["camera_intrinsic"]):
            k = np.asarray(reader.camera_calibration(sensor, t_ns).K).reshape(3, 3)
            np.testing.assert_allclose(record["camera_intrinsic"], k, atol=1e-9)
        sample = next(r for r in tables["sample"] if r["token"] == sd["sample_token"])
        info = sample_frame[(scene, sample["timestamp"])]
        _, labels = reader.labels(info.frame_index)
        # The devkit moves the sample's annotations with this sample_data's ego pose and calibration.
        boxes = labels.boxes.to("world", reader.graph, info.timestamp_ns)
        sensor_T_world = (pose @ calib).inverse()
        ours = boxes.transform(sensor_T_world, sensor)
        by_token = {annotation_token(scene, info.frame_index, str(oid)): k for k, oid in enumerate(ours.ids)}
        assert len(record["boxes"]) > 0
        for box in record["boxes"]:
            k = by_token[box["token"]]
            np.testing.assert_allclose(box["center"], ours.center[k], atol=1e-6)
            w, l, h = box["wlh"]
            np.testing.assert_allclose([l, w, h], ours.size_lwh[k], atol=1e-9)
            q = np.array(box["orientation"])
            np.testing.assert_allclose(Transform.from_quat_wxyz(q).rotation, ours.rotation_matrix()[k], atol=1e-6)
            checked += 1
    return checked


@pytest.fixture(scope="module")
def generated(generated_v2i: Path) -> Path:
    return generated_v2i


@pytest.mark.oracle
def test_generated_v2i_export_equals_devkit(generated: Path, tmp_path: Path) -> None:
    assert _check(generated, tmp_path / "nusc") > 100
    channels = {r["channel"]: r["modality"] for r in json.loads((tmp_path / "nusc" / "v1.0-avdata" / "sensor.json").read_text())}
    assert channels == {"LIDAR_TOP": "lidar", "CAM_FRONT": "camera", "INFRA_00_LIDAR": "lidar", "INFRA_01_LIDAR": "lidar"}
    points = np.fromfile(next((tmp_path / "nusc" / "samples" / "LIDAR_TOP").iterdir()), np.float32).reshape(-1, 5)
    ds = DatasetReader(generated)
    reader = ds.scene(ds.scenes[0])
    info = reader.frame_infos()[0]
    ours = reader.points("ego/lidar_top", info.sensor_timestamps_ns["ego/lidar_top"])
    np.testing.assert_array_equal(points[:, 0], ours["x"])
    np.testing.assert_array_equal(points[:, 4], ours["ring"])


def _lyft_with_sensor_files(root: Path) -> Path:
    """The real Lyft tables (unchanged), with a sensor file written for every sample_data: the shared sample ships
    truncated lidar files and no images, so there would be nothing to export."""
    import shutil

    import cv2

    shutil.copytree(LYFT_ROOT / "v1.01-train", root / "v1.01-train")
    shutil.copytree(LYFT_ROOT / "maps", root / "maps")
    rng = np.random.default_rng(0)
    for record in json.loads((root / "v1.01-train" / "sample_data.json").read_text()):
        path = root / record["filename"]
        path.parent.mkdir(parents=True, exist_ok=True)
        if record["filename"].endswith(".bin"):
            rng.normal(0, 10, (100, 5)).astype(np.float32).tofile(path)
        else:
            image = np.full((int(record["height"]), int(record["width"]), 3), 90, np.uint8)
            path.write_bytes(cv2.imencode(".jpg", image)[1].tobytes())
    return root


@pytest.mark.oracle
def test_converted_lyft_export_equals_devkit(tmp_path: Path) -> None:
    unified = tmp_path / "lyft"
    source = _lyft_with_sensor_files(tmp_path / "lyft-source")
    proc = subprocess.run([sys.executable, "-m", "avdata.cli", "convert", "nuscenes", str(source), str(unified),
                           "--version", "v1.01-train", "--quiet"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert _check(unified, tmp_path / "nusc") > 0
    categories = {r["name"] for r in json.loads((tmp_path / "nusc" / "v1.0-avdata" / "category.json").read_text())}
    assert categories <= {"car", "pedestrian", "truck", "bicycle", "other_vehicle", "bus", "motorcycle", "animal",
                          "emergency_vehicle"}  # Lyft's own category names, kept


# ----------------------------------------------------------------------------- channels named as nuScenes names them
_DEVKIT_SAMPLES = """
import json, sys
from nuscenes.nuscenes import NuScenes
nusc = NuScenes(version="v1.0-avdata", dataroot=sys.argv[1], verbose=False)
print(json.dumps([{channel: nusc.get("sample_data", token)["is_key_frame"] for channel, token in s["data"].items()}
                  for s in nusc.sample]))
"""


def test_channel_map_names_nuscenes_equivalents_and_keeps_the_rest() -> None:
    sensors = ["ego/velodyne", "ego/cam2", "ego/cam3", "infra_03/lidar", "ego/ring_rear_left"]
    assert channel_map(sensors, "ego") == {"ego/velodyne": "LIDAR_TOP", "ego/cam2": "CAM_FRONT", "ego/cam3": "CAM3",
                                           "infra_03/lidar": "INFRA_03_LIDAR", "ego/ring_rear_left": "CAM_BACK_LEFT"}
    assert channel_map(["ego/cam3"], "ego", {"ego/cam3": "CAM_FRONT_RIGHT"}) == {"ego/cam3": "CAM_FRONT_RIGHT"}
    # another agent's lidar is not the ego's top lidar
    assert channel_map(["infra/lidar", "ego/lidar"], "ego") == {"ego/lidar": "LIDAR_TOP", "infra/lidar": "INFRA_LIDAR"}
    with pytest.raises(AvdataError, match=r"channel CAM_FRONT: expected one sensor per channel, got \['ego/cam2', 'ego/cam3'\]"):
        channel_map(["ego/cam2", "ego/cam3"], "ego", {"ego/cam3": "CAM_FRONT"})
    with pytest.raises(AvdataError, match="expected a channel of A-Z"):
        channel_map(["ego/cam3"], "ego", {"ego/cam3": "cam front"})


@pytest.mark.oracle
def test_kitti_tracking_export_has_lidar_top_key_frames_and_goes_through_nuscenes_eval(tmp_path: Path) -> None:
    unified, out = tmp_path / "kitti", tmp_path / "nusc"
    config = ConvertConfig(src=REALDATA / "kitti" / "tracking", dst=unified, quiet=True)
    assert run_conversion(converter_class("kitti-tracking")(config)).written == ["training_0001"]
    proc = subprocess.run([sys.executable, "-m", "avdata.cli", "export", "nuscenes", str(unified), str(out), "--quiet",
                           "--channel", "ego/cam3=CAM_FRONT_RIGHT"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    # the real sample ships sweeps of frames 0 and 1 only: the 445 frames without a LIDAR_TOP message are no samples
    assert "2 samples" in proc.stdout and "445 frames skipped (no LIDAR_TOP message)" in proc.stdout
    tables = out / "v1.0-avdata"
    assert json.loads((out / CHANNELS_FILE).read_text()) == {
        "ego/cam0": "CAM0", "ego/cam1": "CAM1", "ego/cam2": "CAM_FRONT", "ego/cam3": "CAM_FRONT_RIGHT",
        "ego/velodyne": "LIDAR_TOP"}
    assert sorted(p.name for p in (out / "samples").iterdir()) == ["CAM_FRONT", "CAM_FRONT_RIGHT", "LIDAR_TOP"]
    python = REPO / ".oracle-envs" / "nuscenes" / "bin" / "python"
    devkit = subprocess.run([str(python), "-c", _DEVKIT_SAMPLES, str(out)], capture_output=True, text=True, timeout=600)
    assert devkit.returncode == 0, devkit.stderr[-3000:]
    # what mmdetection3d's converter reads: sample["data"]["LIDAR_TOP"] (and the CAM_* channels) of every sample
    assert json.loads(devkit.stdout) == [{"LIDAR_TOP": True, "CAM_FRONT": True, "CAM_FRONT_RIGHT": True}] * 2
    # perfect detections: the exported annotations as a submission
    annotations = json.loads((tables / "sample_annotation.json").read_text())
    detection_name = {"vehicle.car": "car", "human.pedestrian.adult": "pedestrian", "vehicle.bicycle": "bicycle",
                      "vehicle.truck": "truck"}
    results: dict[str, list[dict]] = {s["token"]: [] for s in json.loads((tables / "sample.json").read_text())}
    for a in annotations:
        category = next(c["name"] for c in json.loads((tables / "category.json").read_text())
                        if c["token"] == _instance_category(tables, a["instance_token"]))
        if category in detection_name:
            results[a["sample_token"]].append({
                "sample_token": a["sample_token"], "translation": a["translation"], "size": a["size"],
                "rotation": a["rotation"], "velocity": [0.0, 0.0], "detection_name": detection_name[category],
                "detection_score": 0.9, "attribute_name": ""})
    assert sum(map(len, results.values())) >= 10
    submission = tmp_path / "submission.json"
    submission.write_text(json.dumps({"meta": {"use_camera": False, "use_lidar": True, "use_radar": False,
                                               "use_map": False, "use_external": False}, "results": results}))
    proc = subprocess.run([sys.executable, "-m", "avdata.cli", "eval", "detection", "--protocol", "nuscenes",
                           str(tables), str(submission), "--json", str(tmp_path / "metrics.json")],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["car"]["AP"] == pytest.approx(1.0)
    _check(unified, tmp_path / "nusc-api", channels={"ego/cam3": "CAM_FRONT_RIGHT"})


def _instance_category(tables: Path, instance_token: str) -> str:
    instances = json.loads((tables / "instance.json").read_text())
    return next(i["category_token"] for i in instances if i["token"] == instance_token)


def test_channel_option_errors_are_one_line(generated: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from avdata.cli import main

    assert main(["export", "nuscenes", str(generated), str(tmp_path / "a"), "--channel", "ego/cam_front"]) == 1
    assert capsys.readouterr().err == "avdata: error: --channel: expected SENSOR=CHANNEL, got 'ego/cam_front'\n"
    assert main(["export", "nuscenes", str(generated), str(tmp_path / "b"), "--quiet", "--channel",
                 "ego/cam_front=LIDAR_TOP"]) == 1  # the scene's lidar_top is LIDAR_TOP already: that scene fails
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith("channel LIDAR_TOP: expected one sensor per channel, got ['ego/cam_front', "
                                             "'ego/lidar_top'] (map one of them to another channel, e.g. --channel "
                                             "ego/lidar_top=<CHANNEL>)")


def test_channel_of_an_unknown_or_twice_named_sensor_is_refused(generated: Path, tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    # a mistyped sensor was ignored and a repeated one took its last channel: exit 0 with the defaults / the last
    from avdata.cli import main

    assert main(["export", "nuscenes", str(generated), str(tmp_path / "a"), "--quiet", "--channel",
                 "ego/cam_frnt=CAM_BACK"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"avdata: error: {generated}: channel mapping: expected sensors of the dataset ['ego/cam_front', ")
    assert err.endswith(", got ['ego/cam_frnt']\n") and err.count("\n") == 1
    assert main(["export", "nuscenes", str(generated), str(tmp_path / "b"), "--quiet", "--channel", "ego/cam_front=CAM_BACK",
                 "--channel", "ego/cam_front=CAM_FRONT_LEFT"]) == 1
    assert capsys.readouterr().err == ("avdata: error: --channel: expected one channel per sensor, got ego/cam_front "
                                       "mapped to ['CAM_BACK', 'CAM_FRONT_LEFT']\n")
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    with pytest.raises(AvdataError, match=r"got \['infra_09/lidar'\]"):
        export_nuscenes(generated, tmp_path / "c", channels={"infra_09/lidar": "LIDAR_FRONT"})
    # the same channel named twice for one sensor is one mapping, not a conflict
    assert main(["export", "nuscenes", str(generated), str(tmp_path / "d"), "--quiet", "--channel", "ego/cam_front=CAM_BACK",
                 "--channel", "ego/cam_front=CAM_BACK"]) == 0
    assert json.loads((tmp_path / "d" / CHANNELS_FILE).read_text())["ego/cam_front"] == "CAM_BACK"
