"""Collaboration on a generated V2I scene: what reaches the ego, in its frame, at the stated range and rate."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.compute as pc
import pytest

from avdata.errors import InputError
from avdata.perception import CollaborationConfig, CollaborativePerception, merge_detections
from avdata.perception.detections import Detections
from avdata.schema import DatasetReader
from avdata.studies import load_study

SMALL = Path(__file__).resolve().parents[1] / "studies" / "small_study.yaml"


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> DatasetReader:
    from avdata.generators.config import scenario_from_dict
    from avdata.generators.driver import generate

    scenario = {**load_study(SMALL).scenario(0), "frames": 4}
    root = tmp_path_factory.mktemp("v2i") / "ds"
    generate(scenario_from_dict(scenario, "test"), root, progress=False)
    return DatasetReader(root)


def _expected_ego_boxes(ds: DatasetReader, frame: int, sensors: list[str], own: list[str]) -> np.ndarray:
    """Centres, in the ego frame, of every object any of ``sensors`` saw, moved by the scene reader's labels API."""
    scene = ds.scenes[0]
    reader = ds.scene(scene)
    info, labels = reader.labels(frame)
    vis = ds.visibility().filter(pc.and_(pc.equal(ds.visibility()["frame_index"], frame),
                                         pc.is_in(ds.visibility()["sensor"], value_set=__import__("pyarrow").array(sensors))))
    seen = vis.filter(pc.and_(vis["in_fov"], pc.greater(vis["n_points"], 0)))["object_id"].to_pylist()
    boxes = labels.boxes.to("ego", reader.graph, info.timestamp_ns)
    keep = np.isin(boxes.ids, np.array(seen, dtype=str)) & ~np.isin(boxes.ids, np.array(own, dtype=str))
    return boxes.center[keep]


def _sorted(centres: np.ndarray) -> np.ndarray:
    return centres[np.lexsort(centres.T[::-1])]


def test_noise_free_detections_are_the_seen_objects_in_the_ego_frame(dataset: DatasetReader) -> None:
    config = CollaborationConfig(ego_noise="none", noise="none", comm_range_m=1e6, merge_distance_m=0.0, max_range_m=1e6)
    perception = CollaborativePerception(dataset, dataset.scenes[0], config)
    assert perception.ego_sensors == ["ego/lidar_top"]
    assert perception.collaborator_sensors == [f"infra_{i:02d}/lidar" for i in range(4)]
    for delivery in perception.run():
        got = delivery.detections
        assert got.boxes.frame == "ego" and delivery.sensors_in_range == 4
        per_sensor = []
        for sensor in ["ego/lidar_top", *perception.collaborator_sensors]:
            per_sensor.append(_expected_ego_boxes(dataset, delivery.frame_index, [sensor], perception.own_object_ids))
        expected = np.concatenate(per_sensor)  # one detection per (sensor, seen object): nothing merged
        assert len(got) == len(expected) > 0
        np.testing.assert_allclose(_sorted(got.boxes.center), _sorted(expected), atol=1e-9)
        assert delivery.collaborative_detections == len(expected) - len(per_sensor[0])


def test_range_rate_and_latency(dataset: DatasetReader) -> None:
    scene = dataset.scenes[0]
    run = lambda **kw: CollaborativePerception(dataset, scene, CollaborationConfig(noise="none", **kw)).run()  # noqa: E731
    every = run(comm_range_m=1e6)
    assert [d.collaborative_detections > 0 for d in every] == [True] * 4
    half = run(comm_range_m=1e6, rate_hz=5.0)
    assert [d.collaborative_detections for d in half] == [every[0].collaborative_detections, 0,
                                                          every[2].collaborative_detections, 0]
    late = run(comm_range_m=1e6, latency_frames=1)
    assert late[0].collaborative_detections == 0
    assert [d.collaborative_detections for d in late[1:]] == [d.collaborative_detections for d in every[:-1]]
    nobody = run(comm_range_m=0.0)
    assert all(d.sensors_in_range == 0 and d.collaborative_detections == 0 for d in nobody)
    # The infrastructure poles stand still: the ones in range at a given range are those whose foot is that close.
    graph = dataset.scene(scene).graph
    t = int(dataset.frames()["timestamp_ns"][0].as_py())
    ego_xy = graph.lookup("world", "ego", t).translation[:2]
    dist = sorted(np.hypot(*(graph.lookup("world", f"infra_{i:02d}/lidar", t).translation[:2] - ego_xy)) for i in range(4))
    cut = (dist[1] + dist[2]) / 2
    assert run(comm_range_m=cut)[0].sensors_in_range == 2


def test_merge_keeps_one_detection_per_object(dataset: DatasetReader) -> None:
    config = CollaborationConfig(ego_noise="none", noise="none", comm_range_m=1e6, merge_distance_m=0.0)
    raw = CollaborativePerception(dataset, dataset.scenes[0], config).run()[0].detections
    merged = merge_detections(raw, 1.0)
    # Noise-free duplicates coincide: merging leaves exactly one per distinct object centre.
    assert len(merged) == len(np.unique(np.round(raw.boxes.center, 6), axis=0)) < len(raw)
    assert isinstance(merged, Detections)


def test_a_scene_without_an_ego_lidar_is_refused(dataset: DatasetReader) -> None:
    with pytest.raises(InputError, match="lidar of agent 'infra_07'"):
        CollaborativePerception(dataset, dataset.scenes[0], CollaborationConfig(ego="infra_07"))
    with pytest.raises(InputError, match="noise in"):
        CollaborationConfig(noise="loud")


@pytest.mark.parametrize("rate_hz", [3.0, 1000.0, 4.0])
def test_a_send_rate_the_frames_cannot_honour_is_refused(dataset: DatasetReader, rate_hz: float) -> None:
    # 3 Hz in this 10 Hz scene sent every third frame (3.33 Hz), 1000 Hz every frame, while a study's report said 3
    # and 1000.
    scene = dataset.scenes[0]
    with pytest.raises(InputError, match=rf"^{scene}: collaboration rate_hz: expected the frame rate 10 Hz divided by a "
                                         rf"whole number \(collaborators send on whole frames\), got {rate_hz:g}$"):
        CollaborativePerception(dataset, scene, CollaborationConfig(noise="none", rate_hz=rate_hz))
