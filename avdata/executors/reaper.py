"""Ends the Ray processes a driver started when the driver dies without shutting Ray down (``kill -9``).

Ray ends its raylet, GCS and task workers with the driver, but the raylet's helpers (``DashboardAgent``,
``RuntimeEnvAgent``) can outlive it. A :class:`RayReaper` is a small process in a session of its own, started
with the local Ray instance: while the driver lives it notes the driver's descendants (the processes Ray started
for it) twice a second; once the driver is gone it gives Ray a moment to end them itself, then kills those still
running. A PID is killed only while it belongs to the process noted (same start time), so a reused PID is left
alone. The executor's normal shutdown stops the reaper first. Linux only (it reads ``/proc``).

Run as ``python -m avdata.executors.reaper DRIVER_PID``.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

#: How often the driver's descendants are noted, and how long Ray gets to end them itself.
POLL_S = 0.5
GRACE_S = 2.0


def _stat(pid: int) -> tuple[int, int] | None:
    """(parent PID, start time in clock ticks) of a running process, None if it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    # The command name (field 2) may hold spaces and parentheses: the fields after its last ')' are fixed.
    fields = text[text.rindex(")") + 2:].split()
    return int(fields[1]), int(fields[19])


def descendants(root: int) -> dict[int, int]:
    """PID -> start time of every process below ``root``."""
    children: dict[int, list[int]] = {}
    started: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit() and (stat := _stat(int(entry))) is not None:
            children.setdefault(stat[0], []).append(int(entry))
            started[int(entry)] = stat[1]
    found: dict[int, int] = {}
    stack = [root]
    while stack:
        for child in children.get(stack.pop(), []):
            if child not in found:
                found[child] = started[child]
                stack.append(child)
    return found


def reap(driver: int) -> None:
    """Notes ``driver``'s descendants while it lives; kills those still running after it is gone."""
    me = os.getpid()
    noted: dict[int, int] = {}
    while _stat(driver) is not None:
        noted.update({pid: start for pid, start in descendants(driver).items() if pid != me})
        time.sleep(POLL_S)
    time.sleep(GRACE_S)
    for pid, start in noted.items():
        stat = _stat(pid)
        if stat is not None and stat[1] == start:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:  # ended meanwhile
                pass


class RayReaper:
    """The reaper process of this driver (see the module docstring); ``stop()`` at a normal shutdown."""

    def __init__(self) -> None:
        self._process: subprocess.Popen[bytes] | None = None
        if sys.platform.startswith("linux"):
            self._process = subprocess.Popen(
                [sys.executable, "-m", "avdata.executors.reaper", str(os.getpid())],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                start_new_session=True)  # Ctrl-C and the driver's group signals must not reach it

    def stop(self) -> None:
        """Ends the reaper (Ray was shut down the normal way)."""
        if self._process is not None:
            self._process.kill()
            self._process.wait()
            self._process = None


if __name__ == "__main__":
    reap(int(sys.argv[1]))
