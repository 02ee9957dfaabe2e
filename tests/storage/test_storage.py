"""avdata.storage: URIs, the options each store's filesystem gets from the environment, credentials kept out."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pyarrow.fs as pafs
import pytest

from avdata.errors import InputError, OutputError
from avdata.executors import store
from avdata.storage import gcs_options, is_remote, location, path_or_location, s3_options, scrub
from tests.storage.conftest import SECRET


def test_local_paths_and_file_uris_stay_paths(tmp_path: Path) -> None:
    assert path_or_location(str(tmp_path / "a")) == tmp_path / "a"
    assert path_or_location(f"file://{tmp_path}/a") == tmp_path / "a"
    loc = location(tmp_path / "a")
    assert loc.is_local and loc.local_path == tmp_path / "a" and loc.name == "a"
    assert not is_remote(str(tmp_path)) and not is_remote("relative/path")


def test_store_uris_parse_into_bucket_and_key(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("AWS_REGION", "eu-west-1")
    loc = location("s3://bucket//prefix/scenes/")
    assert (loc.path, loc.uri, loc.bucket, loc.scheme) == ("bucket/prefix/scenes", "s3://bucket/prefix/scenes", "bucket", "s3")
    assert (loc / "a.mcap").uri == "s3://bucket/prefix/scenes/a.mcap"
    assert loc.join("x/y", "z.txt").uri == "s3://bucket/prefix/scenes/x/y/z.txt"
    assert (loc / "a.mcap").parent == loc and (loc / "a.mcap").suffix == ".mcap" and (loc / "a.mcap").stem == "a"
    assert location("s3://bucket").parent.uri == "s3://bucket"
    assert is_remote("s3://b/k") and is_remote("GS://b/k") and is_remote(loc)
    # one filesystem per (scheme, bucket) per process
    assert location("s3://bucket/other").fs is loc.fs and location("s3://other").fs is not loc.fs
    # a Location travels to a worker as its URI: no filesystem (and no credential) in the pickle
    assert pickle.loads(pickle.dumps(loc)) == loc and b"eu-west-1" not in pickle.dumps(loc)


@pytest.mark.parametrize(("uri", "message"), [
    ("s3://", "expected s3://BUCKET/PREFIX, got no bucket"),
    ("ftp://host/x", "got scheme 'ftp'"),
    ("hdfs://nn/x", "got scheme 'hdfs'"),
    # The store client resolved them: s3://b/x/../d read the dataset at s3://b/d.
    ("s3://b/x/../d", r"s3://b/x/\.\./d: expected a URI without '\.' or '\.\.' segments"),
    ("gs://b/./d", r"gs://b/\./d: expected a URI without '\.' or '\.\.' segments"),
])
def test_bad_uris_are_one_line(uri: str, message: str) -> None:
    with pytest.raises(InputError, match=message):
        location(uri)


@pytest.mark.parametrize(("uri", "bad"), [("s3://bucket/d\x00", "'\\x00'"), ("gs://bucket/a\nb", "'\\n'"),
                                          ("s3://bucket/d\x7f/x", "'\\x7f'")])
def test_control_characters_in_a_store_uri_are_refused(uri: str, bad: str) -> None:
    with pytest.raises(InputError) as caught:
        location(uri)
    assert str(caught.value) == f"{uri!r}: expected a URI without control characters, got {bad}"


def test_a_nul_does_not_read_the_key_before_it(s3_server, tmp_path: Path,  # noqa: ANN001 - fixture
                                               capsys: pytest.CaptureFixture[str]) -> None:
    # s3://b/d<NUL> read the dataset at s3://b/d: the S3 client cut the key at the NUL, and every command said 0
    from avdata.cli import main
    from avdata.demo import write_demo

    demo = write_demo(tmp_path / "demo")
    root = location(f"{s3_server.uri}/d")
    for path in sorted(p for p in Path(demo).rglob("*") if p.is_file()):
        (root / path.relative_to(demo).as_posix()).write_bytes(path.read_bytes())
    assert main(["info", f"{s3_server.uri}/d"]) == 0
    capsys.readouterr()
    assert main(["info", f"{s3_server.uri}/d\x00"]) == 1
    assert capsys.readouterr().err == (f"avdata: error: '{s3_server.uri}/d\\x00': expected a URI without control "
                                       "characters, got '\\x00'\n")


def test_a_uri_with_credentials_is_refused_without_repeating_them() -> None:
    with pytest.raises(InputError) as caught:
        location(f"s3://AKIAXXXX:{SECRET}@bucket/prefix")
    assert SECRET not in str(caught.value) and "AKIAXXXX" not in str(caught.value)
    assert str(caught.value).startswith("s3://bucket/prefix: expected a URI without credentials")


def test_s3_options_come_from_the_environment_only() -> None:
    assert s3_options({}) == {}
    assert s3_options({"AWS_DEFAULT_REGION": "us-west-2", "AWS_SECRET_ACCESS_KEY": SECRET}) == {"region": "us-west-2"}
    env = {"AWS_REGION": "eu-central-1", "AWS_ENDPOINT_URL": "https://minio.example:9000",
           "AWS_ENDPOINT_URL_S3": "http://127.0.0.1:9000"}
    # the S3-specific override wins, as in the AWS SDKs
    assert s3_options(env) == {"region": "eu-central-1", "endpoint_override": "127.0.0.1:9000", "scheme": "http"}
    with pytest.raises(InputError, match="AWS_ENDPOINT_URL: expected an endpoint URL without credentials"):
        s3_options({"AWS_ENDPOINT_URL": f"http://user:{SECRET}@host:9000"})
    with pytest.raises(InputError, match="AWS_ENDPOINT_URL: expected an endpoint URL"):
        s3_options({"AWS_ENDPOINT_URL": "ftp://host"})


def test_s3_filesystem_gets_those_options(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("AWS_REGION", "ap-south-1")
    monkeypatch.setenv("AWS_ENDPOINT_URL", "http://127.0.0.1:1")
    fs = location("s3://plumbing-bucket/x").fs
    assert isinstance(fs, pafs.S3FileSystem) and fs.region == "ap-south-1"
    kwargs = fs.__reduce__()[1][0]
    assert kwargs["endpoint_override"] == "127.0.0.1:1" and kwargs["scheme"] == "http"
    assert kwargs.get("access_key") is None and kwargs.get("secret_key") is None  # left to the SDK's chain


def test_gcs_options_and_filesystem(monkeypatch: pytest.MonkeyPatch) -> None:
    assert gcs_options({"GOOGLE_APPLICATION_CREDENTIALS": "/k.json"}) == {}  # read by Google's client itself
    assert gcs_options({"STORAGE_EMULATOR_HOST": "localhost:4443", "GOOGLE_CLOUD_PROJECT": "p"}) == {
        "endpoint_override": "localhost:4443", "scheme": "http", "anonymous": True, "project_id": "p"}
    monkeypatch.setenv("STORAGE_EMULATOR_HOST", "http://127.0.0.1:4443")
    loc = location("gs://waymo_open_dataset_v_2_0_0/training/lidar")
    assert loc.path == "waymo_open_dataset_v_2_0_0/training/lidar" and loc.uri.startswith("gs://")
    assert isinstance(loc.fs, pafs.GcsFileSystem)
    kwargs = loc.fs.__reduce__()[1][0]
    assert kwargs["endpoint_override"] == "127.0.0.1:4443" and kwargs["scheme"] == "http" and kwargs["anonymous"]


def test_scrub_removes_credential_values(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", SECRET)
    assert scrub(f"signature for {SECRET} failed") == "signature for *** failed"


def test_objects_round_trip_through_the_s3_server(s3_server) -> None:  # noqa: ANN001 - fixture
    root = location(f"{s3_server.uri}/prefix")
    (root / "a" / "b.txt").write_bytes(b"hello")
    assert (root / "a" / "b.txt").read_bytes() == b"hello" and (root / "a").is_dir() and (root / "a" / "b.txt").is_file()
    assert [p.name for p in (root / "a").iterdir()] == ["b.txt"] and (root / "a" / "b.txt").size() == 5
    with pytest.raises(InputError, match=rf"^{s3_server.uri}/prefix/missing.txt: no such object$"):
        (root / "missing.txt").read_bytes()
    with pytest.raises(InputError, match="expected a file of at most 2 bytes, got 5 bytes"):
        (root / "a" / "b.txt").read_bytes(max_bytes=2)
    (root / "a" / "b.txt").copy_to(root / "c.txt")
    (root / "a" / "b.txt").delete()
    assert not (root / "a" / "b.txt").exists() and (root / "c.txt").read_bytes() == b"hello"
    with (root / "c.txt").open_input() as stream:
        assert stream.read_at(3, 1) == b"ell"


def test_a_writing_command_without_store_support_refuses_a_uri(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    from avdata.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["demo", "s3://bucket/demo"]) == 1
    assert capsys.readouterr().err == ("avdata: error: s3://bucket/demo: expected a local folder (convert, generate, "
                                       "export, track and study run write to object stores; demo and index write "
                                       "local folders only)\n")
    assert list(tmp_path.iterdir()) == []  # no local folder named "s3:"


def test_an_object_over_the_copy_limit_is_published_in_part_copies(s3_server, tmp_path: Path,  # noqa: ANN001
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    # S3's CopyObject stops at 5 GiB; the limit is lowered here so that an 11 MiB file takes the part-copy path
    # (parts of 5 MiB, S3's smallest but the last).
    monkeypatch.setattr(store, "S3_COPY_LIMIT_BYTES", 1 << 20)
    monkeypatch.setattr(store, "S3_COPY_PART_BYTES", 5 << 20)
    data = np.random.default_rng(0).integers(0, 256, 11 << 20, dtype=np.uint8).tobytes()
    (tmp_path / "scene.mcap").write_bytes(data)
    target = location(f"{s3_server.uri}/ds/scenes/scene.mcap")
    store.publish(tmp_path / "scene.mcap", target)
    assert target.read_bytes() == data
    head = s3_server.client().head_object(Bucket=s3_server.bucket, Key="ds/scenes/scene.mcap")
    assert head["ETag"].strip('"').endswith("-3")  # a multipart object of 3 parts, not one CopyObject
    assert [p.name for p in (target.parent).iterdir()] == ["scene.mcap"]  # the temporary key is gone
    # A copy the store refuses (here: its source is gone) is one line naming both; the final key keeps its object.
    missing = location(f"{s3_server.uri}/ds/scenes/.scene.mcap.gone.tmp")
    with pytest.raises(OutputError, match=rf"^{target.uri}: cannot copy {missing.uri} there \(.*\)$"):
        store._copy_in_parts(missing, target, 5 << 20)
    assert target.read_bytes() == data
