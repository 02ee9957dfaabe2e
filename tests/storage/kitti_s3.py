"""Helpers of the object-store tests: KITTI object's real frames in a bucket, a local twin, the CLI, and the checks
every store's tests make (items read back, the second writer's refusal)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from avdata.errors import InputError
from avdata.storage import Location
from tests.realdata import REALDATA
from tests.storage.conftest import S3Server

KITTI_OBJECT = REALDATA / "kitti" / "object"
KITTI_TRACKING = REALDATA / "kitti" / "tracking"
REPO = Path(__file__).resolve().parents[2]


def upload_kitti(server: S3Server, twin: Path, prefix: str = "kitti", source: Path = KITTI_OBJECT, copies: int = 0) -> str:
    """Uploads real KITTI files (``source``) to ``s3://bucket/<prefix>`` and copies them to the local folder ``twin``.

    Each local copy gets its object's last-modified time: the source fingerprint records large files' mtimes, so the
    two conversions see the same source identity and must write the same bytes. ``copies`` more KITTI object samples
    (ids 3, 4, ...) repeat the three real ones, for a run long enough to be killed in the middle.
    """
    client = server.client()
    shutil.copytree(source, twin)
    for sample in range(3, 3 + copies):
        for real in sorted((twin / "training").glob(f"*/{sample % 3:06d}.*")):
            shutil.copyfile(real, real.with_name(f"{sample:06d}{real.suffix}"))
    for path in sorted(p for p in twin.rglob("*") if p.is_file()):
        key = f"{prefix}/{path.relative_to(twin).as_posix()}"
        client.put_object(Bucket=server.bucket, Key=key, Body=path.read_bytes())
        modified = client.head_object(Bucket=server.bucket, Key=key)["LastModified"].timestamp()
        os.utime(path, ns=(int(modified * 1e9), int(modified * 1e9)))
    return f"{server.uri}/{prefix}"


def objects(server: S3Server, prefix: str) -> dict[str, bytes]:
    """Key (relative to ``prefix``) -> bytes of every object under it but folder markers.

    pyarrow keeps a folder whose last object it deletes as an empty ``folder/`` marker object (its S3 folders);
    they are checked to be empty and left out, as ``files`` leaves folders out.
    """
    client = server.client()
    listed = client.list_objects_v2(Bucket=server.bucket, Prefix=f"{prefix}/").get("Contents", [])
    found = {item["Key"][len(prefix) + 1:]: client.get_object(Bucket=server.bucket, Key=item["Key"])["Body"].read()
             for item in listed}
    assert all(not data for key, data in found.items() if key.endswith("/") or not key)
    return {key: data for key, data in found.items() if key and not key.endswith("/")}


def files(root: Path) -> dict[str, bytes]:
    """Relative path -> bytes of every file under ``root`` except the local writer lock."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in root.rglob("*")
            if p.is_file() and p.name != ".avdata.lock"}


def avdata(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    """``avdata ARGS`` in a subprocess with this environment (the test's AWS_* variables)."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run([sys.executable, "-m", "avdata.cli", *args], capture_output=True, text=True, env=env,
                          timeout=timeout, check=False)


def convert_locally(name: str, src: Path | str, dst: Path | str, **options: object) -> None:
    """``avdata convert NAME SRC DST`` in this process (paths or URIs): the reference, or a test's starting point."""
    from avdata.converters.base import ConvertConfig, converter_class, run_conversion
    from avdata.storage import path_or_location

    cls = converter_class(name)
    result = run_conversion(cls(ConvertConfig(src=path_or_location(src), dst=path_or_location(dst), quiet=True,
                                              options=options)))
    assert not result.failed and not result.n_errors


def assert_items_equal(remote: dict, local: dict) -> None:
    """Two ``FrameDataset`` items hold the same keys, and equal tensors (dtype included), arrays and values."""
    assert remote.keys() == local.keys()
    for key, value in local.items():
        if isinstance(value, dict):
            assert_items_equal(remote[key], value)
        elif isinstance(value, torch.Tensor):
            assert remote[key].dtype == value.dtype and torch.equal(remote[key], value), key
        elif isinstance(value, np.ndarray):
            np.testing.assert_array_equal(remote[key], value)
        else:
            assert remote[key] == value, key


def assert_second_writer_refused(src: str, out: Location, secret: str) -> None:
    """While this process holds ``out``'s lock, a conversion into ``out`` and a second lock are refused in one line
    naming this process, printing no ``secret``; the lock is released when the holder ends."""
    from avdata.executors.store import store_lock

    with store_lock(out):  # this (live) process writes the dataset
        refused = avdata("convert", "kitti-object", src, str(out), "--quiet")
        with pytest.raises(InputError, match="another avdata process"):
            with store_lock(out):
                pass
    assert refused.returncode != 0 and refused.stdout == ""
    assert refused.stderr.startswith(f"avdata: error: {out}: another avdata process (PID {os.getpid()} on host ")
    assert len(refused.stderr.splitlines()) == 1 and secret not in refused.stderr
