"""The unified format: what is written is what stock MCAP tools and avdata's reader read back."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from avdata.errors import AvdataError, FormatVersionError, InputError
from avdata.frames import Transform
from avdata.schema import DatasetReader, DatasetWriter, ObjectLabels, SceneReader
from tests.schema.conftest import (
    EGO_T_LIDAR,
    INFRA_T_LIDAR,
    PERIOD,
    T0,
    WORLD_T_INFRA,
    boxes,
    cloud,
    world_T_ego,
    write_dataset,
)


def stock_messages(path: Path) -> dict[str, list]:
    """Every message decoded with only the stock mcap reader and mcap-protobuf-support."""
    out: dict[str, list] = {}
    with open(path, "rb") as stream:
        for _, channel, message, decoded in make_reader(stream, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            out.setdefault(channel.topic, []).append((message.log_time, decoded))
    return out


def test_every_channel_decodes_with_stock_mcap_tools(dataset: Path) -> None:
    messages = stock_messages(dataset / "scenes" / "scene-a.mcap")
    assert set(messages) == {
        "/tf_static", "/tf", "/ego/lidar/points", "/infra_1/lidar/points", "/ego/cam/image", "/ego/cam/calibration",
        "/labels/objects", "/labels/markers", "/ego/lidar/visibility",
    }
    (_, static), = messages["/tf_static"]
    by_child = {tf.child_frame_id: tf for tf in static.transforms}
    # FrameTransform semantics: the child's pose in the parent (p_parent = R p_child + t).
    lidar = by_child["ego/lidar"]
    assert lidar.parent_frame_id == "ego"
    np.testing.assert_allclose([lidar.translation.x, lidar.translation.y, lidar.translation.z], EGO_T_LIDAR.translation)
    q = lidar.rotation
    np.testing.assert_allclose(Transform.from_quat_wxyz(np.array([q.w, q.x, q.y, q.z])).rotation, EGO_T_LIDAR.rotation,
                               atol=1e-12)
    assert len(messages["/tf"]) == 4
    t1, tf1 = messages["/tf"][1]
    assert t1 == T0 + PERIOD and tf1.transforms[0].child_frame_id == "ego"
    np.testing.assert_allclose(tf1.transforms[0].translation.x, world_T_ego(1).translation[0])
    t, points = messages["/ego/lidar/points"][2]
    assert points.frame_id == "ego/lidar" and [f.name for f in points.fields] == ["x", "y", "z", "intensity", "ring"]
    expected = cloud(2)
    xyz = np.frombuffer(points.data, dtype=np.dtype({"names": ["x", "y", "z"], "formats": ["<f4"] * 3,
                                                     "offsets": [0, 4, 8], "itemsize": points.point_stride}))
    np.testing.assert_array_equal(xyz["x"], expected["x"])
    _, image = messages["/ego/cam/image"][3]
    assert image.data == b"\x89PNG-fake-\x03" and image.format == "png"
    _, calib = messages["/ego/cam/calibration"][0]
    assert (calib.width, calib.height, calib.K[0], calib.P[2]) == (640, 480, 500.0, 320.0)
    _, labels = messages["/labels/objects"][1]
    assert list(labels.ids) == ["car-1", "ped-2"] and labels.frame_id == "world"
    _, markers = messages["/labels/markers"][1]
    assert [e.id for e in markers.entities] == ["car-1", "ped-2"]
    cube = markers.entities[0].cubes[0]
    assert (cube.size.x, cube.size.y, cube.size.z) == pytest.approx((4.5, 1.9, 1.6))
    assert cube.pose.position.x == pytest.approx(11.0)


def test_reader_random_access_returns_written_values(dataset: Path) -> None:
    reader = DatasetReader(dataset)
    assert reader.scenes == ["scene-a", "scene-b"]
    points = reader.points("scene-a", 2, "ego/lidar")
    for name, column in cloud(2).items():
        np.testing.assert_array_equal(points[name], column)
    np.testing.assert_array_equal(reader.points("scene-a", 3, "infra_1/lidar")["x"], cloud(103, 500)["x"])
    data, fmt = reader.image("scene-a", 1, "ego/cam")
    assert (data, fmt) == (b"\x89PNG-fake-\x01", "png")
    info, labels = reader.scene("scene-a").labels(3)
    assert info.timestamp_ns == T0 + 3 * PERIOD and info.sensor_timestamps_ns["infra_1/lidar"] == T0 + 3 * PERIOD + 1000
    np.testing.assert_allclose(labels.boxes.center, boxes(3).center)
    assert labels.attributes[0] == {"state": "moving"} and labels.extras[0]["num_lidar_pts"] == 12.0
    vis = reader.scene("scene-a").visibility("ego/lidar", 2)
    assert vis.in_fov.tolist() == [True, False] and vis.occlusion.tolist() == [1, 3]


def test_frame_graph_of_a_scene_matches_the_written_transforms(dataset: Path) -> None:
    graph = DatasetReader(dataset).frame_graph("scene-a")
    t = T0 + PERIOD + PERIOD // 2
    expected = world_T_ego(1).interpolate(world_T_ego(2), 0.5) @ EGO_T_LIDAR
    assert graph.lookup("world", "ego/lidar", t).allclose(expected, atol=1e-9)
    infra_lidar_T_ego_lidar = graph.lookup("infra_1/lidar", "ego/lidar", T0)
    explicit = np.linalg.inv((WORLD_T_INFRA @ INFRA_T_LIDAR).as_matrix()) @ (world_T_ego(0) @ EGO_T_LIDAR).as_matrix()
    np.testing.assert_allclose(infra_lidar_T_ego_lidar.as_matrix(), explicit, atol=1e-9)


def test_index_rows_equal_explicit_transforms(dataset: Path) -> None:
    reader = DatasetReader(dataset)
    frames = reader.frames().to_pylist()
    assert [(f["scene"], f["frame_index"], f["annotated"], f["split"]) for f in frames] == [
        ("scene-a", 0, True, "train"), ("scene-a", 1, True, "train"), ("scene-a", 2, True, "train"),
        ("scene-a", 3, True, "train"), ("scene-b", 0, False, "val")]
    assert frames[2]["world_T_ego_x_m"] == pytest.approx(4.0)
    objects = [row for row in reader.objects().to_pylist() if row["frame_index"] == 2]
    car = next(row for row in objects if row["object_id"] == "car-1")
    ego_T_world = world_T_ego(2).inverse()
    np.testing.assert_allclose([car["x_ego_m"], car["y_ego_m"], car["z_ego_m"]],
                               ego_T_world.apply(np.array([12.0, 2.0, 0.8])), atol=1e-9)
    assert car["yaw_ego_rad"] == pytest.approx(0.2 - 0.1)
    np.testing.assert_allclose([car["vx_ego_mps"], car["vy_ego_mps"]], ego_T_world.apply_vector(np.array([10.0, 0, 0]))[:2])
    assert car["source_class"] == "Car" and json.loads(car["extras_json"]) == {"num_lidar_pts": 12.0}
    vis = reader.visibility().to_pylist()
    assert len(vis) == 8 and vis[0]["sensor"] == "ego/lidar" and vis[0]["visible_fraction"] == pytest.approx(0.75)


def test_compressed_scenes_read_the_same(tmp_path: Path) -> None:
    root = write_dataset(tmp_path / "zstd", compression="zstd")
    reader = DatasetReader(root)
    np.testing.assert_array_equal(reader.points("scene-a", 1, "ego/lidar")["ring"], cloud(1)["ring"])
    assert reader.scene("scene-a").labels(1)[1].boxes.ids.tolist() == ["car-1", "ped-2"]


def test_interrupted_scene_leaves_no_file_and_rerun_skips_complete_scenes(tmp_path: Path) -> None:
    root = write_dataset(tmp_path / "ds")
    with pytest.raises(RuntimeError), DatasetWriter(root, source="unit-test") as writer:
        with writer.scene("scene-c") as scene:
            scene.add_point_cloud("ego/lidar", T0, cloud(0))
            raise RuntimeError("simulated crash")
    assert not (root / "scenes" / "scene-c.mcap").exists()
    assert not (root / "scenes" / "scene-c.mcap.tmp").exists()
    writer = DatasetWriter(root, source="unit-test")
    assert writer.is_complete("scene-a") and not writer.is_complete("scene-c")


def test_newer_major_version_is_refused(tmp_path: Path) -> None:
    root = write_dataset(tmp_path / "ds")
    manifest = json.loads((root / "avdata.json").read_text())
    manifest["format_version"] = "2.0"
    (root / "avdata.json").write_text(json.dumps(manifest))
    with pytest.raises(FormatVersionError, match=r"avdata.json: format version 2.0 is newer"):
        DatasetReader(root)


def test_truncated_and_corrupted_files_give_one_line_errors(tmp_path: Path) -> None:
    root = write_dataset(tmp_path / "ds")
    path = root / "scenes" / "scene-a.mcap"
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"scene-a.mcap: truncated MCAP file") as error:
        SceneReader(path)
    assert "\n" not in str(error.value)
    corrupted = bytearray(data)
    corrupted[-60:-20] = b"\xff" * 40
    path.write_bytes(bytes(corrupted))
    with pytest.raises(InputError, match="scene-a.mcap"):
        SceneReader(path)
    path.write_bytes(b"not an mcap at all, just text")
    with pytest.raises(InputError, match="not an MCAP file"):
        SceneReader(path)
    path.unlink()
    with pytest.raises(InputError, match="scene file listed in the manifest is missing"):
        DatasetReader(root).scene("scene-a")
    with pytest.raises(InputError, match="does not exist"):
        DatasetReader(tmp_path / "nowhere")


@pytest.mark.parametrize("kind", ["folder", "fifo"])
@pytest.mark.parametrize("file, what", [("avdata.json", "manifest"), ("scenes/scene-a.mcap", "scene"),
                                        ("index/objects.parquet", "index table")])
def test_dataset_file_replaced_by_a_folder_or_fifo_is_named_not_called_missing(tmp_path: Path, file, what, kind):
    root = write_dataset(tmp_path / "ds")
    path = root / file
    path.unlink()
    path.mkdir() if kind == "folder" else os.mkfifo(path)
    expected = f"expected a {what} file, got a folder" if kind == "folder" else "expected a regular file, got a FIFO"
    with pytest.raises(InputError, match=rf"{path.name}: {expected}$"):
        reader = DatasetReader(root)
        reader.scene("scene-a")
        reader.objects()


def test_writer_refuses_reflections_and_backwards_time(tmp_path: Path) -> None:
    with DatasetWriter(tmp_path / "ds", source="unit-test") as writer:
        with pytest.raises(AvdataError, match="reflection"), writer.scene("s") as scene:
            scene.add_static_transform("ego", "ego/lidar", Transform(rotation=np.diag([1.0, -1.0, 1.0]),
                                                                      translation=np.zeros(3)))
        with pytest.raises(AvdataError, match="non-decreasing"), writer.scene("s") as scene:
            scene.add_frame(0, 200, ObjectLabels.empty("world"))
            scene.add_frame(1, 100, ObjectLabels.empty("world"))
    assert not (tmp_path / "ds" / "scenes" / "s.mcap").exists()


def test_index_is_rebuilt_from_mcap(dataset: Path, tmp_path: Path) -> None:
    import shutil

    from avdata.schema import build_index

    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    before = pq.read_table(copy / "index" / "objects.parquet")
    shutil.rmtree(copy / "index")
    build_index(copy)
    assert pq.read_table(copy / "index" / "objects.parquet").equals(before)


@pytest.mark.parametrize(("field", "value", "message"), [
    ("alpha_rad", [1e39], "visibility field alpha_rad: expected values within +-3.40282e+38 (NaN for unknown), got 1e+39"),
    ("visible_fraction", [np.inf], "visibility field visible_fraction: expected values within +-3.40282e+38"),
    ("box2d_xyxy", [[0.0, 0.0, 2e6, 10.0]], "visibility field box2d_xyxy: expected values within +-1e+06"),
    ("ignore_regions_xyxy", [[-np.inf, 0.0, 1.0, 1.0]], "visibility field ignore_regions_xyxy: expected values"),
])
def test_visibility_values_float32_cannot_hold_are_refused(field, value, message):
    # float32 would store these as infinity: a silent change of the input.
    from avdata.schema import VisibilityLabels

    with pytest.raises(AvdataError, match=message.replace("+", r"\+").replace("(", r"\(").replace(")", r"\)")):
        VisibilityLabels(object_ids=["a"], in_fov=[True], **{field: value})
    kept = VisibilityLabels(object_ids=["a"], in_fov=[True], alpha_rad=[np.nan], box2d_xyxy=[[1e6, -1e6, 0.5, 3.25]])
    assert np.isnan(kept.alpha_rad[0]) and kept.box2d_xyxy.tolist() == [[1e6, -1e6, 0.5, 3.25]]


def test_index_tables_are_read_without_arrow_s_thread_pool(dataset: Path) -> None:
    # Index tables are parsed from Python bytes (read once for their checksum). On Arrow's pool, a worker that drops
    # the last reference to those bytes after the read returned takes the GIL; during interpreter exit that aborts
    # the process with "terminate called without an active exception" (exit -6 after a script's last line, 1 run in
    # 6 under load). Read on the calling thread, no pool worker is ever started.
    from tests.arrow_threads import threads_started

    setup = f"from avdata.schema import DatasetReader\ndataset = DatasetReader({str(dataset)!r})"
    code = "[dataset.table(name) for name in ('frames', 'objects', 'visibility')]"
    assert threads_started(setup, code) == 0
