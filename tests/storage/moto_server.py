"""moto's standalone S3 server on a free port of 127.0.0.1, for the object-store tests and benchmarks/object_store.py."""

from __future__ import annotations

import socket
import subprocess
import sys
import time


def start_moto_server(timeout_s: float = 30.0) -> tuple[subprocess.Popen[bytes], str]:
    """Starts the server in its own process; returns it and its endpoint URL. RuntimeError if it does not answer."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = int(sock.getsockname()[1])
    process = subprocess.Popen([sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(port)],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
            return process, f"http://127.0.0.1:{port}"
        except OSError:
            if process.poll() is not None or time.monotonic() > deadline:
                process.kill()
                raise RuntimeError(f"moto server did not start on 127.0.0.1:{port}") from None
            time.sleep(0.1)
