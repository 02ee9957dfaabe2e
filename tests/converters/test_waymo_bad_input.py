"""Bad Waymo v2 input costs exactly the component it is in: one error line naming the file, the rest converted.

Inputs are copies of the real-data fixture (tests/oracles/waymo_fixture.py) with one thing broken.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from avdata.cli import main
from avdata.schema import DatasetReader

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "oracles"))
from waymo_fixture import waymo_v2_fixture  # noqa: E402

pytestmark = pytest.mark.oracle


@pytest.fixture()
def source(tmp_path: Path) -> tuple[Path, str]:
    fixture, info = waymo_v2_fixture()
    src = tmp_path / "src"
    shutil.copytree(fixture, src, ignore=shutil.ignore_patterns("*.npz", "*.json"))
    return src, info["context"]


def convert(src: Path, dst: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str]]:
    status = main(["convert", "waymo", str(src), str(dst), "--quiet"])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return status, [line for line in err.splitlines() if "error" in line]


def replace_column(path: Path, name: str, values: list) -> None:
    """Rewrites the Parquet file ``path`` with column ``name`` replaced by ``values`` (same type)."""
    table = pq.read_table(path)
    field = table.schema.field(name)
    pq.write_table(table.set_column(table.schema.get_field_index(name), name, pa.array(values, field.type)), path)


def set_value(path: Path, name: str, row: int, value: object) -> int:
    """Rewrites ``path`` with row ``row`` of column ``name`` set to ``value``; returns the number of rows."""
    values = pq.read_table(path, columns=[name]).column(name).to_pylist()
    values[row] = value
    replace_column(path, name, values)
    return len(values)


def test_missing_component(source, tmp_path: Path, capsys) -> None:
    src, context = source
    shutil.rmtree(src / "lidar_box")
    status, errors = convert(src, tmp_path / "out", capsys)
    assert status == 1
    assert len(errors) == 1 and f"lidar_box/{context}.parquet" in errors[0] and "missing component" in errors[0]
    reader = DatasetReader(tmp_path / "out")
    assert reader.objects().num_rows == 0
    assert len(reader.points(context, 0, "ego/lidar_top")) > 100_000


def test_component_of_another_context(source, tmp_path: Path, capsys) -> None:
    src, context = source
    path = src / "lidar_calibration" / f"{context}.parquet"
    table = pq.read_table(path)
    other = pa.array(["9999_other_context"] * table.num_rows)
    pq.write_table(table.set_column(0, "key.segment_context_name", other), path)
    status, errors = convert(src, tmp_path / "out", capsys)
    assert status == 1
    assert len(errors) == 1 and str(path) in errors[0] and "9999_other_context" in errors[0]
    reader = DatasetReader(tmp_path / "out")
    assert reader.objects().num_rows == 75
    assert "ego/lidar_top" not in reader.scene(context).sensors()


def test_truncated_parquet(source, tmp_path: Path, capsys) -> None:
    src, context = source
    path = src / "lidar" / f"{context}.parquet"
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    status, errors = convert(src, tmp_path / "out", capsys)
    assert status == 1
    assert len(errors) == 1 and str(path) in errors[0] and "Parquet" in errors[0]
    reader = DatasetReader(tmp_path / "out")
    assert reader.objects().num_rows == 75
    assert reader.scene(context).camera_calibration("ego/cam_front").width == 1920


def test_missing_vehicle_pose_fails_the_scene(source, tmp_path: Path, capsys) -> None:
    src, context = source
    shutil.rmtree(src / "vehicle_pose")
    status, errors = convert(src, tmp_path / "out", capsys)
    assert status == 1
    assert len(errors) == 1 and f"vehicle_pose/{context}.parquet" in errors[0]
    assert not list((tmp_path / "out" / "scenes").glob("*.mcap"))


def test_rerun_skips_the_complete_scene(source, tmp_path: Path, capsys) -> None:
    src, _ = source
    assert convert(src, tmp_path / "out", capsys) == (0, [])
    assert main(["convert", "waymo", str(src), str(tmp_path / "out"), "--quiet"]) == 0
    assert "0 scenes written, 1 already complete" in capsys.readouterr().out


def test_missing_pixel_poses_cost_the_top_lidar_only(source, tmp_path: Path, capsys) -> None:
    src, context = source
    shutil.rmtree(src / "lidar_pose")
    status, errors = convert(src, tmp_path / "out", capsys)
    assert status == 1
    assert len(errors) == 1 and f"lidar_pose/{context}.parquet" in errors[0]
    scene = DatasetReader(tmp_path / "out").scene(context)
    assert "/ego/lidar_top/points" not in scene.topics and "/ego/lidar_front/points" in scene.topics


def test_null_camera_extrinsic_costs_that_camera(source, tmp_path: Path, capsys) -> None:
    src, context = source
    path = src / "camera_calibration" / f"{context}.parquet"
    front = pq.read_table(path).column("key.camera_name").to_pylist().index(1)
    set_value(path, "[CameraCalibrationComponent].extrinsic.transform", front, None)
    status, errors = convert(src, tmp_path / "out", capsys)
    assert status == 1
    assert len(errors) == 1 and str(path) in errors[0] and "camera 1" in errors[0] and "extrinsic.transform" in errors[0]
    scene = DatasetReader(tmp_path / "out").scene(context)
    assert "/ego/cam_front/image" not in scene.topics and "/ego/cam_side_left/image" in scene.topics


def test_empty_vehicle_pose_fails_the_scene_in_one_line(source, tmp_path: Path, capsys) -> None:
    src, context = source
    path = src / "vehicle_pose" / f"{context}.parquet"
    pq.write_table(pq.read_table(path).slice(0, 0), path)
    status, errors = convert(src, tmp_path / "out", capsys)
    assert status == 1 and len(errors) == 1 and "no rows" in errors[0] and str(path) in errors[0]


def test_camera_pose_time_beyond_int64_nanoseconds_costs_that_image(source, tmp_path: Path, capsys) -> None:
    # A pose_timestamp of 1e20 s used to be a 'Value out of range' traceback that lost the segment.
    src, context = source
    path = src / "camera_image" / f"{context}.parquet"
    set_value(path, "[CameraImageComponent].pose_timestamp", 0, 1e20)
    status, errors = convert(src, tmp_path / "out", capsys)
    assert status == 1
    assert len(errors) == 1 and str(path) in errors[0] and "pose_timestamp: expected seconds in 0 .. 9.2e9" in errors[0]
    assert "1e+20" in errors[0]
    scene = DatasetReader(tmp_path / "out").scene(context)
    assert scene.topics  # the rest of the segment is written


def test_a_torn_camera_image_costs_that_image(source, tmp_path: Path, capsys) -> None:
    # The real frame's JPEG cut short (Parquet page CRCs are optional): it was stored as is.
    src, context = source
    path = src / "camera_image" / f"{context}.parquet"
    name = "[CameraImageComponent].image"
    images = pq.read_table(path, columns=[name]).column(name).to_pylist()
    set_value(path, name, 0, images[0][: len(images[0]) // 2])
    status, errors = convert(src, tmp_path / "out", capsys)
    assert status == 1 and len(errors) == 1 and str(path) in errors[0]
    assert "image: expected the file to end with the EOI marker ff d9" in errors[0]
    scene = DatasetReader(tmp_path / "out").scene(context)
    assert sum(topic.endswith("/image") for topic in scene.topics) == len(images) - 1


def test_a_bad_vehicle_pose_row_costs_its_frame_only(source, tmp_path: Path, capsys) -> None:
    # A second frame's pose row, NaN: that frame (its pose and every row at its time) is lost, in one line;
    # a scaled rotation (not within 1e-2 of one) is refused the same way. Both used to lose the segment.
    src, context = source
    path = src / "vehicle_pose" / f"{context}.parquet"
    table = pq.read_table(path)
    name = "[VehiclePoseComponent].world_from_vehicle.transform"
    time_us = table.column("key.frame_timestamp_micros").to_pylist()[0]
    good = table.column(name).to_pylist()[0]
    scaled = [2.0 * v if i % 4 < 3 and i < 12 else v for i, v in enumerate(good)]
    rows = [table, table, table]
    for k, (offset, matrix) in enumerate(((100_000, [float("nan")] * 16), (200_000, scaled)), start=1):
        rows[k] = table.set_column(table.schema.get_field_index("key.frame_timestamp_micros"), "key.frame_timestamp_micros",
                                   pa.array([time_us + offset], table.schema.field("key.frame_timestamp_micros").type))
        rows[k] = rows[k].set_column(rows[k].schema.get_field_index(name), name,
                                     pa.array([matrix], table.schema.field(name).type))
    pq.write_table(pa.concat_tables(rows), path)
    status, errors = convert(src, tmp_path / "out", capsys)
    assert status == 1 and len(errors) == 2
    assert f"frame at {time_us + 100_000} us" in errors[0] and "(finite values with det > 0)" in errors[0]
    assert f"frame at {time_us + 200_000} us" in errors[1] and "max |R^T R - I| <= 0.01" in errors[1]
    assert all(str(path) in e and e.endswith("the frame is skipped") for e in errors)
    reader = DatasetReader(tmp_path / "out")
    assert reader.frames().num_rows == 1 and reader.objects().num_rows == 75


def test_projected_box_beyond_pixel_range_costs_that_box(source, tmp_path: Path, capsys) -> None:
    # A centre of 1e300 px used to be cast to float32 infinity and written without a word.
    src, context = source
    path = src / "projected_lidar_box" / f"{context}.parquet"
    n_boxes = set_value(path, "[ProjectedLiDARBoxComponent].box.center.x", 0, 1e300)
    status, errors = convert(src, tmp_path / "out", capsys)
    assert status == 1
    assert len(errors) == 1 and str(path) in errors[0] and "expected corners within 1e+06 px" in errors[0]
    assert "1 row(s), first row 0" in errors[0]
    scene = DatasetReader(tmp_path / "out").scene(context)
    boxes = [vis.box2d_xyxy for _, _, _, vis in scene.iter_visibility()]
    assert sum(len(b) for b in boxes) == n_boxes - 1
    assert all(np.isfinite(b).all() for b in boxes)


@pytest.mark.parametrize("value", [1e30, float("inf")])
def test_a_range_value_no_lidar_measures_costs_that_lidar_in_that_frame(source, tmp_path: Path, capsys, value) -> None:
    # Range images have no checksum: a damaged range put a point at 1e30 m (or infinity) into the cloud.
    src, context = source
    path = src / "lidar" / f"{context}.parquet"
    table = pq.read_table(path)
    name = "[LiDARComponent].range_image_return1.values"
    rows = table.column(name).to_pylist()
    first = next(k for k in range(0, len(rows[0]), 4) if rows[0][k] > 0)  # a pixel with a return (channel 0: range)
    rows[0][first] = value
    laser = table.column("key.laser_name").to_pylist()[0]
    replace_column(path, name, rows)
    status, errors = convert(src, tmp_path / "out", capsys)
    assert status == 1 and len(errors) == 1 and str(path) in errors[0]
    assert f"laser {laser}" in errors[0] and "expected a finite value within +-1e+07" in errors[0]
    assert errors[0].endswith("; the frame is written without this lidar")
    scene = DatasetReader(tmp_path / "out").scene(context)
    lidars = {sensor for sensor in scene.frame_infos()[0].sensor_timestamps_ns if "lidar" in sensor}
    assert len(lidars) == 4  # the other four lidars of the frame are written
