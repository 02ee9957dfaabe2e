"""The executor interface and its two engines: a local process pool and Ray.

An executor runs one module-level function over a list of tasks (one per scene) and returns the
results in task order, whatever order they finish in, so the output does not depend on the engine or
the number of workers. Tasks report input errors in their result (never by raising); an exception
that escapes a task (a full disk, ``--strict``, a bug) ends the run: tasks not yet started never start, running
ones finish, and the exception propagates as itself. A task whose process dies (killed, out of memory, node
lost) becomes a :class:`TaskFailure`: Ray retries it first (``max_retries``), the local pool does not.

Ctrl-C reaches the driver and every worker of the terminal's process group; pool workers ignore it, and the
driver ends them and re-raises ``KeyboardInterrupt`` (the command line's one line and exit status 130), so no
worker prints a traceback. Their temporary files are removed by the next run, under the lock.
"""

from __future__ import annotations

import argparse
import ctypes
import logging
import os
import signal
import socket
import sys
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from avdata.errors import AvdataError, InputError, one_line
from avdata.executors.reaper import RayReaper
from avdata.outputs import is_disk_full

T = TypeVar("T")
R = TypeVar("R")

EXECUTORS = ("local", "ray")
#: Ray retries of a task whose worker process or node died (input errors are results, never retried).
RAY_MAX_RETRIES = 3
#: How long a run that stops waits for its cancelled Ray tasks to end (they remove their temporary files).
RAY_CANCEL_WAIT_S = 30.0
_PR_SET_PDEATHSIG = 1


@dataclass(frozen=True, slots=True, kw_only=True)
class TaskFailure:
    """A task that ended without a result because its process died (after any retries)."""

    message: str


class Executor(ABC):
    """Runs scene tasks; use as a context manager (it releases its workers at the end)."""

    name: str

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        self.close()

    def close(self) -> None:  # noqa: B027 - nothing to release by default
        """Releases the workers (or the Ray instance this executor started)."""

    def check_visible(self, paths: Sequence[Path]) -> None:  # noqa: B027 - local workers share the caller's files
        """Raises InputError when a worker cannot see one of ``paths`` (SRC, DST on a shared filesystem)."""

    @abstractmethod
    def map(self, fn: Callable[[T], R], tasks: Sequence[T],
            on_done: Callable[[int, R | TaskFailure], None] | None = None) -> list[R | TaskFailure]:
        """``fn`` over every task; results in task order; ``on_done(index, result)`` as each one finishes."""


def die_with_parent(parent_pid: int) -> None:
    """Pool initializer: this worker process ends when the parent does (also after ``kill -9``).

    On Linux the kernel sends SIGKILL at the parent's death (``prctl(PR_SET_PDEATHSIG)``); elsewhere a
    daemon thread polls the parent's PID. Ctrl-C is the parent's to handle (it ends the workers).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
    else:
        def watch() -> None:
            while os.getppid() == parent_pid:
                time.sleep(0.5)
            os._exit(1)

        threading.Thread(target=watch, daemon=True).start()
    # The parent may have died between fork and prctl, when the signal could no longer be armed.
    if os.getppid() != parent_pid:
        os._exit(1)


#: Local worker processes allowed per core (``--workers`` beyond it is refused).
MAX_WORKERS_PER_CORE = 4


class LocalExecutor(Executor):
    """``workers`` processes on this machine (the calling process itself for one worker or one task)."""

    name = "local"

    def __init__(self, workers: int = 1):
        # Each worker is a process holding a scene's data; far more of them than cores only thrashes (and a
        # typo such as 1000 would fork a thousand processes), so the bound is a few per core.
        limit = MAX_WORKERS_PER_CORE * (os.cpu_count() or 1)
        if not 1 <= workers <= limit:
            raise InputError(f"--workers: expected 1..{limit} ({MAX_WORKERS_PER_CORE} per core here), got {workers}")
        self.workers = workers

    def map(self, fn: Callable[[T], R], tasks: Sequence[T],
            on_done: Callable[[int, R | TaskFailure], None] | None = None) -> list[R | TaskFailure]:
        """Runs fn over tasks; see :meth:`Executor.map`."""
        results: list[Any] = [None] * len(tasks)
        if self.workers == 1 or len(tasks) <= 1:
            for i, task in enumerate(tasks):
                results[i] = fn(task)
                if on_done:
                    on_done(i, results[i])
            return results
        pool = ProcessPoolExecutor(max_workers=min(self.workers, len(tasks)), initializer=die_with_parent,
                                   initargs=(os.getpid(),))
        try:
            futures: dict[Future[R], int] = {pool.submit(fn, task): i for i, task in enumerate(tasks)}
            pending = set(futures)
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in sorted(done, key=futures.__getitem__):
                    i = futures[future]
                    try:
                        results[i] = future.result()
                    except BrokenProcessPool:
                        results[i] = TaskFailure(message="a worker process died (killed, or out of memory)")
                    if on_done:
                        on_done(i, results[i])
        except KeyboardInterrupt:
            # Waiting for the running tasks would make Ctrl-C wait for whole scenes.
            processes = list((getattr(pool, "_processes", None) or {}).values())
            pool.shutdown(wait=False, cancel_futures=True)
            for process in processes:
                process.kill()
            raise
        except BaseException:
            # The running tasks end on their own (on a full disk, quickly, removing their temporary files).
            pool.shutdown(wait=True, cancel_futures=True)
            raise
        pool.shutdown(wait=True)
        return results


def _started_task(fn: Callable[[T], R], task: T) -> R:
    """Runs one task in a Ray worker; once started, ``ray.cancel`` no longer interrupts it.

    ``ray.cancel`` of a running task raises KeyboardInterrupt at whatever line the task is on (Ray calls
    ``_thread.interrupt_main``), also between creating a scene's temporary file and the code that removes it on
    failure: a full disk on Ray once left a ``.tmp`` file behind. A run that ends early only drops the tasks not
    yet started, as the local pool does; with SIGINT ignored the interrupt does nothing and a started task ends
    on its own. (Ctrl-C in a terminal does not reach Ray's workers: each has a process group of its own.)
    """
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ray runs a task on its worker's main thread
    try:
        return fn(task)
    finally:  # the worker runs other tasks next, perhaps not avdata's
        signal.signal(signal.SIGINT, previous)


class RayExecutor(Executor):
    """Tasks on a Ray cluster (``address``), or on a local Ray instance started here when None.

    Args:
        address: ``ray.init(address=...)``, e.g. "auto" or "10.0.0.1:6379"; None starts a local instance.
        max_retries: retries of a task whose worker process or node died.
        num_cpus: CPUs of a local instance started here (all when None).
    """

    name = "ray"

    def __init__(self, address: str | None = None, max_retries: int = RAY_MAX_RETRIES, num_cpus: int | None = None):
        try:
            import ray
        except ImportError as error:
            raise AvdataError("--executor ray: expected Ray to be installed (pip install 'avdata[ray]'), got none") from error
        self._ray = ray
        self.max_retries = max_retries
        self._owns_ray = not ray.is_initialized()
        self._reaper: RayReaper | None = None
        if self._owns_ray:
            if address:
                _check_reachable(address)
            else:  # a local instance: its processes must not outlive this driver, even after kill -9
                self._reaper = RayReaper(ray_dir=os.path.dirname(ray.__file__))
            try:
                ray.init(address=address, num_cpus=num_cpus, include_dashboard=False, logging_level=logging.ERROR,
                         configure_logging=True, log_to_driver=False)
            except Exception as error:  # noqa: BLE001 - any start-up failure (a killed raylet, a timeout) is one line
                self.close()
                what = f"--ray-address {address}: cannot connect to a Ray cluster" if address else "cannot start Ray here"
                raise AvdataError(f"{what} ({type(error).__name__}: {one_line(error)[:300]})") from error

    def close(self) -> None:
        """Shuts down the Ray instance this executor started, if it started one, and waits until its processes end."""
        if self._owns_ray:
            if self._reaper is not None:
                self._reaper.note()
            self._ray.shutdown()
            self._owns_ray = False
        if self._reaper is not None:
            self._reaper.stop()
            self._reaper = None

    def check_visible(self, paths: Sequence[Path]) -> None:
        """Runs one task on every alive node that checks ``paths`` exist there."""
        ray = self._ray
        from ray.exceptions import RayError
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        check = ray.remote(num_cpus=0, max_retries=self.max_retries)(_missing_paths)
        names = [str(Path(p).resolve()) for p in paths]
        nodes = [node for node in ray.nodes() if node.get("Alive")]
        refs = [check.options(scheduling_strategy=NodeAffinitySchedulingStrategy(node["NodeID"], soft=False)).remote(names)
                for node in nodes]
        try:
            found = ray.get(refs)
        except RayError as error:  # the check's worker or node died on every retry
            raise AvdataError(f"Ray: the task that checks what the nodes see died {self.max_retries + 1} times "
                              f"({type(error).__name__}); nothing was written") from None
        for node, missing in zip(nodes, found, strict=True):
            if missing:
                raise InputError(f"Ray node {node.get('NodeManagerAddress', node['NodeID'])}: cannot see {missing[0]}; "
                                 f"SRC and DST must be on a filesystem every node mounts at the same path")

    def map(self, fn: Callable[[T], R], tasks: Sequence[T],
            on_done: Callable[[int, R | TaskFailure], None] | None = None) -> list[R | TaskFailure]:
        """Runs fn over tasks; see :meth:`Executor.map`."""
        ray = self._ray
        from ray.exceptions import RayError, RayTaskError

        remote = ray.remote(num_cpus=1, max_retries=self.max_retries, retry_exceptions=False)(_started_task)
        named = remote.options(name=getattr(fn, "__name__", "task"))  # what Ray's process titles and state API show
        refs = {named.remote(fn, task): i for i, task in enumerate(tasks)}
        results: list[Any] = [None] * len(tasks)
        pending = list(refs)
        try:
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                for ref in done:
                    i = refs[ref]
                    try:
                        results[i] = ray.get(ref)
                    except RayTaskError as error:
                        # An exception escaped the task: avdata's own (``--strict``) and a full disk as themselves
                        # (one line each), a bug as itself.
                        if isinstance(error.cause, AvdataError) or is_disk_full(error.cause):
                            raise error.cause from None
                        raise error.as_instanceof_cause() from None  # type: ignore[no-untyped-call]  # ray leaves it unannotated
                    except RayError as error:
                        results[i] = TaskFailure(message=f"the task's worker died {self.max_retries + 1} times "
                                                         f"({type(error).__name__})")
                    if on_done:
                        on_done(i, results[i])
        except BaseException as error:
            for ref in pending:  # the run ends here: tasks not started never start (started ones run on)
                ray.cancel(ref)
            if pending and not isinstance(error, KeyboardInterrupt):
                # As the local pool does: the running tasks end on their own (on a full disk, quickly, removing
                # their temporary files) before the run reports; Ctrl-C does not wait for them.
                ray.wait(pending, num_returns=len(pending), timeout=RAY_CANCEL_WAIT_S)
            raise
        return results


def _check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """Fails fast on an unreachable ``HOST:PORT`` (``ray.init`` would retry it forever); "auto" is left to Ray."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        return
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except OSError as error:
        raise AvdataError(f"--ray-address {address}: expected a running Ray head (ray start --head), "
                          f"got no answer ({error.strerror or error})") from error


def _missing_paths(paths: list[str]) -> list[str]:
    return [p for p in paths if not os.path.exists(p)]


def make_executor(name: str, *, workers: int = 1, ray_address: str | None = None) -> Executor:
    """The executor named on the command line: "local" (``workers`` processes) or "ray"."""
    # Checked against None, not truthiness: --ray-address '' was dropped without a word (a local run or Ray instance).
    if ray_address is not None and not ray_address.strip():
        raise InputError(f"--ray-address: expected a Ray cluster address, e.g. 'auto' or HOST:6379, got {ray_address!r}")
    if name == "local":
        if ray_address is not None:
            raise InputError(f"--ray-address {ray_address}: expected --executor ray with it, got --executor local")
        return LocalExecutor(workers)
    if name == "ray":
        return RayExecutor(address=ray_address)
    raise InputError(f"--executor: expected one of {list(EXECUTORS)}, got {name!r}")


def add_executor_arguments(parser: argparse.ArgumentParser, what: str) -> None:
    """``--workers``, ``--executor``, ``--ray-address`` and ``--force``: shared by convert and generate."""
    parser.add_argument("--workers", type=int, default=1, help=f"{what} in parallel processes (--executor local; default 1)")
    parser.add_argument("--executor", choices=EXECUTORS, default="local",
                        help="local: a process pool on this machine (default); ray: one Ray task per scene")
    parser.add_argument("--ray-address", default=None,
                        help="Ray cluster to join, e.g. 'auto' or HOST:6379 (default: start a local Ray instance)")
    parser.add_argument("--force", action="store_true",
                        help="rewrite every scene (default: skip scenes written by the same inputs, options and version)")
