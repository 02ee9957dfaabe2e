"""Reading a unified dataset from S3 (moto's standalone server on 127.0.0.1): the same values as from disk, by ranged
requests (the summary first, then at most 2 requests per frame per sensor), damage reported naming the object, and a
cache folder that never serves a changed object."""

from __future__ import annotations

import pickle
import time
from pathlib import Path

import numpy as np
import pytest

from avdata.cli import main
from avdata.demo import write_demo
from avdata.errors import InputError
from avdata.loaders import FrameDataset
from avdata.schema import DatasetReader
from avdata.schema.mcap.fileio import _Held, counting_requests
from tests.storage.kitti_s3 import assert_items_equal

SENSORS = ["ego/lidar_top", "ego/cam_front"]


@pytest.fixture(scope="module")
def local_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_demo(tmp_path_factory.mktemp("read") / "demo")


def upload(server, root: Path, prefix: str) -> str:  # noqa: ANN001 - fixture type
    """Puts every file of ``root`` under ``prefix`` in the test bucket; returns the dataset's URI."""
    client = server.client()
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        client.put_object(Bucket=server.bucket, Key=f"{prefix}/{path.relative_to(root)}", Body=path.read_bytes())
    return f"{server.uri}/{prefix}"


def flip_byte(data: bytes, offset: int) -> bytes:
    return data[:offset] + bytes([data[offset] ^ 0xFF]) + data[offset + 1 :]


def test_frames_read_from_s3_equal_local_in_at_most_two_requests_per_frame_and_sensor(s3_server, local_dataset: Path
                                                                                      ) -> None:  # noqa: ANN001
    uri = upload(s3_server, local_dataset, "demo")
    local = FrameDataset(local_dataset, sensors=SENSORS)
    with counting_requests() as opening:
        remote = FrameDataset(uri, sensors=SENSORS)
        first = remote[0]  # opens the scene: its summary, then the frame tree (/tf_static, /tf)
    assert opening.gets + opening.heads <= 12, opening
    assert_items_equal(first, local[0])
    scene_size = (local_dataset / "scenes" / "demo-0000.mcap").stat().st_size
    for index in range(1, len(local)):
        with counting_requests() as frame:
            item = remote[index]
        assert_items_equal(item, local[index])
        assert frame.heads == 0 and frame.gets <= 2 * len(SENSORS), (index, frame)
        assert frame.gets >= 1  # the lidar sweep has a chunk of its own: always fetched
        # only the chunks the frame needs: a lidar chunk and the small chunk of its labels and image
        assert frame.bytes < scene_size / 3, (index, frame)
    # A frame's sensor messages fetched together: the reads that follow make no request.
    scene = DatasetReader(uri).scene("demo-0000")
    scene.graph  # noqa: B018 - opens the scene as FrameDataset does (the frame tree)
    lidar_ns, camera_ns = (DatasetReader(local_dataset).sensor_time("demo-0000", 3, sensor) for sensor in SENSORS)
    with counting_requests() as together:
        scene.prefetch([("/ego/lidar_top/points", lidar_ns), ("/ego/cam_front/image", camera_ns)])
    with counting_requests() as after:
        scene.points("ego/lidar_top", lidar_ns)
        scene.image("ego/cam_front", camera_ns)
    assert 1 <= together.gets <= 2 * len(SENSORS) and after.gets == 0, (together, after)
    reader = DatasetReader(uri, verify=True)
    expected = DatasetReader(local_dataset)
    for scene, frame_index, _ in expected.iter_frames():
        np.testing.assert_array_equal(reader.points(scene, frame_index, "ego/lidar_top"),
                                      expected.points(scene, frame_index, "ego/lidar_top"))
        assert reader.image(scene, frame_index, "ego/cam_front") == expected.image(scene, frame_index, "ego/cam_front")
    assert reader.frames().equals(expected.frames()) and reader.objects().equals(expected.objects())
    assert reader.size_bytes() == expected.size_bytes()


def test_a_damaged_object_is_one_line_naming_its_uri(s3_server, local_dataset: Path, tmp_path: Path
                                                     ) -> None:  # noqa: ANN001
    scene_file = local_dataset / "scenes" / "demo-0000.mcap"
    lidar = DatasetReader(local_dataset).scene("demo-0000").message_table("/ego/lidar_top/points")
    chunk = DatasetReader(local_dataset).scene("demo-0000")._mcap.chunks[int(lidar.chunk[2])]
    damaged = tmp_path / "damaged"
    damaged.mkdir()
    for path in local_dataset.rglob("*"):
        if path.is_file():
            target = damaged / path.relative_to(local_dataset)
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(path.read_bytes())
    (damaged / "scenes" / "demo-0000.mcap").write_bytes(
        flip_byte(scene_file.read_bytes(), chunk.records_offset + chunk.compressed_size // 2))
    uri = upload(s3_server, damaged, "damaged")
    with pytest.raises(InputError) as on_disk:
        DatasetReader(damaged, verify=True).points("demo-0000", 2, "ego/lidar_top")
    with pytest.raises(InputError) as in_store:
        DatasetReader(uri, verify=True).points("demo-0000", 2, "ego/lidar_top")
    expected = str(on_disk.value).replace(str(damaged / "scenes" / "demo-0000.mcap"), f"{uri}/scenes/demo-0000.mcap")
    assert str(in_store.value) == expected and "chunk CRC mismatch" in expected and "\n" not in expected
    with pytest.raises(InputError, match=rf"^{uri}/scenes/missing.mcap: no such object$"):
        reader = DatasetReader(uri)
        reader.scenes.append("missing")
        reader.scene("missing")


def test_cache_folder_serves_fetched_ranges_but_never_a_changed_object(s3_server, local_dataset: Path,
                                                                        tmp_path: Path) -> None:  # noqa: ANN001
    uri = upload(s3_server, local_dataset, "cached")
    cache = tmp_path / "cache"
    with counting_requests() as cold:
        cloud = DatasetReader(uri, cache_dir=cache).points("demo-0000", 1, "ego/lidar_top").copy()
    with counting_requests() as warm:
        again = DatasetReader(uri, cache_dir=cache).points("demo-0000", 1, "ego/lidar_top")
    np.testing.assert_array_equal(again, cloud)
    assert warm.cache_hits == cold.gets - 0 and warm.bytes == 0, (cold, warm)
    # Replaced by an object of the same size whose bytes differ: its modification time changes the key.
    scene = local_dataset / "scenes" / "demo-0000.mcap"
    reader = DatasetReader(local_dataset).scene("demo-0000")
    lidar = reader.message_table("/ego/lidar_top/points")
    chunk = reader._mcap.chunks[int(lidar.chunk[1])]
    time.sleep(1.1)  # S3 modification times have one-second resolution
    s3_server.client().put_object(Bucket=s3_server.bucket, Key="cached/scenes/demo-0000.mcap",
                                  Body=flip_byte(scene.read_bytes(), chunk.records_offset + 100))
    with counting_requests() as changed, pytest.raises(InputError, match="chunk CRC mismatch"):
        DatasetReader(uri, verify=True, cache_dir=cache).points("demo-0000", 1, "ego/lidar_top")
    assert changed.cache_hits == 0 and changed.gets >= 2


def test_info_of_a_dataset_in_s3(s3_server, local_dataset: Path, capsys: pytest.CaptureFixture[str]) -> None:  # noqa: ANN001
    uri = upload(s3_server, local_dataset, "info")
    assert main(["info", str(local_dataset)]) == 0
    on_disk = capsys.readouterr().out.splitlines()
    assert main(["info", uri]) == 0
    in_store = capsys.readouterr().out.splitlines()
    assert in_store[0] == f"dataset:   {uri}" and in_store[1:] == on_disk[1:]
    assert main(["info", f"{s3_server.uri}/nothing-here"]) == 1
    assert capsys.readouterr().err.strip() == (f"avdata: error: {s3_server.uri}/nothing-here/avdata.json: manifest missing "
                                               "(not an avdata dataset, or conversion unfinished)")


def test_a_copy_in_another_process_refuses_an_object_changed_since(s3_server, local_dataset: Path) -> None:  # noqa: ANN001
    uri = upload(s3_server, local_dataset, "changed")
    scene = DatasetReader(uri).scene("demo-0000")
    copy = pickle.loads(pickle.dumps(scene))  # as a DataLoader or Ray worker gets it: it opens the object again
    data = (local_dataset / "scenes" / "demo-0000.mcap").read_bytes()
    s3_server.client().put_object(Bucket=s3_server.bucket, Key="changed/scenes/demo-0000.mcap", Body=data + b"\0")
    with pytest.raises(InputError, match=rf"^{uri}/scenes/demo-0000.mcap: the object changed while it was being read "
                                         r"\(its size, ETag or modification time differ from when it was opened\); "
                                         "open the dataset again$"):
        copy.points("ego/lidar_top", int(copy.times("/ego/lidar_top/points")[1]))


def test_held_ranges_stay_within_the_process_budget() -> None:
    held = _Held(budget=100)
    held.add("a", {0: b"x" * 60})
    held.add("b", {10: b"y" * 30})
    assert bytes(held.find("a", 5, 10)) == b"x" * 10 and held.find("b", 0, 5) is None
    held.add("b", {50: b"z" * 40})  # over budget: the least recently used ("b" at 10) goes, not the new one
    assert held.find("b", 10, 5) is None and held.find("a", 0, 60) is not None and held.find("b", 50, 40) is not None
    held.add("c", {0: b"w" * 150})  # larger than the budget alone: kept, everything older goes
    assert held.find("a", 0, 1) is None and held.find("b", 50, 1) is None and held.find("c", 0, 150) is not None
    held.drop("c")
    assert held.find("c", 0, 1) is None


def test_audit_render_stats_and_rerun_read_a_dataset_in_s3_as_on_disk(s3_server, local_dataset: Path, tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:  # noqa: ANN001
    """Every command that only reads a dataset takes its URI; Foxglove's layout, which names local files, refuses it."""
    pytest.importorskip("rerun")
    uri = upload(s3_server, local_dataset, "demo")
    outputs = {}
    for where, dataset in (("disk", str(local_dataset)), ("store", uri)):
        out = tmp_path / where
        assert main(["audit", dataset, str(local_dataset)]) == 0
        assert main(["render", dataset, str(out / "frame.png")]) == 0
        assert main(["view", "--rerun", dataset, "--save", str(out / "demo.rrd")]) == 0
        assert main(["stats", dataset, "--out", str(out / "stats")]) == 0
        printed = capsys.readouterr()
        outputs[where] = (printed.out.replace(str(out), "OUT"), printed.err, (out / "frame.png").read_bytes(),
                          (out / "stats" / "stats.md").read_text().replace(dataset, "DATASET"))
    assert outputs["store"] == outputs["disk"]
    assert "audit: 0 findings in 2 datasets" in outputs["disk"][1]
    assert "demo-0000: 7 transforms, 5 point clouds" in outputs["disk"][0]
    assert main(["view", uri]) == 1
    assert capsys.readouterr().err == (f"avdata: error: {uri}: Foxglove opens scene files on this machine; a dataset in "
                                       "an object store is viewed with --rerun (read by ranged requests)\n")


def test_eval_reads_a_unified_ground_truth_in_s3_as_on_disk(s3_server, local_dataset: Path, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:  # noqa: ANN001
    """The protocols whose GT is a unified dataset read it by URI; one reading its publisher's files refuses a URI."""
    import pyarrow.parquet as pq

    uri = upload(s3_server, local_dataset, "demo")
    objects = DatasetReader(local_dataset).objects()
    tracks = tmp_path / "tracks.parquet"  # the ground truth less one object's boxes: a table with FN, not all ones
    pq.write_table(objects.filter(np.asarray(objects["object_id"]) != objects["object_id"][0].as_py()), tracks)
    printed = {}
    for where, gt in (("disk", str(local_dataset)), ("store", uri)):
        assert main(["eval", "tracking", gt, str(tracks), "--protocol", "avdata"]) == 0
        assert main(["eval", "safety", gt, "--tracks", str(tracks)]) == 0
        printed[where] = capsys.readouterr()
    assert printed["store"].out == printed["disk"].out and printed["store"].err == printed["disk"].err
    # one of the two cars missing: DetA 0.5, AssA 1, HOTA sqrt(0.5), and its 5 boxes false negatives
    assert "| car | 0.7071 | 0.5000 | 1.0000 | 1.0000 | 0.5000 | 1.0000 | 0.6667 | 0 | 0 | 5 |" in printed["disk"].out
    assert main(["eval", "tracking", uri, str(tracks), "--protocol", "kitti"]) == 1
    assert capsys.readouterr().err == (f"avdata: error: {uri}: expected a local folder for --protocol kitti (it reads "
                                       "its publisher's files from disk); a unified dataset in a store is evaluated "
                                       "with --protocol avdata\n")
