"""The local executor: results in task order, a dead worker is a failure, workers die with their parent."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from avdata.errors import InputError
from avdata.executors import LocalExecutor, TaskFailure, make_executor
from avdata.schema import SceneReader

ROOT = Path(__file__).resolve().parents[2]


def _square_slowly(x: int) -> int:
    time.sleep(0.05 * (3 - x))  # the last task finishes first
    return x * x


def _die_on_two(x: int) -> int:
    if x == 2:
        os.kill(os.getpid(), signal.SIGKILL)
    return x


def test_results_come_back_in_task_order_whatever_finishes_first() -> None:
    finished: list[int] = []
    results = LocalExecutor(2).map(_square_slowly, [0, 1, 2, 3], on_done=lambda i, _r: finished.append(i))
    assert results == [0, 1, 4, 9]
    assert sorted(finished) == [0, 1, 2, 3]


def test_a_killed_worker_is_a_task_failure_not_a_traceback() -> None:
    results = LocalExecutor(2).map(_die_on_two, [0, 2])
    assert isinstance(results[1], TaskFailure) and "worker process died" in results[1].message


def test_executor_names_and_workers_are_checked() -> None:
    with pytest.raises(InputError, match=r"--workers: expected 1\.\.\d+ \(4 per core here\), got 100000"):
        LocalExecutor(100_000)
    with pytest.raises(InputError, match=r"--workers: expected 1\.\.\d+ \(4 per core here\), got 0"):
        make_executor("local", workers=0)
    with pytest.raises(InputError, match="expected one of \\['local', 'ray'\\], got 'dask'"):
        make_executor("dask")
    with pytest.raises(InputError, match="expected --executor ray with it"):
        make_executor("local", ray_address="auto")
    # An empty address is refused, not dropped (--ray-address '' started a local Ray instance without a word).
    with pytest.raises(InputError, match="^--ray-address: expected a Ray cluster address, .*got ''$"):
        make_executor("local", ray_address="")
    with pytest.raises(InputError, match="^--ray-address: expected a Ray cluster address, .*got ' '$"):
        make_executor("ray", ray_address=" ")


def _descendants(pid: int) -> set[int]:
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            children.setdefault(ppid, []).append(int(entry))
    found, todo = set(), [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            found.add(child)
            todo.append(child)
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_kill_9_of_the_parent_leaves_no_live_workers(tmp_path: Path) -> None:
    dst = tmp_path / "out"
    parent = subprocess.Popen(
        [sys.executable, "-m", "avdata.cli", "generate", "--preset", "v2i-intersection", str(dst), "--scenes", "2",
         "--frames", "400", "--workers", "2", "--quiet"],
        env={**os.environ, "PYTHONPATH": str(ROOT)}, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while len(workers := _descendants(parent.pid)) < 2:
            assert parent.poll() is None and time.monotonic() < deadline, "the pool never started"
            time.sleep(0.1)
        time.sleep(2.0)  # the workers are simulating now
        workers = _descendants(parent.pid)
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait(timeout=10)
        deadline = time.monotonic() + 15
        while any(_alive(pid) for pid in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not [pid for pid in workers if _alive(pid)]
    finally:
        if parent.poll() is None:
            parent.kill()
    # Nothing half-written under a final name.
    for path in (dst / "scenes").glob("*.mcap"):
        SceneReader(path)


def test_an_unreachable_ray_address_fails_fast_in_one_line(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    start = time.monotonic()
    result = subprocess.run(
        [sys.executable, "-m", "avdata.cli", "generate", "--preset", "v2i-intersection", str(tmp_path / "out"),
         "--executor", "ray", "--ray-address", "127.0.0.1:1", "--quiet"],
        env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True, timeout=120)
    assert result.returncode == 1 and time.monotonic() - start < 60
    assert result.stderr.startswith("avdata: error: --ray-address 127.0.0.1:1: expected a running Ray head")
    assert result.stderr.count("\n") == 1, result.stderr


#: ``avdata convert kitti-object`` whose scenes take minutes: it marks each start, then sleeps.
SLOW_CONVERT = """
import sys, time
from pathlib import Path
import avdata.converters.base as base
from avdata.cli import main
from avdata.converters.kitti import KittiObjectConverter

class Slow(KittiObjectConverter):
    def convert_scene(self, scene, writer, report):
        Path(str(self.config.dst) + "." + scene + ".started").write_text("x")
        with writer.scene(scene, {}) as scene_writer:  # a temporary scene file exists while it sleeps
            time.sleep(300)

base.CONVERTERS["kitti-object"] = "__main__:Slow"
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize(("options", "started"), [(["--workers", "1"], 1), (["--workers", "2"], 2),
                                                 (["--executor", "ray"], 1)], ids=["local", "2-workers", "ray"])
def test_ctrl_c_is_one_line_and_exit_130(tmp_path: Path, options: list[str], started: int) -> None:
    """Ctrl-C reaches the whole process group: workers printed KeyboardInterrupt tracebacks, the pool waited for them."""
    from tests.realdata import REALDATA

    if options[1] == "ray":
        pytest.importorskip("ray")
    dst = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, "-c", SLOW_CONVERT, "convert", "kitti-object", str(REALDATA / "kitti" / "object"),
                             str(dst), "--quiet", "--scene-size", "1", *options],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while len(list(tmp_path.glob("out.*.started"))) < started and time.monotonic() < deadline:
            time.sleep(0.1)
        assert len(list(tmp_path.glob("out.*.started"))) >= started
        os.killpg(proc.pid, signal.SIGINT)  # what the terminal does on Ctrl-C
        _, err = proc.communicate(timeout=30)  # not after the scenes' 300 s
    finally:
        if proc.poll() is None:  # the test failed: end what it started
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    time.sleep(0.5)  # the killed workers' process entries
    # Of the session's processes, those that still run (a zombie has ended: only its entry waits for a parent).
    ps = subprocess.run(["ps", "-s", str(proc.pid), "-o", "pid=,stat=,args="], capture_output=True, text=True).stdout
    survivors = [line for line in ps.splitlines() if not line.split()[1].startswith("Z")]
    assert survivors == []
    # The next run removes what the interrupted one left under temporary names.
    subprocess.run([sys.executable, "-m", "avdata.cli", "convert", "kitti-object", str(REALDATA / "kitti" / "object"),
                    str(dst), "--quiet", "--scene-size", "1"], env=env, check=True, capture_output=True)
    assert not [p for p in dst.rglob("*") if p.name.endswith(".tmp")]
