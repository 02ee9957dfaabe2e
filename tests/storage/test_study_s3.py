"""``avdata study run`` into S3 (moto's standalone server on 127.0.0.1) against the same study run into a local folder:
the same results table, run results, trial datasets and report; a rerun that redoes only what is missing; one writer;
and a study of a dataset in the bucket, read in place.
"""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import yaml

from avdata.cli import main
from avdata.executors.store import store_lock
from avdata.storage import location
from tests.storage.conftest import SECRET, S3Server
from tests.storage.kitti_s3 import REPO, files, objects

STUDY = REPO / "tests" / "studies" / "small_study.yaml"
#: One trial of 3 frames of the small study: 4 runs, a few seconds.
SHORT = ("--trials", "1", "--frames", "3")


def _study(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    """``avdata study run ARGS`` in this process (the test's AWS_* environment): exit status, stdout, stderr."""
    capsys.readouterr()
    status = main(["study", "run", *args])
    found = capsys.readouterr()
    return status, found.out, found.err


def _without_times(found: dict[str, bytes]) -> dict[str, object]:
    """The study's files with each run result's stage times left out (wall times, never inputs) and the page left
    out (in a store it has no trial pictures); every other file as bytes."""
    return {name: ({k: v for k, v in json.loads(data).items() if k != "seconds"} if name.startswith("runs/") else data)
            for name, data in found.items() if name != "report.html"}


def _modified(server: S3Server, prefix: str) -> dict[str, object]:
    """Key -> last-modified time of every object under ``prefix`` (a rewrite changes it), folder markers left out."""
    listed = server.client().list_objects_v2(Bucket=server.bucket, Prefix=f"{prefix}/").get("Contents", [])
    return {item["Key"]: item["LastModified"] for item in listed if not item["Key"].endswith("/")}


def test_study_run_into_s3_equals_the_local_run_resumes_and_has_one_writer(
        s3_server: S3Server, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = f"{s3_server.uri}/study"
    local = _study(capsys, str(STUDY), str(tmp_path / "local"), *SHORT, "--quiet")
    remote = _study(capsys, str(STUDY), out, *SHORT, "--quiet")
    assert local[0] == 0 and remote[0] == 0, local[2] + remote[2]
    assert remote[1].replace(out, "OUT") == local[1].replace(str(tmp_path / "local"), "OUT")
    expected = files(tmp_path / "local")
    written = objects(s3_server, "study")
    assert sorted(written) == sorted(expected)  # no lock, no temporary key left
    assert sorted(name for name in expected if name.startswith("runs/")) == [
        f"runs/{case}__trial-0.json" for case in ("base", "deaf", "ideal", "slow")]
    assert "trials/trial-0/.study-fingerprint" in expected and "trials/trial-0/avdata.json" in expected
    # The same results table, run results, trial dataset and report, byte for byte.
    assert _without_times(written) == _without_times(expected)
    assert written["results.parquet"] == expected["results.parquet"]
    assert written["report.html"].startswith(b"<!DOCTYPE html>")
    before = _modified(s3_server, "study")
    # A rerun generates nothing and evaluates nothing: every trial object and run result is left as it is.
    rerun = _study(capsys, str(STUDY), out, *SHORT, "--no-report")
    assert rerun[0] == 0 and "study small: 0 trials generated, 1 kept" in rerun[1], rerun[2]
    after = _modified(s3_server, "study")
    kept = [key for key in before if key.startswith(("study/trials/", "study/runs/"))]
    assert kept and {key: after[key] for key in kept} == {key: before[key] for key in kept}
    # One run result lost: the rerun evaluates that run only, and the same result comes back.
    s3_server.client().delete_object(Bucket=s3_server.bucket, Key="study/runs/slow__trial-0.json")
    redone = _study(capsys, str(STUDY), out, *SHORT, "--no-report")
    assert redone[0] == 0 and "0 trials generated, 1 kept" in redone[1], redone[2]
    again = _modified(s3_server, "study")
    assert {key: again[key] for key in kept if key != "study/runs/slow__trial-0.json"} == {
        key: before[key] for key in kept if key != "study/runs/slow__trial-0.json"}
    assert _without_times(objects(s3_server, "study")) == _without_times(expected)
    # A second writer is refused in one line naming the holder; nothing is written meanwhile.
    with store_lock(location(out)):
        refused = _study(capsys, str(STUDY), out, *SHORT, "--quiet")
    assert refused[0] == 1 and refused[1] == ""
    assert refused[2].startswith(f"avdata: error: {out}: another avdata process (PID ")
    assert len(refused[2].splitlines()) == 1 and _modified(s3_server, "study") == again
    assert SECRET not in "".join(r[1] + r[2] for r in (remote, rerun, redone, refused))


def test_a_study_of_a_dataset_in_s3_equals_the_study_of_its_local_copy(
        s3_server: S3Server, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The dataset is read in place (ranged reads); OUT is in the bucket too."""
    generated = tmp_path / "gen"
    for dst in (str(generated), f"{s3_server.uri}/gen"):
        assert main(["generate", "--preset", "v2i-intersection", "--scenes", "1", "--frames", "3", "--quiet", dst]) == 0
    config = {"name": "given", "seed": 3, "evaluation": {"prediction_horizon_s": 0.2},
              "cases": [{"name": "ideal", "comm_range_m": 1000}, {"name": "base", "comm_range_m": None}]}
    for name, dataset in (("local", str(generated)), ("remote", f"{s3_server.uri}/gen")):
        (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump({**config, "dataset": dataset}))
    local = _study(capsys, str(tmp_path / "local.yaml"), str(tmp_path / "local"), "--quiet", "--no-report")
    remote = _study(capsys, str(tmp_path / "remote.yaml"), f"{s3_server.uri}/given", "--quiet", "--no-report")
    assert local[0] == 0 and remote[0] == 0, local[2] + remote[2]
    fetched = pq.read_table(pa.BufferReader(objects(s3_server, "given")["results.parquet"])).to_pylist()
    expected = pq.read_table(tmp_path / "local" / "results.parquet").to_pylist()
    # The rows differ only in their fingerprint (it names the dataset's path or URI) and so their checksum.
    differ = {"fingerprint", "checksum"}
    assert [{k: v for k, v in row.items() if k not in differ} for row in fetched] == [
        {k: v for k, v in row.items() if k not in differ} for row in expected]
    assert [row["case"] for row in fetched] == ["ideal", "base"] and fetched[0]["dataset"] == "gen"
    before = _modified(s3_server, "given")
    again = _study(capsys, str(tmp_path / "remote.yaml"), f"{s3_server.uri}/given", "--no-report")
    assert again[0] == 0 and "2 runs" in again[1], again[2]
    runs = [key for key in before if key.startswith("given/runs/")]
    assert len(runs) == 2 and {key: _modified(s3_server, "given")[key] for key in runs} == {key: before[key] for key in runs}
    # The report of a study in the bucket, as 'avdata study report OUT' writes it after the table.
    assert main(["study", "report", f"{s3_server.uri}/given"]) == 0
    assert capsys.readouterr().out == "".join(f"wrote {s3_server.uri}/given/{name}\n"
                                              for name in ("report.md", "report.csv", "report.html"))
    assert main(["study", "report", str(tmp_path / "local")]) == 0
    fetched_report = objects(s3_server, "given")
    for name in ("report.md", "report.csv"):  # report.md names the dataset: its URI, its local path
        shown = fetched_report[name].replace(f"{s3_server.uri}/gen".encode(), str(generated).encode())
        assert shown == (tmp_path / "local" / name).read_bytes()
    assert SECRET not in "".join(r[1] + r[2] for r in (remote, again)) + capsys.readouterr().err
