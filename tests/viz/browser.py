"""A real headless Chromium driven through the DevTools protocol over a pipe (no websocket library needed).

``open_page(path)`` loads a local HTML file and returns what a person would see go wrong: console errors,
uncaught exceptions, log errors (a Content-Security-Policy violation is one), requests to anything but the
file itself and ``data:`` URLs; ``evaluate`` runs JavaScript in the page; ``screenshot`` saves a PNG.

Chromium is Debian's ``chromium`` package (``.ci/run`` installs it). Without it, the tests that need it are
skipped with one reason, the same for all of them; under CI (``CI=true``) they fail instead.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--remote-debugging-pipe", "--hide-scrollbars")


def chromium_or_skip() -> str:
    """The Chromium executable; skips the test (fails it under CI=true) when there is none."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    if os.environ.get("CI") == "true":
        pytest.fail("CI=true and no Chromium on PATH (.ci/run installs Debian's chromium package)")
    pytest.skip("no Chromium on PATH: browser checks of report.html skipped (apt-get install chromium)")


@dataclass
class Page:
    """A loaded page and what happened while it loaded."""

    browser: Browser
    session: str
    errors: list[str] = field(default_factory=list)
    requests: list[str] = field(default_factory=list)

    def evaluate(self, expression: str) -> Any:
        """The JSON value of ``expression`` evaluated in the page."""
        result = self.browser.call("Runtime.evaluate", {"expression": expression, "returnByValue": True,
                                                        "awaitPromise": True}, self.session)
        if "exceptionDetails" in result:
            raise AssertionError(f"{expression}: {result['exceptionDetails']}")
        return result["result"].get("value")

    def screenshot(self, path: Path) -> Path:
        """Saves a PNG of the whole page (beyond the window's height) to ``path``."""
        result = self.browser.call("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": True},
                                   self.session)
        path.write_bytes(base64.b64decode(result["data"]))
        return path


def _running_in_group(group: int) -> bool:
    """Whether a live process (not a zombie waiting for its parent) is in the process group."""
    for stat_file in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat_file.read_text().rsplit(")", 1)[1].split()  # after "pid (comm)": state, ppid, pgrp
        except OSError:
            continue  # the process ended meanwhile
        if fields[0] != "Z" and int(fields[2]) == group:
            return True
    return False


class Browser:
    """One headless Chromium process; use as a context manager."""

    def __init__(self, executable: str) -> None:
        self._profile = tempfile.TemporaryDirectory(prefix="avdata-chromium-")
        to_browser_read, self._to_browser = os.pipe()
        self._from_browser, from_browser_write = os.pipe()

        def pipes_on_3_and_4() -> None:  # the DevTools pipe: Chromium reads fd 3 and writes fd 4
            read, write = os.dup(to_browser_read), os.dup(from_browser_write)  # neither is 3 or 4 by now
            os.dup2(read, 3)
            os.dup2(write, 4)

        self._process = subprocess.Popen(
            [executable, *CHROMIUM_FLAGS, f"--user-data-dir={self._profile.name}", "about:blank"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            pass_fds=(3, 4), preexec_fn=pipes_on_3_and_4, start_new_session=True)
        os.close(to_browser_read)
        os.close(from_browser_write)
        self._buffer = b""
        self._next_id = 0
        self._events: list[dict[str, Any]] = []

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc: object) -> None:
        # Chromium's renderer and utility processes write into the profile until they end. Killing the browser
        # process alone left them running while the profile was removed ("Directory not empty: 'Default'"), so
        # the browser is asked to close, then its whole process group is killed and waited for.
        try:
            self.call("Browser.close", timeout_s=10.0)
        except (OSError, RuntimeError, TimeoutError):
            pass  # it closed the pipe before answering, or is stuck: the group kill below ends it
        try:
            self._process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait(timeout=30)
        deadline = time.monotonic() + 30.0
        while _running_in_group(self._process.pid) and time.monotonic() < deadline:
            try:
                os.killpg(self._process.pid, signal.SIGKILL)
            except ProcessLookupError:
                break
            time.sleep(0.05)
        os.close(self._to_browser)
        os.close(self._from_browser)
        self._profile.cleanup()

    def _read_message(self, deadline: float) -> dict[str, Any]:
        while b"\0" not in self._buffer:
            if time.monotonic() > deadline:
                raise TimeoutError("Chromium did not answer within the time limit")
            chunk = os.read(self._from_browser, 1 << 20)
            if not chunk:
                raise RuntimeError("Chromium closed the DevTools pipe")
            self._buffer += chunk
        message, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(message)

    def call(self, method: str, params: dict[str, Any] | None = None, session: str | None = None,
             timeout_s: float = 60.0) -> dict[str, Any]:
        """Sends one command and returns its result; events that arrive meanwhile are kept."""
        self._next_id += 1
        message: dict[str, Any] = {"id": self._next_id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        os.write(self._to_browser, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + timeout_s
        while True:
            reply = self._read_message(deadline)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self._events.append(reply)

    def _wait_for(self, method: str, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not any(e.get("method") == method for e in self._events):
            self._events.append(self._read_message(deadline))

    def open_page(self, path: Path, width_px: int = 1280) -> Page:
        """Loads the file at ``path`` in a new tab and waits for its load event."""
        target = self.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Page", "Runtime", "Log", "Network"):
            self.call(f"{domain}.enable", {}, session)
        self.call("Emulation.setDeviceMetricsOverride", {"width": width_px, "height": 900, "deviceScaleFactor": 1,
                                                         "mobile": False}, session)
        self._events.clear()
        url = path.resolve().as_uri()
        self.call("Page.navigate", {"url": url}, session)
        self._wait_for("Page.loadEventFired")
        page = Page(self, session)
        self.call("Runtime.evaluate", {"expression": "1"}, session)  # flushes events queued during the load
        for event in self._events:
            params = event.get("params", {})
            if event.get("method") == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
                page.errors.append(f"console: {[a.get('value') for a in params.get('args', [])]}")
            elif event.get("method") == "Runtime.exceptionThrown":
                page.errors.append(f"exception: {params['exceptionDetails'].get('text')}")
            elif event.get("method") == "Log.entryAdded" and params["entry"].get("level") == "error":
                page.errors.append(f"log: {params['entry'].get('text')}")
            elif event.get("method") == "Network.requestWillBeSent":
                request_url = params["request"]["url"]
                if request_url != url and not request_url.startswith("data:"):
                    page.requests.append(request_url)
        return page
