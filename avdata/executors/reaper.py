"""Ends the Ray processes a driver started: after ``ray.shutdown()``, and when the driver dies without it (``kill -9``).

Ray ends its raylet, GCS and task workers with the driver, but the raylet's helpers (``DashboardAgent``,
``RuntimeEnvAgent``) can outlive a killed driver, and after an orderly ``ray.shutdown()`` some of Ray's processes
still run for a moment (on a loaded machine one was alive 0.5 s after the interrupted driver had exited).

A :class:`RayReaper` is a small process in a session of its own, started with the local Ray instance; its stdin
and stdout are pipes to the driver. It notes Ray's processes below the driver twice a second, and once more when
the driver asks just before ``ray.shutdown()``: those started after the reaper whose command line is a Ray worker
(``ray::...``) or lives in Ray's package folder, and everything below them (a caller's own child processes, and a
Ray instance that was already running below the driver, are never touched). When the driver says it is done
(after ``ray.shutdown()``), or the pipe breaks because the driver died, it gives Ray a moment to end what it noted,
kills those still running and exits. The driver waits for that, so no Ray process outlives the executor, not even
a task's child that left Ray's process group. A PID is killed only while it belongs to the process noted (same
start time), so a reused PID is left alone. Linux only (it reads ``/proc``).

Run as ``python -m avdata.executors.reaper DRIVER_PID RAY_PACKAGE_DIR``.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

#: How often Ray's processes are noted, how long Ray gets to end them itself, how long a killed one gets to go.
POLL_S = 0.5
GRACE_S = 2.0
KILLED_S = 1.0


def _stat(pid: int) -> tuple[str, int, int] | None:
    """(state, parent PID, start time in clock ticks) of a process, None if it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    # The command name (field 2) may hold spaces and parentheses: the fields after its last ')' are fixed.
    fields = text[text.rindex(")") + 2:].split()
    return fields[0], int(fields[1]), int(fields[19])


def _running(pid: int, start: int) -> bool:
    """Whether the process noted with this start time still runs (a zombie has ended: only its entry is left)."""
    stat = _stat(pid)
    return stat is not None and stat[2] == start and stat[0] != "Z"


def _is_ray(pid: int, ray_dir: bytes) -> bool:
    try:
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return False
    return cmdline.startswith(b"ray::") or ray_dir in cmdline


def ray_processes(driver: int, ray_dir: str, since: int = 0) -> dict[int, int]:
    """PID -> start time of Ray's processes below ``driver`` (see the module docstring).

    Args:
        driver: the PID below which to look.
        ray_dir: Ray's package folder.
        since: start time (clock ticks since boot) before which a process, and all below it, is not this Ray's:
            the reaper passes its own, so a Ray instance already running below the driver is never touched.
    """
    children: dict[int, list[int]] = {}
    started: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit() and (stat := _stat(int(entry))) is not None:
            children.setdefault(stat[1], []).append(int(entry))
            started[int(entry)] = stat[2]
    marker = os.fsencode(os.path.join(ray_dir, ""))
    found: dict[int, int] = {}
    stack = [(driver, False)]
    while stack:
        parent, below_ray = stack.pop()
        for child in children.get(parent, []):
            if started[child] < since:
                continue
            is_ray = below_ray or _is_ray(child, marker)
            if is_ray:
                found[child] = started[child]
            stack.append((child, is_ray))
    return found


def _end(noted: dict[int, int]) -> None:
    """Gives the noted processes GRACE_S to end on their own, then kills those still running."""
    deadline = time.monotonic() + GRACE_S
    while time.monotonic() < deadline and any(_running(pid, start) for pid, start in noted.items()):
        time.sleep(0.05)
    left = {pid: start for pid, start in noted.items() if _running(pid, start)}
    for pid in left:
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:  # ended meanwhile
            pass
    deadline = time.monotonic() + KILLED_S
    while time.monotonic() < deadline and any(_running(pid, start) for pid, start in left.items()):
        time.sleep(0.02)


def reap(driver: int, ray_dir: str) -> None:
    """Notes Ray's processes below ``driver`` until the driver says ``end`` or dies; then ends those still running.

    The driver's words arrive on stdin, one per line: ``note`` (note them now and answer ``noted``) and ``end``.
    """
    me = _stat(os.getpid())
    since = me[2] if me is not None else 0
    noted: dict[int, int] = {}
    received = b""
    while True:
        noted.update(ray_processes(driver, ray_dir, since))
        readable, _, _ = select.select([sys.stdin.fileno()], [], [], POLL_S)
        if readable:
            chunk = os.read(sys.stdin.fileno(), 64)
            received += chunk
            if not chunk or b"end\n" in received:  # EOF: the driver died (the kernel closed the pipe)
                break
            if b"note\n" in received:
                received = received.replace(b"note\n", b"")
                noted.update(ray_processes(driver, ray_dir, since))
                os.write(sys.stdout.fileno(), b"noted\n")
        elif _stat(driver) is None:
            break
    _end(noted)


class RayReaper:
    """The reaper process of this driver (see the module docstring).

    ``note()`` before ``ray.shutdown()`` (Ray's processes are then all still below the driver), ``stop()`` after.
    """

    def __init__(self, ray_dir: str) -> None:
        self._process: subprocess.Popen[bytes] | None = None
        if sys.platform.startswith("linux"):
            self._process = subprocess.Popen(
                [sys.executable, "-m", "avdata.executors.reaper", str(os.getpid()), ray_dir],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                start_new_session=True)  # Ctrl-C and the driver's group signals must not reach it

    def _say(self, word: bytes) -> bool:
        """Sends one word; False if the reaper is gone."""
        if self._process is None or self._process.stdin is None:
            return False
        try:
            self._process.stdin.write(word + b"\n")
            self._process.stdin.flush()
        except OSError:
            return False
        return True

    def note(self) -> None:
        """Has the reaper note Ray's processes now, and waits (at most 10 s) until it has."""
        if self._say(b"note") and self._process is not None and self._process.stdout is not None:
            readable, _, _ = select.select([self._process.stdout.fileno()], [], [], 10.0)
            if readable:
                os.read(self._process.stdout.fileno(), 64)

    def stop(self) -> None:
        """Waits until the reaper has ended what is left of Ray (call it after ``ray.shutdown()``)."""
        if self._process is None:
            return
        self._say(b"end")
        try:
            self._process.wait(timeout=GRACE_S + KILLED_S + 10)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()
        for pipe in (self._process.stdin, self._process.stdout):
            if pipe is not None:
                pipe.close()
        self._process = None


if __name__ == "__main__":
    reap(int(sys.argv[1]), sys.argv[2])
