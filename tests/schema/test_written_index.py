"""The index rows of scenes written in this process come from the writer, and equal those read from the files."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import avdata.schema.dataset as dataset_module
import avdata.schema.index as index_module
from avdata.cli import main
from avdata.errors import AvdataError, InputError
from avdata.frames import Boxes3D, Transform
from avdata.schema import DatasetWriter, ObjectLabels, build_index
from avdata.schema.index import INDEX_TABLES, SCHEMAS
from avdata.schema.records import VisibilityLabels
from tests.converters.test_nuscenes import build_synthetic_nuscenes
from tests.realdata import REALDATA
from tests.schema.conftest import write_dataset


def _index(root: Path) -> dict[str, object]:
    return {name: pq.read_table(root / "index" / f"{name}.parquet") for name in INDEX_TABLES}


def _rebuilt_from_files(root: Path, tmp_path: Path) -> Path:
    copy = tmp_path / f"{root.name}-reread"
    shutil.copytree(root, copy)
    shutil.rmtree(copy / "index")
    build_index(copy)  # no writer: every scene file is read
    return copy


def _count_reads(monkeypatch: pytest.MonkeyPatch) -> list[Path]:
    reads: list[Path] = []
    real = dataset_module.scene_index

    def counting(scene, split=""):  # type: ignore[no-untyped-def]
        reads.append(scene.path)
        return real(scene, split)

    monkeypatch.setattr(dataset_module, "scene_index", counting)
    return reads


def _assert_same_index_and_manifest(root: Path, reread: Path) -> None:
    for name in INDEX_TABLES:  # byte for byte (Table.equals would call NaN columns different)
        assert (root / "index" / f"{name}.parquet").read_bytes() == (reread / "index" / f"{name}.parquet").read_bytes()
    assert json.loads((root / "avdata.json").read_text()) == json.loads((reread / "avdata.json").read_text())


def _parquet_bytes(table: pa.Table) -> bytes:
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink)
    return sink.getvalue().to_pybytes()


def _check_against_pa_table(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Makes every index table also be built by ``pa.table`` and compared, column by column and as Parquet bytes."""
    checked: list[str] = []
    built = index_module._table

    def comparing(columns: dict[str, Any], schema: pa.Schema) -> pa.Table:
        ours = built(columns, schema)
        reference = pa.table(columns, schema=schema)
        assert ours.schema == reference.schema
        for name in schema.names:  # to_pylist: NaN != NaN would fail Table.equals on the NaN ego columns
            assert repr(ours.column(name).to_pylist()) == repr(reference.column(name).to_pylist()), name
        assert _parquet_bytes(ours) == _parquet_bytes(reference)
        checked.append(schema.names[-1])
        return ours

    monkeypatch.setattr(index_module, "_table", comparing)
    return checked


def test_index_tables_built_from_buffers_equal_pa_table(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    checked = _check_against_pa_table(monkeypatch)
    write_dataset(tmp_path / "ds", n_frames=5)  # two agents, velocities, visibility
    assert main(["convert", "kitti-object", str(REALDATA / "kitti" / "object"), str(tmp_path / "kitti"), "--quiet"]) == 0
    build_synthetic_nuscenes(tmp_path / "nuscenes-src")  # velocities, attributes, two scenes
    assert main(["convert", "nuscenes", str(tmp_path / "nuscenes-src"), str(tmp_path / "nuscenes"), "--version",
                 "v1.0-mini", "--quiet"]) == 0
    assert len(checked) >= 9
    # What the conversions above do not produce: nulls (a scene without an ego agent), empty tables,
    # NaN and infinities, float64 values rounded to float32, Unicode.
    columns = {
        "frames": {"scene": ["ß-😀", "a"], "frame_index": [0, 1], "timestamp_ns": np.array([0, 2**62]),
                   "annotated": [True, False], "split": [np.str_("val"), "train"],
                   "sensor_timestamps_ns": [[("a", 1), ("b", -2)], []],
                   "ego_frame": [None, None], **{name: np.array([np.nan, -np.inf]) for name in SCHEMAS["frames"].names[7:14]},
                   "n_objects": [0, 3]},
        "objects": {field.name: [] for field in SCHEMAS["objects"]},
        "visibility": {field.name: ([0.1, np.nan, 1e-40, 3.4e38] if pa.types.is_floating(field.type) else
                                    [1, 0, -1, 2] if pa.types.is_integer(field.type) else
                                    [True, False, True, True] if pa.types.is_boolean(field.type) else ["x", "", "y", "é"])
                       for field in SCHEMAS["visibility"]},
    }
    for name, table_columns in columns.items():
        index_module._table(table_columns, SCHEMAS[name])
    # Values a cast would change are refused, as Arrow's safe cast (and so pa.table) refuses them.
    for values, arrow_type in (([300], pa.int8()), ([1.5], pa.int32()), ([np.nan], pa.int32()),
                               ([2**53 + 1], pa.float64()), ([-1], pa.uint32())):
        with pytest.raises(pa.ArrowInvalid):
            pa.array(np.asarray(values)).cast(arrow_type)
        with pytest.raises(pa.ArrowInvalid, match="does not fit an Arrow"):
            index_module._array(values, arrow_type)
    for values, arrow_type in (([2.0, -0.0], pa.int32()), ([1e300, 1.1, 1e-46, np.nan], pa.float32()), ([], pa.int8())):
        ours, arrow = index_module._array(values, arrow_type), pa.array(np.asarray(values)).cast(arrow_type)
        assert ours.type == arrow.type
        np.testing.assert_array_equal(ours.to_numpy(), arrow.to_numpy())
    with pytest.raises(TypeError):  # not text in a string column: refused, as pa.table refuses it
        index_module._array(["a", 3], pa.string())


def test_converting_imports_neither_pandas_nor_heavy_modules(tmp_path: Path) -> None:
    """pandas (~40 MB), torch, OpenCV, Open3D and matplotlib stay out of a conversion's memory; so do Arrow's compute
    functions (~40 MB once a cast builds them) out of the library's (the command line's study parser imports them)."""
    kitti = str(REALDATA / "kitti" / "object")
    code = ("import sys; from pathlib import Path; from avdata.converters import ConvertConfig, run_conversion; "
            "from avdata.converters.kitti import KittiObjectConverter; "
            f"run_conversion(KittiObjectConverter(ConvertConfig(src=Path({kitti!r}), dst=Path({str(tmp_path / 'lib')!r}), "
            "quiet=True))); "
            "print(sorted(m for m in ('pandas', 'pyarrow.compute', 'torch', 'cv2', 'open3d', 'matplotlib') "
            "if m in sys.modules)); "
            "from avdata.cli import main; "
            f"assert main(['convert', 'kitti-object', {kitti!r}, {str(tmp_path / 'cli')!r}, '--quiet']) == 0; "
            "print(sorted(m for m in ('pandas', 'torch', 'cv2', 'open3d', 'matplotlib') if m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                          env={**os.environ, "PYTHONPATH": str(Path(index_module.__file__).parents[2])})
    assert [line for line in done.stdout.splitlines() if line.startswith("[")] == ["[]", "[]"]


def test_index_of_a_written_dataset_equals_the_index_read_from_its_files(tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    reads = _count_reads(monkeypatch)
    root = write_dataset(tmp_path / "ds", n_frames=5)
    assert reads == []  # built from what the writer wrote
    assert _index(root)["visibility"].num_rows > 0 and _index(root)["objects"].num_rows == 10  # type: ignore[attr-defined]
    _assert_same_index_and_manifest(root, _rebuilt_from_files(root, tmp_path))
    assert len(reads) == len(list((root / "scenes").glob("*.mcap"))) == 2


def test_attributes_that_reencode_differently_give_the_same_index_written_or_read(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # The writer stores each object's JSON as readers re-encode it, and the index takes that text
    # as is: int keys sort differently once they are strings, nested objects are sorted too.
    reads = _count_reads(monkeypatch)
    odd = [{10: "ten", 9: "nine"}, {"z": {"b": [1, {"y": 2, "x": 1}], "a": None}, "k": 1.5}, {"plain": "x", "n": 2}]
    root = tmp_path / "ds"
    with DatasetWriter(root, source="unit-test") as writer:
        with writer.scene("s") as scene:
            boxes = Boxes3D.from_yaw(np.zeros((3, 3)), np.ones((3, 3)), np.zeros(3), "world",
                                     ids=["a", "b", "c"], classes=["car"] * 3)
            scene.add_frame(0, 0, ObjectLabels(boxes=boxes, source_classes=["Car"] * 3, attributes=odd,
                                               extras=[{2: 1.0}, {}, {"m": [3]}]))
    assert reads == []
    objects = _index(root)["objects"]
    assert objects.column("attributes_json").to_pylist() == [  # type: ignore[attr-defined]
        '{"10": "ten", "9": "nine"}', '{"k": 1.5, "z": {"a": null, "b": [1, {"x": 1, "y": 2}]}}', '{"n": 2, "plain": "x"}']
    assert objects.column("extras_json").to_pylist() == ['{"2": 1.0}', "{}", '{"m": [3]}']  # type: ignore[attr-defined]
    _assert_same_index_and_manifest(root, _rebuilt_from_files(root, tmp_path))
    with pytest.raises(AvdataError, match="expected extras as one dict per object, got a list"):
        ObjectLabels(boxes=boxes, source_classes=["Car"] * 3, extras=[{}, [1], {}])


def test_index_of_a_converted_real_kitti_object_set_equals_the_index_read_from_its_files(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    reads = _count_reads(monkeypatch)
    root = tmp_path / "kitti"
    assert main(["convert", "kitti-object", str(REALDATA / "kitti" / "object"), str(root), "--quiet"]) == 0
    assert reads == []
    objects = _index(root)["objects"]
    assert objects.num_rows > 0 and set(objects.column("class").to_pylist()) >= {"car"}  # type: ignore[attr-defined]
    _assert_same_index_and_manifest(root, _rebuilt_from_files(root, tmp_path))


def test_a_scene_file_changed_after_writing_is_read_again(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    reads = _count_reads(monkeypatch)
    source = write_dataset(tmp_path / "source", n_frames=3)
    root = tmp_path / "ds"
    with DatasetWriter(root, source="unit-test") as writer:
        with writer.scene("scene-a") as scene:
            scene.add_frame(0, 0, ObjectLabels.empty("world"))
        with writer.scene("scene-b") as scene:
            scene.add_frame(0, 0, ObjectLabels.empty("world"))
        path = root / "scenes" / "scene-b.mcap"
        assert path in writer._fresh.parts
        # Another process replaces the file before the index is built: the new file is what counts.
        shutil.copyfile(source / "scenes" / "scene-a.mcap", path)
        os.utime(path, ns=(1, 1))
        shutil.copyfile(source / "scenes" / "scene-a.mcap", root / "scenes" / "scene-a.mcap")
    assert sorted(p.name for p in reads) == ["scene-a.mcap", "scene-b.mcap"]
    frames = _index(root)["frames"]
    assert frames.num_rows == 6 and set(frames.column("scene").to_pylist()) == {"scene-a"}  # type: ignore[attr-defined]


def test_a_scene_without_frames_is_refused_and_the_dataset_indexed(tmp_path: Path) -> None:
    # A scene whose every frame was refused used to be kept; the index then failed for the whole dataset
    # ("no frame in the scene"), leaving no manifest. The writer now refuses it; the other scenes stand.
    cloud = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    root = tmp_path / "ds"
    with DatasetWriter(root, source="test") as writer:
        with pytest.raises(InputError, match=r"s\.mcap: no frame written \(every frame was refused, or none was given\)"):
            with writer.scene("s") as scene:
                scene.add_static_transform("ego", "ego/lidar", Transform.identity())
                scene.add_point_cloud("ego/lidar", 1_000, cloud)
        with writer.scene("t") as scene:
            scene.add_frame(0, 0, ObjectLabels.empty("world"))
    assert sorted(p.name for p in (root / "scenes").iterdir()) == ["t.mcap"]  # no file, no temporary left
    assert _index(root)["frames"].column("scene").to_pylist() == ["t"]  # type: ignore[attr-defined]


def test_visibility_given_to_the_writer_is_indexed_as_the_file_holds_it(tmp_path: Path) -> None:
    # The index takes the labels the writer was given, not the decoded message: values float32 rounds,
    # NaN, -0.0 and Unicode ids must come out as the file has them, and the caller's arrays, changed
    # after the call, must not reach the index.
    ids = np.array(["a", "ü-2", "c"])
    fraction = np.array([0.1, np.nan, -0.0])
    points = np.array([3, -1, 7], dtype=np.int32)
    root = tmp_path / "ds"
    with DatasetWriter(root, source="unit-test") as writer:
        with writer.scene("s") as scene:
            boxes = Boxes3D.from_yaw(np.zeros((3, 3)), np.ones((3, 3)), np.zeros(3), "world", ids=ids,
                                     classes=["car"] * 3)
            scene.add_frame(0, 0, ObjectLabels(boxes=boxes, source_classes=["Car"] * 3))
            scene.add_visibility("ego/lidar", 0, 0, VisibilityLabels(
                object_ids=ids, in_fov=np.array([True, False, True]), n_points=points, visible_fraction=fraction,
                box2d_xyxy=np.array([[1.0, 2.0, 3.000001, 4.0]] * 3), alpha_rad=np.array([1e-46, 1.0, -2.0])))
            points[:] = 99  # after the call
            fraction[:] = 0.5
    _assert_same_index_and_manifest(root, _rebuilt_from_files(root, tmp_path))
    visibility = _index(root)["visibility"]
    assert visibility.column("n_points").to_pylist() == [3, -1, 7]  # type: ignore[attr-defined]
    assert visibility.column("object_id").to_pylist() == ["a", "ü-2", "c"]  # type: ignore[attr-defined]
