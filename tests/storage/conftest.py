"""A real S3 API server on 127.0.0.1 for the object-store tests: moto's standalone server, in its own process.

It speaks the S3 HTTP protocol (pyarrow's C++ S3 client and botocore talk to it as to AWS), so nothing in the
process under test is patched. One server per test session; each test gets its own bucket and environment.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass

import pytest

from tests.storage.moto_server import start_moto_server

#: A distinctive fake secret: tests check that it never appears in any output.
SECRET = "Sup3rSecretKeyThatMustNeverBePrinted0123"
ACCESS_KEY = "AKIAAVDATATESTKEY000"
_BUCKETS = itertools.count()


@dataclass(frozen=True)
class S3Server:
    """The running server: its endpoint URL and this test's bucket."""

    endpoint: str
    bucket: str

    @property
    def uri(self) -> str:
        """``s3://<bucket>``."""
        return f"s3://{self.bucket}"

    def client(self):  # noqa: ANN201 - botocore's client type is generated at run time
        import boto3

        return boto3.client("s3", endpoint_url=self.endpoint, region_name="us-east-1",
                            aws_access_key_id=ACCESS_KEY, aws_secret_access_key=SECRET)


@pytest.fixture(scope="session")
def _moto_endpoint() -> Iterator[str]:
    pytest.importorskip("moto.server", reason="needs moto[server] (the test extra)")
    try:
        process, endpoint = start_moto_server()
    except RuntimeError as exc:
        pytest.fail(str(exc))
    try:
        yield endpoint
    finally:
        process.terminate()
        process.wait(10)


@pytest.fixture
def s3_server(_moto_endpoint: str, monkeypatch: pytest.MonkeyPatch) -> S3Server:
    """The S3 server with a new empty bucket, and the AWS environment pointing at it (dummy credentials)."""
    for name in ("AWS_PROFILE", "AWS_ENDPOINT_URL_S3", "AWS_DEFAULT_REGION", "AWS_SESSION_TOKEN"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", ACCESS_KEY)
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", SECRET)
    monkeypatch.setenv("AWS_REGION", "us-east-1")
    monkeypatch.setenv("AWS_ENDPOINT_URL", _moto_endpoint)
    monkeypatch.setenv("AWS_EC2_METADATA_DISABLED", "true")
    server = S3Server(endpoint=_moto_endpoint, bucket=f"avdata-test-{next(_BUCKETS)}")
    server.client().create_bucket(Bucket=server.bucket)
    return server
