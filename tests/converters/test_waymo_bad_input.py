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
from avdata.schema.validate import validate_dataset

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
    if (dst / "avdata.json").is_file():  # what was written passes validate (issue 34)
        assert validate_dataset(dst) == []
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


# --- one bad value costs its box, laser, camera or scan (issue 34), and the output passes validate ---------------

def convert_all(src: Path, dst: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str], list[str]]:
    """(exit status, error lines, warning lines); the written dataset must pass ``avdata validate``."""
    status = main(["convert", "waymo", str(src), str(dst), "--quiet"])
    lines = capsys.readouterr().err.splitlines()
    assert not any("Traceback" in line for line in lines)
    assert validate_dataset(dst) == []
    return status, [line for line in lines if "error:" in line], [line for line in lines if "warning:" in line]


def component(src: Path, context: str, name: str) -> Path:
    return src / name / f"{context}.parquet"


def duplicate_row(path: Path, row: int) -> None:
    table = pq.read_table(path)
    pq.write_table(pa.concat_tables([table, table.slice(row, 1)]), path)


def set_row_value(path: Path, name: str, row: int, value: object) -> None:
    """Like :func:`set_value`, for list columns whose element type the new value must keep."""
    table = pq.read_table(path)
    values = table.column(name).to_pylist()
    values[row] = value
    pq.write_table(table.set_column(table.schema.get_field_index(name), name,
                                    pa.array(values, table.schema.field(name).type)), path)


def test_a_box_centre_of_1e30_costs_that_box(source, tmp_path: Path, capsys) -> None:
    # The scene writer refused it, and the segment was lost.
    src, context = source
    path = component(src, context, "lidar_box")
    set_value(path, "[LiDARBoxComponent].box.center.x", 3, 1e30)
    status, errors, _ = convert_all(src, tmp_path / "out", capsys)
    assert status == 1 and len(errors) == 1 and str(path) in errors[0]
    assert "expected a box within 1e+07 m" in errors[0] and "1e+30" in errors[0]
    assert errors[0].endswith("that box is skipped")
    assert DatasetReader(tmp_path / "out").objects().num_rows == 74


def test_a_box_row_given_twice_is_an_error_and_costs_that_object(source, tmp_path: Path, capsys) -> None:
    # It was written twice, as two boxes of one id in one frame.
    src, context = source
    path = component(src, context, "lidar_box")
    duplicate_row(path, 5)
    object_id = pq.read_table(path).column("key.laser_object_id").to_pylist()[5]
    status, errors, _ = convert_all(src, tmp_path / "out", capsys)
    assert status == 1 and len(errors) == 1 and str(path) in errors[0]
    assert f"object {object_id} at" in errors[0] and "expected one box per frame, got 2; those boxes are skipped" in errors[0]
    objects = DatasetReader(tmp_path / "out").objects()
    assert objects.num_rows == 74 and object_id not in objects.column("object_id").to_pylist()


def test_a_null_object_id_costs_that_box(source, tmp_path: Path, capsys) -> None:
    # It became an object named "None".
    src, context = source
    path = component(src, context, "lidar_box")
    set_value(path, "key.laser_object_id", 2, None)
    status, errors, _ = convert_all(src, tmp_path / "out", capsys)
    assert status == 1 and len(errors) == 1 and str(path) in errors[0]
    assert "row 2 at" in errors[0] and "key.laser_object_id: expected an object id, got null; that box is skipped" in errors[0]
    objects = DatasetReader(tmp_path / "out").objects()
    assert objects.num_rows == 74 and "None" not in objects.column("object_id").to_pylist()


def test_a_nan_beam_inclination_costs_that_laser(source, tmp_path: Path, capsys) -> None:
    # "Out of range float values are not JSON compliant": the segment was lost.
    src, context = source
    path = component(src, context, "lidar_calibration")
    lasers = pq.read_table(path).column("key.laser_name").to_pylist()
    set_value(path, "[LiDARCalibrationComponent].beam_inclination.min", lasers.index(2), float("nan"))
    status, errors, _ = convert_all(src, tmp_path / "out", capsys)
    assert status == 1 and len(errors) == 2 and str(path) in errors[0]
    assert errors[0].endswith("laser 2: beam_inclination: expected angles within +-pi/2 rad, got nan; that laser is not "
                              "converted")
    assert "expected a calibrated laser" in errors[1]  # its scan, named once
    topics = DatasetReader(tmp_path / "out").scene(context).topics
    assert "/ego/lidar_front/points" not in topics and "/ego/lidar_top/points" in topics


@pytest.mark.parametrize(("name", "message"), [
    ("camera_image", "expected one image per frame and camera, got another; the later row is skipped"),
    ("lidar", "expected one row per frame and laser, got another; the later row is skipped"),
    ("camera_calibration", "key.camera_name: 1 given 2 times; that camera is not converted"),
    ("lidar_calibration", "key.laser_name: 2 given 2 times; that laser is not converted"),
])
def test_a_row_given_twice_is_an_error(source, tmp_path: Path, capsys, name, message) -> None:
    # Each was written twice without a word.
    src, context = source
    path = component(src, context, name)
    key = "key.camera_name" if "camera" in name else "key.laser_name"
    duplicate_row(path, pq.read_table(path).column(key).to_pylist().index(1 if "camera" in name else 2))
    status, errors, _ = convert_all(src, tmp_path / "out", capsys)
    assert status == 1 and str(path) in errors[0] and errors[0].endswith(message)
    scene = DatasetReader(tmp_path / "out").scene(context)
    images = [t for t in scene.topics if t.endswith("/image")]
    clouds = [t for t in scene.topics if t.endswith("/points")]
    assert (len(images), len(clouds)) == {"camera_image": (5, 5), "lidar": (5, 5), "camera_calibration": (4, 5),
                                          "lidar_calibration": (5, 4)}[name]
    if name in ("camera_image", "lidar"):
        assert len(errors) == 1 and len(scene.times(images[0] if name == "camera_image" else clouds[0])) == 1


@pytest.mark.parametrize(("shape", "values", "got"), [
    ([200, 800, 3], None, "expected (H, W, 4) holding the 480000 values given, got [200, 800, 3]"),
    ([-200, -600, 4], None, "expected (H, W, 4) holding the 480000 values given, got [-200, -600, 4]"),
    (None, [], "expected (H, W, 4) holding the 0 values given, got [200, 600, 4]"),
])
def test_a_range_image_that_does_not_fit_its_shape_costs_that_scan(source, tmp_path: Path, capsys, shape, values,
                                                                   got) -> None:
    # [200, 800, 3] from [200, 600, 4] gave garbage points; a negative shape was a ValueError traceback; empty
    # values lost 108,000 points without a word.
    src, context = source
    path = component(src, context, "lidar")
    table = pq.read_table(path)
    row = table.column("key.laser_name").to_pylist().index(2)
    if shape is not None:
        set_row_value(path, "[LiDARComponent].range_image_return1.shape", row, shape)
    if values is not None:
        set_row_value(path, "[LiDARComponent].range_image_return1.values", row, values)
    status, errors, _ = convert_all(src, tmp_path / "out", capsys)
    assert status == 1 and len(errors) == 1 and str(path) in errors[0]
    assert f"laser 2: [LiDARComponent].range_image_return1.shape: {got}; the frame is written without this lidar" in errors[0]
    topics = DatasetReader(tmp_path / "out").scene(context).topics
    assert "/ego/lidar_front/points" not in topics and "/ego/lidar_top/points" in topics


def test_a_nan_range_is_named(source, tmp_path: Path, capsys) -> None:
    # range > 0 dropped the pixel without a word.
    src, context = source
    path = component(src, context, "lidar")
    name = "[LiDARComponent].range_image_return1.values"
    table = pq.read_table(path)
    row = table.column("key.laser_name").to_pylist().index(3)
    values = table.column(name).to_pylist()[row]
    first = next(k for k in range(0, len(values), 4) if values[k] > 0)
    values[first] = float("nan")
    set_row_value(path, name, row, values)
    status, errors, _ = convert_all(src, tmp_path / "out", capsys)
    assert status == 1 and len(errors) == 1 and str(path) in errors[0]
    pixel = divmod(first // 4, 600)
    assert f"laser 3: {name}: expected a range, got nan at pixel (row, column) {pixel}" in errors[0]
    assert "/ego/lidar_side_left/points" not in DatasetReader(tmp_path / "out").scene(context).topics


def test_a_2d_box_of_no_3d_box_is_left_out_with_a_warning(source, tmp_path: Path, capsys) -> None:
    # It still got a visibility row.
    src, context = source
    path = component(src, context, "projected_lidar_box")
    n_boxes = set_value(path, "key.laser_object_id", 0, "no-such-object")
    status, errors, warnings = convert_all(src, tmp_path / "out", capsys)
    assert status == 0 and errors == [] and len(warnings) == 1 and str(path) in warnings[0]
    assert "expected objects with a 3D box, got ['no-such-object'] (1 2D boxes); those 2D boxes are left out" in warnings[0]
    scene = DatasetReader(tmp_path / "out").scene(context)
    ids = [i for _, _, _, vis in scene.iter_visibility() for i in vis.object_ids.tolist()]
    assert len(ids) == n_boxes - 1 and "no-such-object" not in ids


@pytest.mark.parametrize("field", ["intrinsic.f_u", "extrinsic.transform"])
def test_a_refused_camera_takes_its_visibility_labels_with_it(source, tmp_path: Path, capsys, field) -> None:
    # The camera was dropped but its 2D boxes kept, and validate refused the written dataset (4 of 4 cases).
    src, context = source
    path = component(src, context, "camera_calibration")
    front = pq.read_table(path).column("key.camera_name").to_pylist().index(1)
    set_value(path, f"[CameraCalibrationComponent].{field}", front, None)
    status, errors, _ = convert_all(src, tmp_path / "out", capsys)
    assert status == 1 and len(errors) == 1 and "camera 1" in errors[0]
    scene = DatasetReader(tmp_path / "out").scene(context)
    assert scene.iter_visibility() and all(frame != "ego/cam_front" for frame, _, _, _ in scene.iter_visibility())


# --- null keys and null values (found by a bad-input sweep: each was a TypeError / ValueError traceback) ---------


def test_rows_after_a_dropped_null_key_row_are_named_by_their_file_row(source, tmp_path: Path, capsys) -> None:
    # Once a row with a null key was dropped, later messages counted the rows kept: row 2 was called row 1.
    src, context = source
    path = component(src, context, "lidar_box")
    set_value(path, "key.frame_timestamp_micros", 0, None)
    set_value(path, "key.laser_object_id", 2, None)
    status, errors, _ = convert_all(src, tmp_path / "out", capsys)
    assert status == 1 and len(errors) == 2 and all(str(path) in e for e in errors)
    assert errors[0].endswith("row 0: key.frame_timestamp_micros: expected an integer, got null; that row is skipped")
    assert "row 2 at" in errors[1] and "expected an object id, got null; that box is skipped" in errors[1]
    assert DatasetReader(tmp_path / "out").objects().num_rows == 73


def _left(reader: DatasetReader, context: str) -> tuple[int, int, int, int]:
    """(images, point clouds, 3D boxes, 2D boxes) written."""
    scene = reader.scene(context)
    return (sum(t.endswith("/image") for t in scene.topics), sum(t.endswith("/points") for t in scene.topics),
            reader.objects().num_rows, sum(len(vis.object_ids) for *_, vis in scene.iter_visibility()))


@pytest.mark.parametrize(("name", "key", "left"), [
    ("camera_calibration", "key.camera_name", (4, 5, 75, 62 - 12)),  # camera 1 and its 12 2D boxes
    ("camera_image", "key.frame_timestamp_micros", (4, 5, 75, 62)),
    ("lidar", "key.laser_name", (5, 4, 75, 62)),
    ("lidar_box", "key.frame_timestamp_micros", (5, 5, 74, None)),
    ("projected_lidar_box", "key.camera_name", (5, 5, 75, 61)),
])
def test_a_null_key_costs_that_row(source, tmp_path: Path, capsys, name, key, left) -> None:
    src, context = source
    path = component(src, context, name)
    set_value(path, key, 0, None)
    status, errors, _ = convert_all(src, tmp_path / "out", capsys)
    assert status == 1 and str(path) in errors[0]
    assert errors[0].endswith(f"row 0: {key}: expected an integer, got null; that row is skipped")
    written = _left(DatasetReader(tmp_path / "out"), context)
    assert written[:3] == left[:3] and left[3] in (None, written[3])


def test_a_null_image_and_a_null_shape_element_cost_that_image_and_that_scan(source, tmp_path: Path, capsys) -> None:
    src, context = source
    images, lidar = component(src, context, "camera_image"), component(src, context, "lidar")
    set_value(images, "[CameraImageComponent].image", 0, None)
    row = pq.read_table(lidar).column("key.laser_name").to_pylist().index(2)
    set_row_value(lidar, "[LiDARComponent].range_image_return1.shape", row, [200, None, 4])
    status, errors, _ = convert_all(src, tmp_path / "out", capsys)
    assert status == 1 and len(errors) == 2
    assert str(lidar) in errors[0] and "laser 2: [LiDARComponent].range_image_return1.shape: expected (H, W, 4) holding " \
        "the 480000 values given, got [200, None, 4]; the frame is written without this lidar" in errors[0]
    assert str(images) in errors[1] and errors[1].endswith("image: expected JPEG bytes, got null")
    topics = DatasetReader(tmp_path / "out").scene(context).topics
    assert sum(t.endswith("/image") for t in topics) == 4 and "/ego/lidar_front/points" not in topics


def test_a_null_box_type_costs_that_box(source, tmp_path: Path, capsys) -> None:
    src, context = source
    path = component(src, context, "lidar_box")
    set_value(path, "[LiDARBoxComponent].type", 4, None)
    status, errors, _ = convert_all(src, tmp_path / "out", capsys)
    assert status == 1 and len(errors) == 1 and str(path) in errors[0] and "type nan; that box is skipped" in errors[0]
    assert DatasetReader(tmp_path / "out").objects().num_rows == 74


def test_an_object_id_column_of_integers_costs_that_component(source, tmp_path: Path, capsys) -> None:
    # It was an ArrowInvalid traceback.
    src, context = source
    path = component(src, context, "lidar_box")
    table = pq.read_table(path)
    index = table.schema.get_field_index("key.laser_object_id")
    pq.write_table(table.set_column(index, "key.laser_object_id", pa.array(range(table.num_rows), pa.int64())), path)
    status, errors, _ = convert_all(src, tmp_path / "out", capsys)
    assert status == 1 and len(errors) == 1
    assert errors[0].endswith(f"{path}: column key.laser_object_id: expected text, got type int64")
    assert DatasetReader(tmp_path / "out").objects().num_rows == 0


def test_an_image_whose_pose_is_refused_is_skipped(source, tmp_path: Path, capsys) -> None:
    # The images were written at times no pose reached, and validate refused the dataset.
    src, context = source
    path = component(src, context, "camera_image")
    name = "[CameraImageComponent].pose.transform"
    replace_column(path, name, [None] * pq.read_table(path).num_rows)
    status, errors, _ = convert_all(src, tmp_path / "out", capsys)
    assert status == 1 and len(errors) == 5
    assert all(str(path) in e and "pose.transform: expected 16 numbers, got None; that image is skipped" in e for e in errors)
    assert not any(t.endswith("/image") for t in DatasetReader(tmp_path / "out").scene(context).topics)


@pytest.mark.parametrize(("field", "value"), [("speed.x", float("inf")), ("acceleration.y", 1e308),
                                              ("box.heading", 1e308)])
def test_an_absurd_motion_or_heading_costs_that_box(source, tmp_path: Path, capsys, field, value) -> None:
    # A speed of inf made the scene writer refuse the frame (all 75 boxes, in a line naming vehicle_pose); an
    # acceleration of 1e308 and a heading of 1e308 rad (any turn) were written without a word.
    src, context = source
    path = component(src, context, "lidar_box")
    set_value(path, f"[LiDARBoxComponent].{field}", 3, value)
    status, errors, _ = convert_all(src, tmp_path / "out", capsys)
    assert status == 1 and len(errors) == 1 and str(path) in errors[0] and errors[0].endswith("that box is skipped")
    assert f"{value:g}" in errors[0] and "heading within +-12.57 rad, speed within 1000 m/s" in errors[0]
    reader = DatasetReader(tmp_path / "out")
    assert reader.frames().num_rows == 1 and reader.objects().num_rows == 74
