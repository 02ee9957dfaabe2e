"""``avdata view --rerun``: the .rrd read back with Rerun's own reader holds the scene's entities, counts and values."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from avdata.cli import main
from avdata.schema import DatasetReader, topics

pytest.importorskip("rerun", reason="the Rerun SDK (pip install 'avdata[rerun]') is not installed")


def _read_rrd(path: Path) -> dict[str, list[dict]]:
    """Entity path -> rows (column name -> value), in scene-time order, via rerun.chunk.RrdReader."""
    from rerun.chunk import RrdReader

    rows: dict[str, list[dict]] = defaultdict(list)
    for chunk in RrdReader(path).stream():
        rows[chunk.entity_path].extend(chunk.to_record_batch().to_pylist())
    for entity in rows:
        rows[entity].sort(key=lambda r: (r.get("scene_time") is not None, r.get("scene_time") or 0))
    return rows


def _ns(value) -> int:
    return int(np.datetime64(value, "ns").astype(np.int64))


@pytest.mark.parametrize("which", ["demo", "generated"])
def test_recording_holds_every_message_of_the_scene(demo_dataset: Path, generated: Path, tmp_path: Path, which: str) -> None:
    from avdata.viz.rerun_log import entity_path

    dataset = demo_dataset if which == "demo" else generated
    out = tmp_path / "scene.rrd"
    assert main(["view", "--rerun", str(dataset), "--save", str(out)]) == 0
    rows = _read_rrd(out)
    ds = DatasetReader(dataset)
    reader = ds.scene(ds.scenes[0])
    graph = reader.graph
    expected = {"/world"}
    for frame in graph.frames:
        if graph.parent(frame) is not None:
            expected.add("/" + entity_path(graph, frame))
            if not graph.is_static(frame):
                edge = graph.stamped_edge(frame)
                logged = [r for r in rows["/" + entity_path(graph, frame)] if r.get("Transform3D:translation")]
                assert [_ns(r["scene_time"]) for r in logged] == edge.timestamps_ns.tolist()
                np.testing.assert_allclose([r["Transform3D:translation"][0] for r in logged],
                                           edge.parent_T_child.translation, rtol=1e-6, atol=1e-4)
    lidars = [s for s in reader.sensors() if topics.sensor_topic(s, topics.POINTS_SUFFIX) in reader.topics]
    cameras = [s for s in reader.sensors() if topics.sensor_topic(s, topics.IMAGE_SUFFIX) in reader.topics]
    assert lidars and cameras
    for lidar in lidars:
        entity = f"/{entity_path(graph, lidar)}/points"
        expected.add(entity)
        times = reader.times(topics.sensor_topic(lidar, topics.POINTS_SUFFIX)).tolist()
        assert [_ns(r["scene_time"]) for r in rows[entity]] == times
        cloud = reader.points(lidar, times[-1])
        np.testing.assert_array_equal(np.array(rows[entity][-1]["Points3D:positions"], np.float32),
                                      np.stack([cloud["x"], cloud["y"], cloud["z"]], axis=1).astype(np.float32))
        assert len(rows[entity][-1]["Points3D:colors"]) == len(cloud)
    for camera in cameras:
        entity = f"/{entity_path(graph, camera)}/image"
        expected.add(entity)
        times = reader.times(topics.sensor_topic(camera, topics.IMAGE_SUFFIX)).tolist()
        blobs = [r for r in rows[entity] if r.get("EncodedImage:blob")]
        assert [_ns(r["scene_time"]) for r in blobs] == times
        assert bytes(blobs[0]["EncodedImage:blob"][0]) == bytes(reader.image(camera, times[0])[0])
        pinhole = next(r for r in rows[entity] if r.get("Pinhole:image_from_camera"))
        k = np.array(pinhole["Pinhole:image_from_camera"][0]).reshape(3, 3).T  # Rerun stores it column-major
        np.testing.assert_allclose(k, np.array(reader.camera_calibration(camera, times[0]).K).reshape(3, 3))
    infos = reader.frame_infos()
    _, labels = reader.labels(len(infos) - 1)
    label_entity = f"/{entity_path(graph, labels.boxes.frame)}/labels"
    expected.add(label_entity)
    assert [r["frame"] for r in rows[label_entity]] == [i.frame_index for i in infos]
    last = rows[label_entity][-1]
    np.testing.assert_allclose(last["Boxes3D:centers"], labels.boxes.center, rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(np.array(last["Boxes3D:half_sizes"]) * 2, labels.boxes.size_lwh, rtol=1e-6)
    assert last["Boxes3D:labels"] == [f"{c} {i}" for c, i in zip(labels.boxes.classes, labels.boxes.ids, strict=True)]
    for sensor, frame_index, _, visibility in reader.iter_visibility():
        entity = f"/{entity_path(graph, sensor)}/visibility"
        expected.add(entity)
        row = next(r for r in rows[entity] if r["frame"] == frame_index)
        assert row["object_id"] == [str(i) for i in visibility.object_ids]
        assert row["n_points"] == np.asarray(visibility.n_points).tolist()
    assert set(rows) - {"/__properties"} == expected


def test_rerun_options_are_checked(demo_dataset: Path, tmp_path: Path, capsys, monkeypatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["view", "--rerun", str(demo_dataset)]) == 1
    assert capsys.readouterr().err.startswith("avdata: error: view --rerun: expected a display for the Rerun viewer")
    assert main(["view", "--rerun", str(demo_dataset), "--save", str(tmp_path / "scene.mcap")]) == 1
    assert main(["view", str(demo_dataset), "--save", str(tmp_path / "scene.rrd")]) == 1
    (tmp_path / "folder.rrd").mkdir()
    assert main(["view", "--rerun", str(demo_dataset), "--save", str(tmp_path / "folder.rrd")]) == 1
    err = capsys.readouterr().err.splitlines()
    assert err == [f"avdata: error: {tmp_path / 'scene.mcap'}: expected an .rrd file, got suffix '.mcap'",
                   "avdata: error: view --save: expected --rerun with it (--save writes a Rerun recording)",
                   f"avdata: error: {tmp_path / 'folder.rrd'}: cannot write this file (a folder is in its place)"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["folder.rrd"]
