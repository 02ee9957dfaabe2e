"""Argoverse 2 converter on the real val log, against av2-api 0.3.6 (its own venv) where it has an answer.

Real inputs, read in place through symlinks: ../shared/realdata/argoverse2/sensor/val/<log> (11,364
cuboids at 156 sweep times, 2 of the sweeps, poses, calibration, map). AV2 ships no camera images
here, so the fixture root adds JPEGs of the real sizes, named as AV2 names them, at real camera
times of the pose table. The root is ``val/<log>`` only (the real test/<log> is the same log id).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.feather as feather
import pytest

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.argoverse2 import LIDAR_FRAME, Argoverse2Converter
from avdata.exporters.cli import add_export_subparser
from avdata.frames import Transform
from avdata.schema import DatasetReader
from avdata.sources import argoverse2 as av2
from tests.eval.eval_oracle_env import run_oracle
from tests.realdata import REALDATA

REAL = REALDATA / "argoverse2" / "sensor"
LOG = "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"
REAL_LOG = REAL / "val" / LOG
SWEEPS = (315966265259836000, 315966265360032000)
CAMERAS = ("ring_front_center", "ring_side_left")


def link_log(src: Path, dst: Path) -> None:
    """A log folder of symlinks to every real file (so a test can drop or replace single files)."""
    for path in sorted(src.rglob("*")):
        if path.is_file():
            target = dst / path.relative_to(src)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.symlink(path, target)


def camera_times(sweep_ns: int) -> list[int]:
    """Real pose times within 40 ms of a sweep, other than the sweep's own (the cameras' capture times)."""
    poses = feather.read_table(REAL_LOG / "city_SE3_egovehicle.feather").column("timestamp_ns").to_numpy()
    near = poses[(np.abs(poses - sweep_ns) < 40_000_000) & (poses != sweep_ns)]
    return sorted(set(near.tolist()))


def write_images(log_dir: Path) -> dict[str, list[int]]:
    """JPEGs of the real sizes (ring_front_center is portrait 1550 x 2048) at real camera times."""
    intrinsics, _ = av2.read_intrinsics(REAL_LOG / "calibration" / "intrinsics.feather")
    written: dict[str, list[int]] = {}
    for k, camera in enumerate(CAMERAS):
        size = intrinsics[camera]
        image = np.full((size.height_px // 8, size.width_px // 8, 3), 40 * (k + 1), dtype=np.uint8)
        ok, data = cv2.imencode(".jpg", cv2.resize(image, (size.width_px, size.height_px)))
        assert ok
        folder = log_dir / "sensors" / "cameras" / camera
        folder.mkdir(parents=True, exist_ok=True)
        written[camera] = [t for s in SWEEPS for t in camera_times(s)]
        for time_ns in written[camera]:
            (folder / f"{time_ns}.jpg").write_bytes(data.tobytes())
    return written


@pytest.fixture(scope="module")
def av2_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("av2") / "sensor"
    link_log(REAL_LOG, root / "val" / LOG)
    write_images(root / "val" / LOG)
    return root


@pytest.fixture(scope="module")
def converted(av2_root, tmp_path_factory):
    dst = tmp_path_factory.mktemp("av2_unified")
    result = run_conversion(Argoverse2Converter(ConvertConfig(src=av2_root, dst=dst, quiet=True)))
    return dst, result


@pytest.fixture(scope="module")
def converted_sweeps_only(tmp_path_factory):
    """The real log with annotations.feather cut to the real rows of the two sweeps it ships (a clean log)."""
    root = tmp_path_factory.mktemp("av2_sweeps") / "sensor"
    log_dir = root / "val" / LOG
    link_log(REAL_LOG, log_dir)
    table = feather.read_table(REAL_LOG / "annotations.feather")
    keep = np.isin(table.column("timestamp_ns").to_numpy(), SWEEPS)
    (log_dir / "annotations.feather").unlink()
    feather.write_feather(table.filter(keep), log_dir / "annotations.feather", compression="uncompressed")
    dst = tmp_path_factory.mktemp("av2_sweeps_unified")
    result = run_conversion(Argoverse2Converter(ConvertConfig(src=root, dst=dst, quiet=True)))
    return dst, result


@pytest.fixture(scope="module")
def oracle(tmp_path_factory) -> dict:
    """av2's own points in city, cuboid vertices and camera projections on the real log."""
    out = tmp_path_factory.mktemp("av2_oracle") / "geometry.npz"
    summary = run_oracle("av2", "av2_geometry.py", str(REAL / "val"), LOG, str(out))
    with np.load(out) as arrays:
        return {"summary": summary, **{k: arrays[k] for k in arrays.files}}


def test_conversion_keeps_every_annotated_time_and_reports_the_missing_sweeps(converted):
    dst, result = converted
    assert result.written == [LOG] and not result.failed
    # The real log ships 2 of its 156 sweeps: one error line names the first missing file and the count.
    assert [p.severity for p in result.problems] == ["error"]
    assert "sensors/lidar/315966253660357000.feather" in result.problems[0].file
    assert "154 missing" in result.problems[0].message
    reader = DatasetReader(dst)
    frames = reader.frames()
    assert frames.num_rows == 156
    assert all(frames.column("annotated").to_pylist())
    objects = reader.objects()
    assert objects.num_rows == 11364
    scene = reader.scene(LOG)
    assert scene.metadata["split"] == "val" and scene.metadata["city"] == "PIT"
    assert scene.metadata["time_is_utc"] is False


def test_points_round_trip_exactly(converted):
    dst, _ = converted
    scene = DatasetReader(dst).scene(LOG)
    for time_ns in SWEEPS:
        source = av2.read_sweep(REAL_LOG / "sensors" / "lidar" / f"{time_ns}.feather")
        points = scene.points(LIDAR_FRAME, time_ns)
        assert points.dtype.names == ("x", "y", "z", "intensity", "laser_number", "offset_ns")
        for axis in "xyz":
            assert points[axis].dtype == np.float32
            # float16 -> float32 is exact: back to float16 gives the stored bytes.
            assert points[axis].astype(np.float16).tobytes() == source[axis].tobytes()
        for name in ("intensity", "laser_number", "offset_ns"):
            assert points[name].dtype == source[name].dtype
            np.testing.assert_array_equal(points[name], source[name])
        assert set(np.unique(points["laser_number"]).tolist()) <= set(range(64))


def test_points_in_world_equal_av2_transform_point_cloud(converted, oracle):
    dst, _ = converted
    scene = DatasetReader(dst).scene(LOG)
    assert oracle["summary"]["sweeps"] == list(SWEEPS)
    worst = 0.0
    for time_ns in SWEEPS:
        points = scene.points(LIDAR_FRAME, time_ns)
        xyz = np.stack([points[a] for a in "xyz"], axis=1).astype(np.float64)
        world = scene.graph.lookup("world", LIDAR_FRAME, time_ns).apply(xyz)
        expected = oracle[f"points_city_{time_ns}"]
        assert expected.shape == world.shape
        worst = max(worst, float(np.abs(world - expected).max()))
    print(f"points in world vs av2 city_SE3_egovehicle.transform_point_cloud: max |diff| {worst:.2e} m")
    assert worst < 1e-3


def test_every_cuboid_corner_in_world_equals_av2(converted, oracle):
    dst, _ = converted
    scene = DatasetReader(dst).scene(LOG)
    expected = {(int(t), str(u)): v
                for t, u, v in zip(oracle["cuboid_ts"], oracle["cuboid_uuid"], oracle["vertices_city"], strict=True)}
    assert len(expected) == 11364
    seen = 0
    worst = 0.0
    for info in scene.frame_infos():
        _, labels = scene.labels(info.frame_index)
        assert labels.boxes.frame == "world"
        corners = labels.boxes.corners()
        for object_id, box_corners in zip(labels.boxes.ids.tolist(), corners, strict=True):
            worst = max(worst, float(np.abs(box_corners - expected[(info.timestamp_ns, object_id)]).max()))
            seen += 1
    print(f"cuboid corners in world vs av2 CuboidList.transform(city_SE3_ego).vertices_m: max |diff| {worst:.2e} m")
    assert seen == 11364
    assert worst < 1e-6


def test_labels_keep_ids_categories_interior_points_and_ego_centres(converted):
    dst, _ = converted
    objects = DatasetReader(dst).objects()
    table = feather.read_table(REAL_LOG / "annotations.feather")
    keys = ("timestamp_ns", "track_uuid", "category", "num_interior_pts", "tx_m", "ty_m", "tz_m")
    source = {(row[0], row[1]): row[2:] for row in zip(*(table.column(k).to_pylist() for k in keys), strict=True)}
    columns = ("timestamp_ns", "object_id", "source_class", "class", "extras_json", "x_ego_m", "y_ego_m", "z_ego_m")
    rows = zip(*(objects.column(k).to_pylist() for k in columns), strict=True)
    seen = 0
    worst = 0.0
    for time_ns, object_id, source_class, unified, extras, *centre_ego in rows:
        category, n_points, *centre = source[(time_ns, object_id)]
        assert source_class == category
        assert unified == av2.unified_class(category)
        assert extras == f'{{"num_interior_pts": {float(n_points)}}}'
        worst = max(worst, float(np.abs(np.subtract(centre_ego, centre)).max()))
        seen += 1
    assert seen == len(source) == 11364
    # world -> ego through the same pose gives the source centres back (float64 noise only)
    assert worst < 1e-9
    pairs = set(zip(objects.column("source_class").to_pylist(), objects.column("class").to_pylist(), strict=True))
    assert {("REGULAR_VEHICLE", "car"), ("PEDESTRIAN", "pedestrian"), ("BOLLARD", "barrier"),
            ("BOX_TRUCK", "truck"), ("STROLLER", "other")} <= pairs


def test_camera_projection_equals_av2_project_ego_to_img(converted, oracle):
    dst, _ = converted
    scene = DatasetReader(dst).scene(LOG)
    time_ns = SWEEPS[0]
    points = scene.points(LIDAR_FRAME, time_ns)
    xyz = np.stack([points[a] for a in "xyz"], axis=1).astype(np.float64)
    worst = 0.0
    for camera in oracle["summary"]["cameras"]:
        frame = f"ego/{camera}"
        calibration = scene.camera_calibration(frame, time_ns)
        K = np.array(calibration.K).reshape(3, 3)
        cam = scene.graph.lookup(frame, LIDAR_FRAME, time_ns).apply(xyz)
        uv = (cam @ K.T)[:, :2] / cam[:, 2:3]
        valid = oracle[f"valid_{camera}"]
        inside = (cam[:, 2] > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < calibration.width - 1) \
            & (uv[:, 1] >= 0) & (uv[:, 1] < calibration.height - 1)
        np.testing.assert_array_equal(inside, valid)
        assert valid.sum() > 100
        worst = max(worst, float(np.abs(uv[valid] - oracle[f"uv_{camera}"][valid]).max()))
        intr = av2.read_intrinsics(REAL_LOG / "calibration" / "intrinsics.feather")[0][camera]
        assert list(calibration.D) == [intr.k1, intr.k2, 0.0, 0.0, intr.k3]
        assert calibration.distortion_model == "plumb_bob"
    print(f"projection vs av2 PinholeCamera.project_ego_to_img: max |diff| {worst:.2e} px")
    assert worst < 1e-6
    front = scene.camera_calibration("ego/ring_front_center", time_ns)
    assert (front.width, front.height) == (1550, 2048)  # portrait


def test_camera_frames_are_the_calibration_poses_and_lidar_frames_are_static(converted):
    dst, _ = converted
    scene = DatasetReader(dst).scene(LOG)
    poses, _ = av2.read_sensor_poses(REAL_LOG / "calibration" / "egovehicle_SE3_sensor.feather")
    for name, (quat_wxyz, translation) in poses.items():
        got = scene.graph.lookup("ego", f"ego/{name}", SWEEPS[0])
        assert got.allclose(Transform.from_quat_wxyz(quat_wxyz, translation), atol=1e-12)
    assert scene.graph.lookup("ego", LIDAR_FRAME, SWEEPS[0]).allclose(Transform.identity(), atol=0)


def test_images_untouched_and_matched_to_the_nearest_sweep(converted, av2_root):
    dst, _ = converted
    reader = DatasetReader(dst)
    scene = reader.scene(LOG)
    frames = {info.timestamp_ns: info for info in scene.frame_infos()}
    for camera in CAMERAS:
        frame = f"ego/{camera}"
        for sweep_ns in SWEEPS:
            nearest = min(camera_times(sweep_ns), key=lambda t: abs(t - sweep_ns))
            assert frames[sweep_ns].sensor_timestamps_ns[frame] == nearest
            data, fmt = scene.image(frame, nearest)
            assert fmt == "jpeg"
            assert data == (av2_root / "val" / LOG / "sensors" / "cameras" / camera / f"{nearest}.jpg").read_bytes()
        assert len(scene.times(f"/{frame}/image")) == sum(len(camera_times(s)) for s in SWEEPS)
    # annotated times without a sweep have no camera within 25 ms in this fixture
    assert frames[315966253660357000].sensor_timestamps_ns == {}


def test_frame_dataset_reads_the_converted_log(converted, converted_sweeps_only):
    torch = pytest.importorskip("torch")
    from avdata.loaders import FrameDataset

    labels_only = FrameDataset(converted[0], frame="world")
    assert len(labels_only) == 156
    assert sum(len(labels_only[i]["object_ids"]) for i in range(len(labels_only))) == 11364
    dst, result = converted_sweeps_only
    assert result.written == [LOG] and result.problems == []
    dataset = FrameDataset(dst, sensors=[LIDAR_FRAME], frame="ego")
    times = [dataset[i]["timestamp_ns"] for i in range(len(dataset))]
    assert times == list(SWEEPS)
    item = dataset[0]
    points = item["points"][LIDAR_FRAME]
    source = av2.read_sweep(REAL_LOG / "sensors" / "lidar" / f"{SWEEPS[0]}.feather")
    np.testing.assert_array_equal(points[:, 0].numpy(), source["x"].astype(np.float32))
    assert item["point_fields"][LIDAR_FRAME] == ("x", "y", "z", "intensity", "laser_number", "offset_ns")
    table = feather.read_table(REAL_LOG / "annotations.feather")
    at = np.asarray(table.column("timestamp_ns").to_numpy()) == SWEEPS[0]
    centres = np.stack([table.column(k).to_numpy()[at] for k in ("tx_m", "ty_m", "tz_m")], axis=1)
    boxes = item["boxes"].numpy().astype(np.float64)
    assert isinstance(item["boxes"], torch.Tensor)
    assert len(boxes) == int(at.sum())
    # ego-frame boxes back through world equal the source cuboid centres (float32 tensor precision)
    order = [list(table.column("track_uuid").to_numpy()[at]).index(i) for i in item["object_ids"]]
    np.testing.assert_allclose(boxes[:, :3], centres[order], atol=1e-4)


def test_export_kitti_object_round_trip(converted, tmp_path):
    """AV2 -> unified -> KITTI object files -> unified (kitti-object converter): boxes back in the lidar frame."""
    from avdata.converters.kitti import KittiObjectConverter

    dst, _ = converted
    parser = argparse.ArgumentParser(prog="avdata")
    add_export_subparser(parser.add_subparsers())
    kitti = tmp_path / "kitti"
    args = parser.parse_args(["export", "kitti-object", str(dst), str(kitti), "--camera", "ego/ring_front_center"])
    assert args.run(args) == 0
    samples = sorted(p.stem for p in (kitti / "training" / "label_2").glob("*.txt"))
    assert len(samples) == 2  # the two frames with a sweep and a front-centre image
    velodyne = np.fromfile(kitti / "training" / "velodyne" / f"{samples[0]}.bin", dtype=np.float32).reshape(-1, 4)
    source = av2.read_sweep(REAL_LOG / "sensors" / "lidar" / f"{SWEEPS[0]}.feather")
    np.testing.assert_array_equal(velodyne[:, 0], source["x"].astype(np.float32))
    back = tmp_path / "back"
    run_conversion(KittiObjectConverter(ConvertConfig(src=kitti, dst=back, quiet=True)))
    reader = DatasetReader(back)
    original = DatasetReader(dst).scene(LOG)
    frames = {info.timestamp_ns: info for info in original.frame_infos()}
    scene = reader.scene(reader.scenes[0])
    for k, sweep_ns in enumerate(SWEEPS):
        _, ours = original.labels(frames[sweep_ns].frame_index)
        ours_lidar = ours.boxes.to(LIDAR_FRAME, original.graph, sweep_ns)
        info, theirs = scene.labels(k)
        theirs_lidar = theirs.boxes.to("ego/velodyne", scene.graph, info.timestamp_ns)
        assert len(theirs_lidar) > 0
        # KITTI keeps the boxes in front of the camera that project into the image; each one re-read
        # lands on an original AV2 box (KITTI's text keeps 2 decimals).
        distance = np.linalg.norm(theirs_lidar.center[:, None, :] - ours_lidar.center[None, :, :], axis=2)
        nearest = distance.argmin(axis=1)
        assert distance.min(axis=1).max() < 0.01
        np.testing.assert_allclose(theirs_lidar.size_lwh, ours_lidar.size_lwh[nearest], atol=0.006)
        yaw_diff = np.angle(np.exp(1j * (theirs_lidar.yaw() - ours_lidar.yaw()[nearest])))
        assert np.abs(yaw_diff).max() < 0.006


def test_test_split_log_converts_unannotated(tmp_path):
    """The real test/<log> (no annotations.feather): frames are the sweeps, not annotated, no error."""
    root = tmp_path / "sensor"
    link_log(REAL / "test" / LOG, root / "test" / LOG)
    result = run_conversion(Argoverse2Converter(ConvertConfig(src=root, dst=tmp_path / "out", quiet=True)))
    assert result.written == [LOG] and result.problems == []
    frames = DatasetReader(tmp_path / "out").frames()
    assert frames.column("timestamp_ns").to_pylist() == list(SWEEPS)
    assert not any(frames.column("annotated").to_pylist())
    assert DatasetReader(tmp_path / "out").scene(LOG).metadata["split"] == "test"


def test_the_real_root_as_shipped(tmp_path):
    """../shared/realdata/argoverse2/sensor read in place: val/<log> converts; test/<log> has the same log id
    and is reported (one line) instead of overwriting it."""
    result = run_conversion(Argoverse2Converter(ConvertConfig(src=REAL, dst=tmp_path / "out", quiet=True)))
    assert result.written == [LOG]
    messages = [(p.file, p.message) for p in result.problems]
    assert (str(REAL / "test" / LOG), "log id also in val/; converted from there only") in messages
    assert len(messages) == 2  # and the 154 missing sweeps of val, in one line
    assert DatasetReader(tmp_path / "out").scene(LOG).metadata["split"] == "val"


def test_a_bad_pose_row_costs_its_time_and_a_bad_sensor_row_its_sensor(tmp_path):
    """NaN in one ego pose row: that sweep loses its cuboids (they need the exact pose), nothing else; NaN in
    one camera's calibration row: that camera only; a quaternion 1e-4 off unit norm: normalised, a warning."""
    log_dir = tmp_path / "sensor" / "val" / LOG
    link_log(REAL_LOG, log_dir)
    poses = feather.read_table(REAL_LOG / "city_SE3_egovehicle.feather")
    tx = poses.column("tx_m").to_numpy().copy()
    row = int(np.flatnonzero(poses.column("timestamp_ns").to_numpy() == SWEEPS[1])[0])
    tx[row] = np.nan
    (log_dir / "city_SE3_egovehicle.feather").unlink()
    feather.write_feather(poses.set_column(poses.column_names.index("tx_m"), "tx_m", pa.array(tx)),
                          log_dir / "city_SE3_egovehicle.feather")
    sensors = feather.read_table(REAL_LOG / "calibration" / "egovehicle_SE3_sensor.feather")
    names = sensors.column("sensor_name").to_pylist()
    ty, qw = sensors.column("ty_m").to_numpy().copy(), sensors.column("qw").to_numpy().copy()
    ty[names.index("ring_rear_left")] = np.inf
    qw[names.index("ring_front_center")] *= 1.0002
    sensors = sensors.set_column(sensors.column_names.index("ty_m"), "ty_m", pa.array(ty))
    sensors = sensors.set_column(sensors.column_names.index("qw"), "qw", pa.array(qw))
    (log_dir / "calibration" / "egovehicle_SE3_sensor.feather").unlink()
    feather.write_feather(sensors, log_dir / "calibration" / "egovehicle_SE3_sensor.feather")
    dst = tmp_path / "out"
    result = run_conversion(Argoverse2Converter(ConvertConfig(src=tmp_path / "sensor", dst=dst, quiet=True)))
    assert result.written == [LOG]
    messages = [(p.severity, Path(p.file).name, p.message) for p in result.problems]
    assert ("error", "city_SE3_egovehicle.feather",
            f"row {row}: column 'tx_m': expected a finite number within 1e+07, got nan; row dropped; frames at its "
            "time lose what needs the ego pose") in messages
    assert ("error", "egovehicle_SE3_sensor.feather",
            "row 3 (ring_rear_left): column 'ty_m': expected a finite number within 1e+07, got inf; that sensor is "
            "not converted") in messages
    assert any(severity == "warning" and "row 0 (ring_front_center): columns qw..qz: quaternion" in message
               and "off unit norm by" in message and message.endswith("normalised")
               for severity, _, message in messages)
    assert any(f"timestamp_ns {SWEEPS[1]}: no ego pose at this time" in message for _, _, message in messages)
    reader = DatasetReader(dst)
    scene = reader.scene(LOG)
    times = reader.objects().column("timestamp_ns").to_numpy()
    assert np.sum(times == SWEEPS[1]) == 0 and np.sum(times == SWEEPS[0]) > 0
    sweep = av2.read_sweep(REAL_LOG / "sensors" / "lidar" / f"{SWEEPS[1]}.feather")
    assert len(scene.points(LIDAR_FRAME, SWEEPS[1])) == len(sweep["x"])  # the sweep itself is kept
    assert "ego/ring_rear_left" not in scene.graph.frames and "ego/ring_rear_left" not in scene.sensors()
    assert "ego/ring_rear_right" in scene.graph.frames
    quat = np.asarray([sensors.column(k).to_numpy()[0] for k in ("qw", "qx", "qy", "qz")])
    translation = np.asarray([sensors.column(k).to_numpy()[0] for k in ("tx_m", "ty_m", "tz_m")])
    expected = Transform.from_quat_wxyz(quat / np.linalg.norm(quat), translation)
    assert scene.graph.lookup("ego", "ego/ring_front_center", SWEEPS[0]).allclose(expected, atol=1e-12)
