"""``avdata convert`` from and to S3 (moto's standalone server on 127.0.0.1), against a local conversion."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from avdata.errors import InputError
from tests.storage.conftest import SECRET, S3Server
from tests.storage.kitti_s3 import (
    KITTI_TRACKING,
    REPO,
    assert_second_writer_refused,
    avdata,
    convert_locally,
    files,
    objects,
    upload_kitti,
)


def test_kitti_object_s3_to_s3_with_two_local_workers_is_byte_identical(s3_server: S3Server, tmp_path: Path) -> None:
    src = upload_kitti(s3_server, tmp_path / "kitti")
    convert_locally("kitti-object", tmp_path / "kitti", tmp_path / "local", scene_size=1)
    remote = avdata("convert", "kitti-object", src, f"{s3_server.uri}/out", "--scene-size", "1", "--quiet",
                    "--executor", "local", "--workers", "2")
    assert remote.returncode == 0, remote.stderr
    assert "3 scenes written" in remote.stdout and remote.stdout.endswith(f"-> {s3_server.uri}/out\n")
    written = objects(s3_server, "out")
    assert written == files(tmp_path / "local")  # every key, every byte; no lock, no temporary key left
    assert SECRET not in remote.stdout + remote.stderr


def test_validate_checks_every_crc_over_the_network(s3_server: S3Server, tmp_path: Path) -> None:
    src = upload_kitti(s3_server, tmp_path / "kitti")
    convert_locally("kitti-object", src, f"{s3_server.uri}/out", scene_size=2)
    clean = avdata("validate", f"{s3_server.uri}/out")
    assert clean.returncode == 0 and clean.stdout == f"{s3_server.uri}/out: clean\n", clean.stderr
    client, key = s3_server.client(), "out/scenes/training_000000.mcap"
    data = bytearray(client.get_object(Bucket=s3_server.bucket, Key=key)["Body"].read())
    data[len(data) // 3] ^= 0x01  # one bit inside a chunk (a point cloud), far from the summary
    client.put_object(Bucket=s3_server.bucket, Key=key, Body=bytes(data))
    damaged = avdata("validate", f"{s3_server.uri}/out")
    assert damaged.returncode == 1 and "training_000000" in damaged.stdout and "CRC" in damaged.stdout, damaged.stdout
    assert f"{s3_server.uri}/out/scenes/training_000000.mcap" in damaged.stdout and "/tmp" not in damaged.stdout
    assert "training_000002" not in damaged.stdout and SECRET not in damaged.stdout + damaged.stderr


def test_a_failed_scene_is_redone_alone_and_leaves_no_stale_or_temporary_keys(s3_server: S3Server, tmp_path: Path) -> None:
    src = upload_kitti(s3_server, tmp_path / "kitti")
    convert = ("convert", "kitti-object", src, f"{s3_server.uri}/out", "--scene-size", "1", "--quiet")
    convert_locally("kitti-object", src, f"{s3_server.uri}/out", scene_size=1)
    client = s3_server.client()
    calib_key = "kitti/training/calib/000001.txt"
    calib = client.get_object(Bucket=s3_server.bucket, Key=calib_key)["Body"].read()
    # What a worker killed between its upload and its copy leaves behind, and one scene's damaged source.
    client.put_object(Bucket=s3_server.bucket, Key="out/scenes/.training_000001.mcap.4242.deadbeef.tmp", Body=b"partial")
    client.put_object(Bucket=s3_server.bucket, Key=calib_key, Body=calib.replace(b"P2:", b"P2: x"))
    failed = avdata(*convert)
    assert failed.returncode == 1 and "0 scenes written, 2 already complete, 1 failed" in failed.stdout, failed.stdout
    assert f"{src}/training/calib/000001.txt" in failed.stderr  # the one line names the object's URI
    after_failure = objects(s3_server, "out")
    assert sorted(k for k in after_failure if k.startswith("scenes/")) == [
        "scenes/training_000000.mcap", "scenes/training_000002.mcap"]  # the failed scene's old object is gone
    log = after_failure["errors.jsonl"].decode()
    assert f"{src}/training/calib/000001.txt" in log and SECRET not in log
    client.put_object(Bucket=s3_server.bucket, Key=calib_key, Body=calib)  # fixed: only that scene is redone
    fixed = avdata(*convert)
    assert fixed.returncode == 0 and "1 scenes written, 2 already complete, 0 failed" in fixed.stdout, fixed.stdout
    convert_locally("kitti-object", tmp_path / "kitti", tmp_path / "local", scene_size=1)
    assert objects(s3_server, "out") == files(tmp_path / "local")  # no temporary, stale or mixed key
    assert SECRET not in "".join(r.stdout + r.stderr for r in (failed, fixed))


def test_a_run_killed_in_the_middle_is_resumed_by_the_next(s3_server: S3Server, tmp_path: Path) -> None:
    src = upload_kitti(s3_server, tmp_path / "kitti", copies=5)  # 8 one-sample scenes
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    convert = [sys.executable, "-m", "avdata.cli", "convert", "kitti-object", src, f"{s3_server.uri}/out",
               "--scene-size", "1", "--quiet", "--workers", "2"]
    driver = subprocess.Popen(convert, env=env, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    client, deadline = s3_server.client(), time.monotonic() + 120

    def published() -> list[str]:
        listed = client.list_objects_v2(Bucket=s3_server.bucket, Prefix="out/scenes/").get("Contents", [])
        return [item["Key"] for item in listed if item["Key"].endswith(".mcap") and "/." not in item["Key"]]

    while len(published()) < 2 and driver.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    os.killpg(driver.pid, signal.SIGKILL)  # the driver and its workers, at once
    driver.wait()
    kept = published()
    assert driver.returncode == -signal.SIGKILL and 2 <= len(kept) < 8, kept
    assert "out/avdata.json" not in objects(s3_server, "out")  # the manifest comes last
    rerun = avdata(*convert[3:])  # takes over the dead driver's lock, deletes its temporary keys
    assert rerun.returncode == 0, rerun.stderr
    assert f"{8 - len(kept)} scenes written, {len(kept)} already complete, 0 failed" in rerun.stdout
    convert_locally("kitti-object", tmp_path / "kitti", tmp_path / "local", scene_size=1)
    assert objects(s3_server, "out") == files(tmp_path / "local")


def test_two_writers_one_is_refused(s3_server: S3Server, tmp_path: Path) -> None:
    from avdata.executors.store import create_exclusively
    from avdata.storage import location

    src = upload_kitti(s3_server, tmp_path / "kitti")
    out = location(f"{s3_server.uri}/out")
    assert create_exclusively(out / "probe", "a") and not create_exclusively(out / "probe", "b")  # If-None-Match: *
    assert (out / "probe").read_bytes() == b"a"
    assert_second_writer_refused(src, out, SECRET)
    assert not (out / "scenes").exists() and not (out / ".avdata.lock").exists()  # released at the end
    # A lock left by a killed run of this host (its PID gone) is taken over.
    gone = subprocess.Popen(["true"])
    gone.wait()
    (out / ".avdata.lock").write_bytes(json.dumps({"host": socket.gethostname(), "pid": gone.pid, "token": "x"}).encode())
    convert_locally("kitti-object", src, str(out))
    assert (out / "avdata.json").is_file() and not (out / ".avdata.lock").exists()


def test_kitti_object_s3_to_s3_on_ray_is_byte_identical(s3_server: S3Server, tmp_path: Path) -> None:
    pytest.importorskip("ray")
    src = upload_kitti(s3_server, tmp_path / "kitti")
    convert_locally("kitti-object", tmp_path / "kitti", tmp_path / "local", scene_size=1)
    remote = avdata("convert", "kitti-object", src, f"{s3_server.uri}/out", "--scene-size", "1", "--quiet",
                    "--executor", "ray", "--workers", "2")
    assert remote.returncode == 0, remote.stderr
    assert objects(s3_server, "out") == files(tmp_path / "local")
    assert SECRET not in remote.stdout + remote.stderr


def test_the_driver_holds_one_scene_at_a_time_on_its_disk(s3_server: S3Server, tmp_path: Path,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """Tasks publish from their own folders; the index is built from the scene objects fetched one by one."""
    from avdata.executors.store import StoreScenes

    src = upload_kitti(s3_server, tmp_path / "kitti")
    fetched = StoreScenes.fetched
    on_disk: list[list[str]] = []

    @contextlib.contextmanager
    def counting(self: StoreScenes, name: str) -> Iterator[Path]:
        with fetched(self, name) as path:
            on_disk.append(sorted(p.name for p in self.staging.rglob("*.mcap")))
            yield path

    monkeypatch.setattr(StoreScenes, "fetched", counting)
    convert_locally("kitti-object", src, f"{s3_server.uri}/out", scene_size=1)  # one worker: this process
    assert on_disk == [[f"training_00000{i}.mcap"] for i in range(3)]
    convert_locally("kitti-object", tmp_path / "kitti", tmp_path / "local", scene_size=1)
    assert objects(s3_server, "out") == files(tmp_path / "local")


def test_kitti_tracking_s3_to_s3_is_byte_identical(s3_server: S3Server, tmp_path: Path) -> None:
    src = upload_kitti(s3_server, tmp_path / "tracking", prefix="tracking", source=KITTI_TRACKING)
    local = avdata("convert", "kitti-tracking", str(tmp_path / "tracking"), str(tmp_path / "local"), "--quiet")
    remote = avdata("convert", "kitti-tracking", src, f"{s3_server.uri}/out", "--quiet")
    assert remote.returncode == local.returncode and remote.stdout.replace(f"{s3_server.uri}/out", "DST") == \
        local.stdout.replace(str(tmp_path / "local"), "DST"), remote.stderr
    assert remote.stderr.replace(src, "SRC") == local.stderr.replace(str(tmp_path / "tracking"), "SRC")
    written, expected = objects(s3_server, "out"), files(tmp_path / "local")
    # errors.jsonl names each problem's file: the object's URI, or the local path
    assert written.pop("errors.jsonl").replace(src.encode(), b"SRC") == \
        expected.pop("errors.jsonl").replace(str(tmp_path / "tracking").encode(), b"SRC")
    assert written == expected


def test_a_converter_reading_local_folders_only_refuses_a_store_source(s3_server: S3Server, tmp_path: Path) -> None:
    """Every converter reads SRC from a store; one that would not (``reads_stores`` False) is refused at once."""
    from avdata.converters.base import ConvertConfig, converter_class
    from avdata.storage import path_or_location

    class LocalOnly(converter_class("kitti-raw")):  # type: ignore[misc]  # a base chosen at run time
        reads_stores = False

    src = f"{s3_server.uri}/raw"
    with pytest.raises(InputError) as refused:
        LocalOnly(ConvertConfig(src=path_or_location(src), dst=tmp_path / "out", quiet=True))
    assert str(refused.value) == (f"{src}: kitti-raw reads its source from a local folder only (from an object store: "
                                  "argoverse2, dair-v2x, kitti-object, kitti-raw, kitti-tracking, nuscenes, opv2v, "
                                  "waymo); copy it to a disk first")
