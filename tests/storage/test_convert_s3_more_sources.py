"""``avdata convert`` of OPV2V / V2XSet / V2V4Real, DAIR-V2X and KITTI raw sources read from S3 (moto's server on 127.0.0.1).

The real sample files (and folders built around them) are uploaded to the bucket at test time, with a local twin
of the same files and modification times; the conversion from the bucket must write the same bytes as the local
one, with the same problems (their files named relative to SRC). A damaged object costs what a damaged file
costs, in one line naming the object's URI.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.converters.opv2v_fixtures import build_opv2v, build_v2v4real
from tests.converters.test_dair_v2x import build_dair
from tests.converters.test_kitti_raw import TRACKLETS, assemble_drive
from tests.realdata import REALDATA
from tests.storage.conftest import SECRET, S3Server
from tests.storage.kitti_s3 import avdata
from tests.storage.sources_s3 import convert_locally_and_from_s3, rewrite_object, same_dataset, upload_tree

V2XSET = REALDATA / "v2xset"  # one real frame file alone: no cloud, no image
DAIR_V2X = REALDATA / "dair_v2x"
KITTI_RAW = REALDATA / "kitti" / "raw"


@pytest.fixture
def opv2v_src(s3_server: S3Server, tmp_path: Path) -> tuple[str, Path]:
    """A V2XSet scenario built around the real frame file (its ego's first frame; ASCII, binary and compressed
    PCDs, PNGs, an RSU) and a V2V4Real scenario, in the bucket and in a local twin."""
    built = tmp_path / "built"
    build_opv2v(built, n_points=200)
    build_v2v4real(built)
    return upload_tree(s3_server, built, tmp_path / "opv2v", "opv2v"), tmp_path / "opv2v"


def test_opv2v_from_s3_is_byte_identical(s3_server: S3Server, opv2v_src: tuple[str, Path], tmp_path: Path,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    src, twin = opv2v_src
    local, remote, traffic = convert_locally_and_from_s3("opv2v", s3_server, twin, src, tmp_path, monkeypatch)
    assert remote == local == []
    assert same_dataset(tmp_path / "remote", src, tmp_path / "local", twin)  # every file, every byte
    assert traffic.requests.get("GET", 0) > 0
    print(f"opv2v from S3: {traffic.requests} requests, {traffic.get_bytes} bytes")


def test_a_bad_frame_object_is_one_line_naming_its_uri(s3_server: S3Server, tmp_path: Path) -> None:
    src = upload_tree(s3_server, V2XSET, tmp_path / "twin", "opv2v")
    key = "opv2v/validate/2021_08_21_17_30_41/4279/000069.yaml"
    rewrite_object(s3_server, key, lambda data: data.replace(b"lidar_pose:", b"lidar_pose: [1, x]\nold:", 1))
    result = avdata("convert", "opv2v", src, str(tmp_path / "out"), "--quiet")
    errors = [line for line in result.stderr.splitlines() if line.startswith("error: ")]
    # the frame file's record, then its consequence: the scenario's only vehicle agent has no frame left
    assert result.returncode != 0 and len(errors) == 2, result.stderr
    assert f"{s3_server.uri}/{key}: field lidar_pose: expected numbers, got [1, 'x']" in errors[0], result.stderr
    assert errors[1].endswith("expected at least one vehicle agent folder with frame files, got none")
    assert "Traceback" not in result.stderr and SECRET not in result.stdout + result.stderr


def test_dair_v2x_from_s3_fails_as_locally(s3_server: S3Server, tmp_path: Path) -> None:
    """The real sample has no calib folders: its pair fails on disk and in a bucket alike, in the same records."""
    src, twin = upload_tree(s3_server, DAIR_V2X, tmp_path / "dair", "dair"), tmp_path / "dair"
    local = avdata("convert", "dair-v2x", str(twin), str(tmp_path / "local"), "--quiet")
    remote = avdata("convert", "dair-v2x", src, str(tmp_path / "remote"), "--quiet")
    assert local.returncode == remote.returncode != 0, (local.stderr, remote.stderr)
    assert remote.stderr.replace(src, "SRC") == local.stderr.replace(str(twin), "SRC")
    assert "lidar_to_novatel" in remote.stderr and "Traceback" not in remote.stderr
    assert (tmp_path / "remote" / "errors.jsonl").is_file()
    assert same_dataset(tmp_path / "remote", src, tmp_path / "local", twin)  # errors.jsonl and manifest alike


def test_a_whole_dair_v2x_pair_from_s3_is_byte_identical(s3_server: S3Server, tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """The official layout around the real sweeps and labels (calibrations, images, data_info as the devkit's)."""
    build_dair(tmp_path / "built", skew=2e-5)
    src, twin = upload_tree(s3_server, tmp_path / "built", tmp_path / "dair", "dair"), tmp_path / "dair"
    local, remote, traffic = convert_locally_and_from_s3("dair-v2x", s3_server, twin, src, tmp_path, monkeypatch)
    assert remote == local and any("not orthonormal" in line for line in local)
    assert same_dataset(tmp_path / "remote", src, tmp_path / "local", twin)  # every file, every byte
    print(f"dair-v2x from S3: {traffic.requests} requests, {traffic.get_bytes} bytes")


def test_a_truncated_dair_v2x_json_object_is_one_line_naming_its_uri(s3_server: S3Server, tmp_path: Path) -> None:
    src = upload_tree(s3_server, DAIR_V2X, tmp_path / "dair", "dair")
    key = "dair/cooperative/selected_data_info.json"
    rewrite_object(s3_server, key, lambda data: data[: len(data) // 2])
    result = avdata("convert", "dair-v2x", src, str(tmp_path / "out"), "--quiet")
    assert result.returncode != 0 and len(result.stderr.splitlines()) == 1, result.stderr
    assert f"{s3_server.uri}/{key}: malformed JSON (" in result.stderr and "Traceback" not in result.stderr
    assert SECRET not in result.stdout + result.stderr


def test_kitti_raw_from_s3_is_byte_identical(s3_server: S3Server, tmp_path: Path,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """The real day's calibrations and timestamps, with real tracking oxts packets, sweeps and images, and tracklets;
    12 of the 108 timed packets (fewer requests), so that frames 12.. are skipped as they are on disk."""
    drive = assemble_drive(tmp_path / "built", n_frames=12)
    (drive / "tracklet_labels.xml").write_text(TRACKLETS)
    src, twin = upload_tree(s3_server, tmp_path / "built", tmp_path / "raw", "raw"), tmp_path / "raw"
    local, remote, traffic = convert_locally_and_from_s3("kitti-raw", s3_server, twin, src, tmp_path, monkeypatch)
    assert remote == local and any("oxts packet missing" in line for line in local)
    assert same_dataset(tmp_path / "remote", src, tmp_path / "local", twin)  # every file, every byte
    print(f"kitti-raw from S3: {traffic.requests} requests, {traffic.get_bytes} bytes")


def test_a_bad_kitti_raw_calibration_object_is_one_line_naming_its_uri(s3_server: S3Server, tmp_path: Path) -> None:
    src = upload_tree(s3_server, KITTI_RAW, tmp_path / "raw", "raw")
    key = "raw/2011_09_26/calib_velo_to_cam.txt"
    rewrite_object(s3_server, key, lambda data: re.sub(rb"T: \S+", b"T: 1e999x", data, count=1))
    result = avdata("convert", "kitti-raw", src, str(tmp_path / "out"), "--quiet")
    errors = [line for line in result.stderr.splitlines() if line.startswith("error: ")]
    assert result.returncode != 0 and len(errors) == 1, result.stderr
    assert f"{s3_server.uri}/{key}: " in errors[0] and "1e999x" in errors[0], result.stderr
    assert "Traceback" not in result.stderr and SECRET not in result.stdout + result.stderr
