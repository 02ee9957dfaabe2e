"""The index rows of scenes written in this process come from the writer, and equal those read from the files."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

import avdata.schema.dataset as dataset_module
from avdata.cli import main
from avdata.errors import InputError
from avdata.frames import Transform
from avdata.schema import DatasetWriter, ObjectLabels, build_index
from avdata.schema.index import INDEX_TABLES
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


def test_index_of_a_written_dataset_equals_the_index_read_from_its_files(tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    reads = _count_reads(monkeypatch)
    root = write_dataset(tmp_path / "ds", n_frames=5)
    assert reads == []  # built from what the writer wrote
    assert _index(root)["visibility"].num_rows > 0 and _index(root)["objects"].num_rows == 10  # type: ignore[attr-defined]
    _assert_same_index_and_manifest(root, _rebuilt_from_files(root, tmp_path))
    assert len(reads) == len(list((root / "scenes").glob("*.mcap"))) == 2


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
