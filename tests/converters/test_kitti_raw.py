"""KITTI raw: the real 2011_09_26 calibration and timestamps, in a drive assembled from real files.

The sample has no raw velodyne or images, so the drive gets the tracking sample's real velodyne
sweeps and stereo images for frames 0-1 and the tracking sequence's real oxts packets; calib and
timestamps are the raw drive's own.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.kitti import KittiRawConverter
from avdata.schema import DatasetReader
from avdata.schema.validate import validate_dataset
from avdata.sources.kitti import read_oxts_lines, read_raw_calib, read_timestamps
from tests.realdata import REALDATA

REAL = REALDATA / "kitti"
RAW_DAY = REAL / "raw" / "2011_09_26"
RAW_DRIVE = RAW_DAY / "2011_09_26_drive_0001_sync"
TRACKING = REAL / "tracking" / "training"
DRIVE = "2011_09_26_drive_0001_sync"

TRACKLETS = """<?xml version="1.0" encoding="UTF-8" standalone="yes" ?>
<!DOCTYPE boost_serialization>
<boost_serialization signature="serialization::archive" version="9">
<tracklets class_id="0" tracking_level="0" version="0">
  <count>2</count>
  <item_version>1</item_version>
  <item class_id="1" tracking_level="0" version="1">
    <objectType>Car</objectType><h>1.5</h><w>1.6</w><l>4.0</l>
    <first_frame>0</first_frame>
    <poses class_id="2" tracking_level="0" version="0">
      <count>2</count><item_version>2</item_version>
      <item class_id="3" tracking_level="0" version="2">
        <tx>10.0</tx><ty>2.0</ty><tz>-1.7</tz><rx>0</rx><ry>0</ry><rz>0.3</rz>
        <state>1</state><occlusion>1</occlusion><occlusion_kf>0</occlusion_kf>
        <truncation>0</truncation><amt_occlusion>-1</amt_occlusion><amt_occlusion_kf>-1</amt_occlusion_kf>
        <amt_border_l>-1</amt_border_l><amt_border_r>-1</amt_border_r><amt_border_kf>-1</amt_border_kf>
      </item>
      <item>
        <tx>11.0</tx><ty>2.0</ty><tz>-1.7</tz><rx>0</rx><ry>0</ry><rz>0.3</rz>
        <state>1</state><occlusion>2</occlusion><occlusion_kf>0</occlusion_kf>
        <truncation>1</truncation><amt_occlusion>-1</amt_occlusion><amt_occlusion_kf>-1</amt_occlusion_kf>
        <amt_border_l>-1</amt_border_l><amt_border_r>-1</amt_border_r><amt_border_kf>-1</amt_border_kf>
      </item>
    </poses>
    <finished>1</finished>
  </item>
  <item>
    <objectType>Pedestrian</objectType><h>1.8</h><w>0.6</w><l>0.8</l>
    <first_frame>1</first_frame>
    <poses><count>1</count><item_version>2</item_version>
      <item>
        <tx>6.0</tx><ty>-3.0</ty><tz>-1.6</tz><rx>0</rx><ry>0</ry><rz>-1.2</rz>
        <state>1</state><occlusion>0</occlusion><occlusion_kf>0</occlusion_kf>
        <truncation>99</truncation><amt_occlusion>-1</amt_occlusion><amt_occlusion_kf>-1</amt_occlusion_kf>
        <amt_border_l>-1</amt_border_l><amt_border_r>-1</amt_border_r><amt_border_kf>-1</amt_border_kf>
      </item>
    </poses>
    <finished>1</finished>
  </item>
</tracklets>
</boost_serialization>
"""


def assemble_drive(root: Path, n_frames: int = 108) -> Path:
    """A raw-layout drive from real files (symlinks; nothing is copied)."""
    day = root / "2011_09_26"
    drive = day / DRIVE
    for name in ("calib_cam_to_cam.txt", "calib_imu_to_velo.txt", "calib_velo_to_cam.txt"):
        day.mkdir(parents=True, exist_ok=True)
        (day / name).symlink_to(RAW_DAY / name)
    for folder in ("oxts", "velodyne_points", "image_00", "image_01", "image_02", "image_03"):
        (drive / folder / "data").mkdir(parents=True)
        (drive / folder / "timestamps.txt").symlink_to(RAW_DRIVE / folder / "timestamps.txt")
    oxts_lines = (TRACKING / "oxts" / "0001.txt").read_text().splitlines()
    for frame in range(n_frames):
        (drive / "oxts" / "data" / f"{frame:010d}.txt").write_text(oxts_lines[frame] + "\n")
    for frame in (0, 1):
        (drive / "velodyne_points" / "data" / f"{frame:010d}.bin").symlink_to(
            TRACKING / "velodyne" / "0001" / f"{frame:06d}.bin")
        for cam in (2, 3):
            (drive / f"image_0{cam}" / "data" / f"{frame:010d}.png").symlink_to(
                TRACKING / f"image_0{cam}" / "0001" / f"{frame:06d}.png")
    return drive


def test_real_raw_calibration_timestamps_and_oxts_packet_are_read():
    calib = read_raw_calib(RAW_DAY)
    np.testing.assert_allclose(calib.P[2][0], [721.5377, 0.0, 609.5593, 44.85728])
    np.testing.assert_allclose(calib.velo_to_cam[:, 3], [-4.069766e-03, -7.631618e-02, -2.717806e-01])
    np.testing.assert_allclose(calib.imu_to_velo[:, 3], [-8.086759e-01, 3.195559e-01, -7.997231e-01])
    assert calib.image_size.tolist() == [[1242, 375]] * 4
    times, _ = read_timestamps(RAW_DRIVE / "image_00" / "timestamps.txt")
    epoch = int(dt.datetime(2011, 9, 26, 13, 2, 25, tzinfo=dt.timezone.utc).timestamp())
    assert times[0] == epoch * 1_000_000_000 + 967_790_592
    assert len(times) == 108 and np.all(np.diff(times) > 0)
    packet = read_oxts_lines(RAW_DRIVE / "oxts" / "data" / "0000000000.txt",
                             (RAW_DRIVE / "oxts" / "data" / "0000000000.txt").read_text().splitlines())
    np.testing.assert_allclose(packet[0, :3], [49.015003823272, 8.4342971002335, 116.43032836914])


def test_assembled_raw_drive_converts(tmp_path):
    drive = assemble_drive(tmp_path / "src")
    (drive / "tracklet_labels.xml").write_text(TRACKLETS)
    result = run_conversion(KittiRawConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "out", quiet=True)))
    assert result.written == [DRIVE] and result.n_errors == 0
    assert sorted(Path(p.file).name for p in result.problems) == ["image_00", "image_01", "image_02", "image_03",
                                                                  "velodyne_points"]
    dataset = DatasetReader(tmp_path / "out")
    frames = dataset.frames()
    assert frames.num_rows == 108
    oxts_ns, _ = read_timestamps(RAW_DRIVE / "oxts" / "timestamps.txt")
    np.testing.assert_array_equal(frames.column("timestamp_ns").to_numpy(), oxts_ns)
    velo_ns, _ = read_timestamps(RAW_DRIVE / "velodyne_points" / "timestamps.txt")
    assert dataset.sensor_time(DRIVE, 1, "ego/velodyne") == velo_ns[1]
    reader = dataset.scene(DRIVE)
    assert reader.metadata["time_nominal"] is False
    # The first sweep is 13.19 ms before the first oxts packet: one pose extrapolated back to it.
    assert reader.metadata["pose_extrapolated_ns"] == [int(oxts_ns[0] - velo_ns[0]), 0] == [13_190_108, 0]
    oxts = np.loadtxt(TRACKING / "oxts" / "0001.txt")
    np.testing.assert_allclose(reader.graph.lookup("world", "ego", int(velo_ns[0])).translation[0],
                               -oxts[0, 8] * 0.013190108, atol=1e-6)
    assert validate_dataset(tmp_path / "out") == []

    # Projection through the graph (velodyne -> cam2, K) equals P_rect_02 · R_rect_00 · Tr_velo_to_cam · x.
    calib = read_raw_calib(RAW_DAY)
    rect = np.eye(4)
    rect[:3, :3] = calib.R0_rect
    velo_to_cam = np.eye(4)
    velo_to_cam[:3, :] = calib.velo_to_cam
    points = dataset.points(DRIVE, 1, "ego/velodyne")
    xyz = np.stack([points["x"], points["y"], points["z"]], axis=1).astype(np.float64)
    reference = (calib.P[2] @ rect @ velo_to_cam @ np.c_[xyz, np.ones(len(xyz))].T).T
    front = reference[:, 2] > 1.0
    reference = reference[front, :2] / reference[front, 2:]
    calibration = reader.camera_calibration("ego/cam2")
    assert (calibration.width, calibration.height) == (1242, 375)
    in_cam = reader.graph.lookup("ego/cam2", "ego/velodyne", int(velo_ns[1])).apply(xyz[front])
    in_cam = in_cam @ np.array(calibration.K).reshape(3, 3).T
    error = np.abs(in_cam[:, :2] / in_cam[:, 2:] - reference).max()
    print(f"raw max projection error: {error:.6f} px")
    assert error < 0.01

    # Tracklets: bottom centre in velodyne + h/2 up = the box centre, back through the graph.
    info, labels = reader.labels(1)
    assert labels.boxes.ids.tolist() == ["0", "1"]
    assert labels.boxes.classes.tolist() == ["car", "pedestrian"]
    in_velo = labels.boxes.to("ego/velodyne", reader.graph, info.timestamp_ns)
    np.testing.assert_allclose(in_velo.center, [[11.0, 2.0, -0.95], [6.0, -3.0, -0.7]], atol=1e-9)
    np.testing.assert_allclose(in_velo.size_lwh, [[4.0, 1.6, 1.5], [0.8, 0.6, 1.8]])
    np.testing.assert_allclose(in_velo.yaw(), [0.3, -1.2], atol=1e-9)
    vis = reader.visibility("ego/cam2", 1)
    assert vis.occlusion.tolist() == [3, 0] and vis.in_fov.tolist() == [True, False]
    assert [e["kitti_truncation_level"] for e in labels.extras] == [1.0, 99.0]
    assert reader.labels(2)[1].boxes.ids.tolist() == []


def test_a_timestamps_file_that_is_a_folder_is_an_error(tmp_path):
    # It was reported as absent (a warning, "partial download?") and the sensor left out, exit 0.
    drive = assemble_drive(tmp_path / "src")
    stamps = drive / "image_02" / "timestamps.txt"
    stamps.unlink()
    stamps.mkdir()
    result = run_conversion(KittiRawConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "out", quiet=True)))
    errors = [p for p in result.problems if p.severity == "error"]
    assert result.written == [DRIVE] and len(errors) == 1 and errors[0].file.endswith("image_02/timestamps.txt")
    assert errors[0].message == "expected a file, got a folder, a broken link or a special file; this sensor is not written"


def test_empty_velodyne_file_costs_that_scan(tmp_path):
    # A 0-byte sweep (an interrupted copy) was written as an empty cloud without a word (issue 34, S24); in a raw
    # drive it costs that frame's scan with one error line, as in KITTI object and tracking.
    drive = assemble_drive(tmp_path / "src")
    scan = drive / "velodyne_points" / "data" / "0000000001.bin"
    scan.unlink()
    scan.write_bytes(b"")
    result = run_conversion(KittiRawConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "out", quiet=True)))
    (error,) = [p for p in result.problems if p.severity == "error"]
    assert error.file == str(scan) and "got an empty file (0 bytes)" in error.message and "\n" not in error.message
    assert result.written == [DRIVE]
    dataset = DatasetReader(tmp_path / "out")
    frames = dataset.scene(DRIVE).frame_infos()
    assert "ego/velodyne" in frames[0].sensor_timestamps_ns and "ego/velodyne" not in frames[1].sensor_timestamps_ns
    assert dataset.frames().num_rows == 108 and validate_dataset(tmp_path / "out") == []
