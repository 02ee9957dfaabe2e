"""Helpers of the tests converting sources read from S3: real sample files in a bucket, and a counting proxy.

:class:`CountingProxy` stands between the process under test and moto's server: an HTTP relay on 127.0.0.1 that
counts the requests and the bytes of the responses it passes on, so a test measures what a converter fetched over
the wire (each ranged GET, HEAD and listing), not what it says it fetched.
"""

from __future__ import annotations

import http.client
import os
import shutil
import threading
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import urlsplit

import pytest

from tests.storage.conftest import S3Server
from tests.storage.kitti_s3 import files


def convert(name: str, src: Path | str, dst: Path | str, **options: object) -> list[str]:
    """``avdata convert NAME SRC DST`` in this process (paths or URIs); every problem as "severity file: message".

    Each file is named relative to SRC (the same for a local folder and a bucket), so two runs compare equal.
    """
    from avdata.converters.base import ConvertConfig, converter_class, run_conversion
    from avdata.storage import path_or_location

    cls = converter_class(name)
    result = run_conversion(cls(ConvertConfig(src=path_or_location(src), dst=path_or_location(dst), quiet=True,
                                              options=options)))
    assert not result.failed
    return [f"{p.severity} {p.file.removeprefix(str(src))}: {p.message}" for p in result.problems]


def same_dataset(written: Path | dict[str, bytes], src: str, reference: Path, reference_src: Path) -> bool:
    """Whether dataset ``written`` (a folder, or a bucket's key -> bytes) from ``src`` holds the same bytes as the
    local dataset ``reference`` from ``reference_src``: every file, every byte; ``errors.jsonl`` names SRC's files,
    so there the two SRC prefixes are taken as equal."""
    found = files(written) if isinstance(written, Path) else dict(written)
    expected = files(reference)
    for log in (found, expected):
        if "errors.jsonl" in log:
            log["errors.jsonl"] = log["errors.jsonl"].replace(src.encode(), b"SRC").replace(str(reference_src).encode(), b"SRC")
    return found == expected


def upload_tree(server: S3Server, source: Path, twin: Path, prefix: str, names: Iterable[str] | None = None) -> str:
    """Uploads the files under ``source`` (or only ``names``, relative to it) to ``s3://bucket/<prefix>``.

    They are also copied to the local folder ``twin`` (see :func:`upload_files`). Returns the prefix's URI.
    """
    relative = sorted(names) if names is not None else sorted(
        p.relative_to(source).as_posix() for p in source.rglob("*") if p.is_file())
    return upload_files(server, {name: source / name for name in relative}, twin, prefix)


def upload_files(server: S3Server, named: dict[str, Path], twin: Path, prefix: str) -> str:
    """Uploads each local file of ``named`` as ``s3://bucket/<prefix>/<its name>`` and copies it to ``twin/<name>``.

    Each local copy gets its object's last-modified time: the resume fingerprint records large files' mtimes, so
    the two conversions see the same source and must write the same bytes. Returns the prefix's URI.
    """
    client = server.client()
    for name, path in sorted(named.items()):
        local = twin / name
        local.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, local)
        key = f"{prefix}/{name}"
        client.put_object(Bucket=server.bucket, Key=key, Body=local.read_bytes())
        modified = client.head_object(Bucket=server.bucket, Key=key)["LastModified"].timestamp()
        os.utime(local, ns=(int(modified * 1e9), int(modified * 1e9)))
    return f"{server.uri}/{prefix}"


@dataclass
class Traffic:
    """What passed through the proxy: requests by HTTP method, response body bytes of GETs, and each GET's
    (path, Range header, bytes)."""

    requests: dict[str, int] = field(default_factory=dict)
    get_bytes: int = 0
    gets: list[tuple[str, str, int]] = field(default_factory=list)

    @property
    def n_requests(self) -> int:
        """Every request, of any method."""
        return sum(self.requests.values())


class _Relay(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    upstream: tuple[str, int]
    traffic: Traffic
    lock: threading.Lock

    def _relay(self) -> None:
        length = int(self.headers.get("Content-Length") or 0)
        body = self.rfile.read(length) if length else None
        connection = http.client.HTTPConnection(*self.upstream, timeout=60)
        headers = {k: v for k, v in self.headers.items() if k.lower() != "connection"}
        connection.request(self.command, self.path, body=body, headers=headers)
        response = connection.getresponse()
        data = response.read()
        connection.close()
        with self.lock:
            self.traffic.requests[self.command] = self.traffic.requests.get(self.command, 0) + 1
            if self.command == "GET":
                self.traffic.get_bytes += len(data)
                self.traffic.gets.append((self.path, self.headers.get("Range", ""), len(data)))
        self.send_response_only(response.status, response.reason)
        for name, value in response.getheaders():
            if name.lower() not in ("connection", "transfer-encoding", "content-length", "date", "server"):
                self.send_header(name, value)
        self.send_header("Content-Length", response.getheader("Content-Length", str(len(data)))
                         if self.command == "HEAD" else str(len(data)))
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(data)

    do_GET = do_HEAD = do_PUT = do_POST = do_DELETE = _relay  # noqa: N815 - http.server's method names

    def log_message(self, format: str, *args: object) -> None:  # noqa: A002 - the base class's signature
        """Quiet: pytest shows no per-request lines."""


@contextmanager
def counting_proxy(server: S3Server, monkeypatch: pytest.MonkeyPatch) -> Iterator[Traffic]:
    """Points ``AWS_ENDPOINT_URL`` at a relay to ``server`` for the ``with`` block and counts what passes through."""
    upstream = urlsplit(server.endpoint)
    traffic = Traffic()
    handler = type("Relay", (_Relay,), {"upstream": (upstream.hostname, upstream.port), "traffic": traffic,
                                         "lock": threading.Lock()})
    relay = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=relay.serve_forever, daemon=True)
    thread.start()
    monkeypatch.setenv("AWS_ENDPOINT_URL", f"http://127.0.0.1:{relay.server_address[1]}")
    try:
        yield traffic
    finally:
        monkeypatch.setenv("AWS_ENDPOINT_URL", server.endpoint)
        relay.shutdown()
        relay.server_close()


def convert_locally_and_from_s3(name: str, server: S3Server, twin: Path, src: str, dst: Path,
                                monkeypatch: pytest.MonkeyPatch, **options: object) -> tuple[list[str], list[str], Traffic]:
    """Converts the local ``twin`` to ``dst/local`` and the bucket's ``src`` to ``dst/remote`` through the counting
    relay: both runs' problems (see :func:`convert`) and what the second fetched."""
    local = convert(name, twin, dst / "local", **options)
    with counting_proxy(server, monkeypatch) as traffic:
        remote = convert(name, src, dst / "remote", **options)
    return local, remote, traffic


def rewrite_object(server: S3Server, key: str, change: Callable[[bytes], bytes]) -> None:
    """Replaces the bucket's object ``key`` with ``change`` of its bytes (a damaged copy of a real file)."""
    client = server.client()
    data = client.get_object(Bucket=server.bucket, Key=key)["Body"].read()
    client.put_object(Bucket=server.bucket, Key=key, Body=change(data))
