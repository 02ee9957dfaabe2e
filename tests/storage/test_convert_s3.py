"""``avdata convert`` from and to S3 (moto's standalone server on 127.0.0.1), against a local conversion."""

from __future__ import annotations

from pathlib import Path

from tests.storage.conftest import SECRET, S3Server
from tests.storage.kitti_s3 import avdata, files, objects, upload_kitti


def test_kitti_object_s3_to_s3_with_two_local_workers_is_byte_identical(s3_server: S3Server, tmp_path: Path) -> None:
    src = upload_kitti(s3_server, tmp_path / "kitti")
    local = avdata("convert", "kitti-object", str(tmp_path / "kitti"), str(tmp_path / "local"), "--scene-size", "1", "--quiet")
    assert local.returncode == 0, local.stderr
    remote = avdata("convert", "kitti-object", src, f"{s3_server.uri}/out", "--scene-size", "1", "--quiet",
                    "--executor", "local", "--workers", "2")
    assert remote.returncode == 0, remote.stderr
    assert "3 scenes written" in remote.stdout and remote.stdout.endswith(f"-> {s3_server.uri}/out\n")
    written = objects(s3_server, "out")
    assert written == files(tmp_path / "local")  # every key, every byte; no lock, no temporary key left
    assert SECRET not in remote.stdout + remote.stderr


def test_validate_checks_every_crc_over_the_network(s3_server: S3Server, tmp_path: Path) -> None:
    src = upload_kitti(s3_server, tmp_path / "kitti")
    assert avdata("convert", "kitti-object", src, f"{s3_server.uri}/out", "--scene-size", "2", "--quiet").returncode == 0
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
