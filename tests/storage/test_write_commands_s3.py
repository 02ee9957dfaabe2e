"""``generate``, ``export`` and ``track`` into S3 (moto's standalone server on 127.0.0.1), against the same run into a
local folder: the same bytes, resume that redoes only what is missing, one writer; ``demo`` and ``index`` refused in one line, and
what a study cannot read from a store (``study run`` into S3: tests/storage/test_study_s3.py).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from avdata.executors.store import store_lock
from avdata.storage import location
from tests.exporters.export_files import export_digest
from tests.realdata import REALDATA
from tests.storage.conftest import SECRET, S3Server
from tests.storage.kitti_s3 import KITTI_OBJECT, KITTI_TRACKING, avdata, convert_locally, files, objects

GENERATE = ("--preset", "v2i-intersection", "--frames", "2")
STATE = ".avdata-export/"


def test_generate_to_s3_is_byte_identical_resumes_and_has_one_writer(s3_server: S3Server, tmp_path: Path) -> None:
    out = f"{s3_server.uri}/gen"
    local = avdata("generate", *GENERATE, "--scenes", "2", str(tmp_path / "local"))
    remote = avdata("generate", *GENERATE, "--scenes", "2", out, "--workers", "2")
    assert local.returncode == 0 and remote.returncode == 0, local.stderr + remote.stderr
    assert remote.stdout == f"generate: 2 scenes written, 0 already complete, 0 failed -> {out}\n"
    expected = files(tmp_path / "local")
    assert objects(s3_server, "gen") == expected  # every key, every byte; no lock, no temporary key left
    scenes = sorted(key for key in expected if key.startswith("scenes/"))
    assert len(scenes) == 2
    # A lost scene object: the rerun writes that scene only, and the index and manifest again.
    s3_server.client().delete_object(Bucket=s3_server.bucket, Key=f"gen/{scenes[1]}")
    rerun = avdata("generate", *GENERATE, "--scenes", "2", out)
    assert rerun.stdout == f"generate: 1 scenes written, 1 already complete, 0 failed -> {out}\n", rerun.stderr
    assert objects(s3_server, "gen") == expected
    # A second writer is refused in one line naming the holder; nothing is written meanwhile.
    with store_lock(location(out)):
        refused = avdata("generate", *GENERATE, "--scenes", "2", out)
    assert refused.returncode == 1 and refused.stdout == ""
    assert refused.stderr.startswith(f"avdata: error: {out}: another avdata process (PID {os.getpid()} on host ")
    assert len(refused.stderr.splitlines()) == 1 and objects(s3_server, "gen") == expected
    # Fewer scenes: the other scene's object is removed as stale, and the index follows.
    fewer = avdata("generate", *GENERATE, "--scenes", "1", out)
    assert fewer.stdout == f"generate: 1 scenes written, 0 already complete, 0 failed, 1 stale scenes removed -> {out}\n"
    assert sorted(key for key in objects(s3_server, "gen") if key.startswith("scenes/")) == scenes[:1]
    assert SECRET not in "".join(r.stdout + r.stderr for r in (remote, rerun, refused, fewer))


def _without_state(found: dict[str, bytes], dataset: str) -> dict[str, bytes]:
    """An export's files without its resume markers and run state (they hold times and the dataset's path),
    with the dataset's path or URI replaced in ``avdata_export.json``."""
    return {name: data.replace(dataset.encode(), b"<DATASET>") for name, data in found.items()
            if not name.startswith(STATE)}


@pytest.fixture
def kitti_datasets(s3_server: S3Server, tmp_path: Path) -> tuple[Path, str]:
    """The real KITTI object samples converted one scene per sample, into a local folder and into the bucket."""
    convert_locally("kitti-object", KITTI_OBJECT, tmp_path / "ds", scene_size=1)
    convert_locally("kitti-object", KITTI_OBJECT, f"{s3_server.uri}/ds", scene_size=1)
    return tmp_path / "ds", f"{s3_server.uri}/ds"


def test_kitti_export_from_s3_to_s3_equals_the_local_export_and_resumes(s3_server: S3Server, tmp_path: Path,
                                                                        kitti_datasets: tuple[Path, str]) -> None:
    local_ds, remote_ds = kitti_datasets
    out = f"{s3_server.uri}/kitti"
    local = avdata("export", "kitti-object", str(local_ds), str(tmp_path / "kitti"), "--quiet")
    remote = avdata("export", "kitti-object", remote_ds, out, "--quiet", "--workers", "2")
    assert local.returncode == 0 and remote.returncode == 0, local.stderr + remote.stderr
    assert remote.stdout.replace(out, "DST") == local.stdout.replace(str(tmp_path / "kitti"), "DST")
    expected = _without_state(files(tmp_path / "kitti"), str(local_ds))
    written = objects(s3_server, "kitti")
    assert _without_state(written, remote_ds) == expected  # every exported file, byte for byte
    assert sorted(name for name in written if name.startswith(STATE)) == [
        f"{STATE}export.json", *(f"{STATE}scenes/training_00000{i}.json" for i in range(3))]
    assert json.loads(written[f"{STATE}export.json"])["dataset"] == remote_ds
    again = avdata("export", "kitti-object", remote_ds, out, "--quiet")
    assert "0 scenes written, 3 already complete, 0 failed" in again.stdout, again.stderr
    # One exported object lost: its scene is written again, the two others are kept.
    s3_server.client().delete_object(Bucket=s3_server.bucket, Key="kitti/training/velodyne/000001.bin")
    redone = avdata("export", "kitti-object", remote_ds, out, "--quiet")
    assert "1 scenes written, 2 already complete, 0 failed" in redone.stdout, redone.stderr
    assert _without_state(objects(s3_server, "kitti"), remote_ds) == expected
    with store_lock(location(out)):
        refused = avdata("export", "kitti-object", remote_ds, out, "--quiet")
    assert refused.returncode == 1 and refused.stderr.startswith(f"avdata: error: {out}: another avdata process")
    assert SECRET not in "".join(r.stdout + r.stderr for r in (remote, again, redone, refused))


def test_nuscenes_export_from_s3_to_s3_equals_the_local_export(s3_server: S3Server, tmp_path: Path,
                                                               kitti_datasets: tuple[Path, str]) -> None:
    local_ds, remote_ds = kitti_datasets
    local = avdata("export", "nuscenes", str(local_ds), str(tmp_path / "nusc"), "--quiet")
    remote = avdata("export", "nuscenes", remote_ds, f"{s3_server.uri}/nusc", "--quiet")
    assert local.returncode == 0 and remote.returncode == 0, local.stderr + remote.stderr
    fetched = tmp_path / "fetched"
    for name, data in objects(s3_server, "nusc").items():
        (fetched / name).parent.mkdir(parents=True, exist_ok=True)
        (fetched / name).write_bytes(data)
    # The tables name the dataset (scene descriptions, the map token): export_digest puts placeholders there.
    assert export_digest(fetched, remote_ds) == export_digest(tmp_path / "nusc", local_ds)  # type: ignore[arg-type]  # a URI, used as text


def test_a_store_export_refuses_a_prefix_holding_other_files(s3_server: S3Server, kitti_datasets: tuple[Path, str]) -> None:
    _, remote_ds = kitti_datasets
    s3_server.client().put_object(Bucket=s3_server.bucket, Key="theirs/notes.txt", Body=b"not an export")
    refused = avdata("export", "kitti-object", remote_ds, f"{s3_server.uri}/theirs", "--quiet")
    assert refused.returncode == 1 and refused.stderr == (
        f"avdata: error: {s3_server.uri}/theirs: expected an empty folder or an earlier avdata export, got a folder "
        "holding notes.txt (write into another folder)\n")
    into_itself = avdata("export", "kitti-object", remote_ds, remote_ds, "--quiet")
    assert into_itself.returncode == 1 and "expected an output outside DATASET, got DATASET itself" in into_itself.stderr


def test_a_store_export_refuses_an_object_as_its_folder(s3_server: S3Server, kitti_datasets: tuple[Path, str]) -> None:
    # the dataset's manifest key was taken as a prefix: exit 0, the export's keys written under avdata.json/
    _, remote_ds = kitti_datasets
    before = objects(s3_server, "ds")
    s3_server.client().put_object(Bucket=s3_server.bucket, Key="an-object.json", Body=b"{}")
    refused = avdata("export", "kitti-object", remote_ds, f"{s3_server.uri}/an-object.json", "--quiet")
    assert refused.returncode == 1 and refused.stderr == (
        f"avdata: error: {s3_server.uri}/an-object.json: expected a folder (prefix) to write into, got an object\n")
    inside = avdata("export", "kitti-object", remote_ds, f"{remote_ds}/avdata.json", "--quiet")
    assert inside.returncode == 1 and inside.stderr == (
        f"avdata: error: {remote_ds}/avdata.json: expected an output outside DATASET, got a path inside DATASET "
        f"{remote_ds}\n")
    assert objects(s3_server, "ds") == before


DETECTIONS = REALDATA / "kitti_tracking_detections"


def _tracking_source(root: Path) -> Path:
    """KITTI tracking sequence 0006 (its calibration, labels and no oxts), as tests/perception/test_track_cli.py builds it."""
    src = root / "training"
    for folder in ("calib", "label_02"):
        (src / folder).mkdir(parents=True)
    (src / "calib" / "0006.txt").symlink_to(DETECTIONS / "calib_object_keys" / "0006.txt")
    (src / "label_02" / "0006.txt").symlink_to(DETECTIONS / "label_02" / "0006.txt")
    assert KITTI_TRACKING.is_dir()
    return root


@pytest.mark.parametrize("output_format", ["kitti", "unified"])
def test_track_from_s3_to_s3_equals_the_local_run(s3_server: S3Server, tmp_path: Path, output_format: str) -> None:
    src = _tracking_source(tmp_path / "src")
    convert_locally("kitti-tracking", src, tmp_path / "ds")
    convert_locally("kitti-tracking", src, f"{s3_server.uri}/ds")
    options = ("--detections", str(DETECTIONS / "pointrcnn_Car_val" / "0006.txt"), "--format", "ab3dmot",
               "--output-format", output_format, "--quiet")
    out = f"{s3_server.uri}/tracks"
    local = avdata("track", str(tmp_path / "ds"), str(tmp_path / "tracks"), *options)
    remote = avdata("track", f"{s3_server.uri}/ds", out, *options)
    assert local.returncode == 0 and remote.returncode == 0, local.stderr + remote.stderr
    assert remote.stdout.replace(out, "OUT") == local.stdout.replace(str(tmp_path / "tracks"), "OUT")
    expected = files(tmp_path / "tracks")
    assert objects(s3_server, "tracks") == expected
    assert sorted(expected) == (["0006.txt"] if output_format == "kitti" else
                                [".avdata-track/training_0006.json", "tracks.parquet"])
    again = avdata("track", f"{s3_server.uri}/ds", out, *options)
    assert "0 scenes tracked, 1 already complete, 0 failed" in again.stdout, again.stderr
    assert objects(s3_server, "tracks") == expected
    assert SECRET not in "".join(r.stdout + r.stderr for r in (remote, again))


@pytest.mark.parametrize("command", ["demo", "index"])
def test_demo_and_index_refuse_a_uri_in_one_line(s3_server: S3Server, command: str) -> None:
    refused = avdata(command, f"{s3_server.uri}/{command}")
    assert refused.returncode == 1 and refused.stdout == ""
    assert refused.stderr == (f"avdata: error: {s3_server.uri}/{command}: expected a local folder (convert, generate, "
                              "export, track and study run write to object stores; demo and index write local folders "
                              "only)\n")
    assert objects(s3_server, command) == {}


@pytest.mark.parametrize("key", ["dataset", "datasets[0].path"])
def test_a_study_dataset_missing_from_the_store_is_one_line(s3_server: S3Server, key: str) -> None:
    """A study reads its datasets in a store in place (tests/storage/test_study_s3.py); a prefix without one is refused."""
    from avdata.errors import InputError
    from avdata.studies.config import study_from_dict

    uri = f"{s3_server.uri}/unified"
    datasets = {"dataset": uri} if key == "dataset" else {"datasets": [{"name": "kitti", "path": uri}]}
    with pytest.raises(InputError) as refused:
        study_from_dict({"name": "s", "cases": [{"name": "a"}], **datasets}, "study.yaml")
    assert str(refused.value) == f"study.yaml: expected {key} to be a unified dataset folder, got {uri!r}"


@pytest.mark.parametrize("detector", [{"kind": "files", "path": "s3://bucket/dets", "format": "ab3dmot"},
                                      {"kind": "model", "callable": "pkg.mod:make", "checkpoint": "s3://bucket/dets"}])
def test_a_study_detector_file_in_a_store_is_refused_in_one_line(detector: dict[str, str]) -> None:
    from avdata.errors import InputError
    from avdata.studies.config import study_from_dict

    key = "path" if "path" in detector else "checkpoint"
    with pytest.raises(InputError) as refused:
        study_from_dict({"name": "s", "cases": [{"name": "a", "detector": detector}]}, "study.yaml")
    assert str(refused.value) == (
        f"study.yaml: cases[0]: detector.{key}: expected a local file or folder, got the object store URI "
        "'s3://bucket/dets' (detections and checkpoints are read from local files; copy them to a disk)")
