"""Start-up of the ``avdata`` command: wall time and peak memory of ``avdata --help`` and ``avdata info DATASET``.

Each command runs ``--repeats`` times in a fresh interpreter (``python -m avdata.cli``, as the console script
does); the figures are the median wall time and the largest peak resident memory (``ru_maxrss`` of the child),
next to a bare ``python -c pass`` for the interpreter's own share. ``info`` reads the built-in demo dataset
(written once into a temporary folder). Targets (issue 32): under 0.4 s and 60 MB each on the 2-core machine.

Usage: ``python benchmarks/cli_startup.py [--quick] [--repeats R]``
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def measure(argv: list[str], repeats: int) -> tuple[float, float]:
    """(median seconds, peak MB) of running ``argv`` ``repeats`` times."""
    times, peaks = [], []
    for _ in range(repeats):
        start = time.perf_counter()
        pid = os.posix_spawn(argv[0], argv, dict(os.environ),
                             file_actions=[(os.POSIX_SPAWN_OPEN, 1, os.devnull, os.O_WRONLY, 0)])
        _, status, usage = os.wait4(pid, 0)
        times.append(time.perf_counter() - start)
        if os.waitstatus_to_exitcode(status) != 0:
            raise SystemExit(f"{' '.join(argv)}: exit {os.waitstatus_to_exitcode(status)}")
        peaks.append(usage.ru_maxrss / 1024)  # kB on Linux
    return statistics.median(times), max(peaks)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="3 repeats instead of --repeats (default: off)")
    parser.add_argument("--repeats", type=int, default=10, help="runs per command (default: 10)")
    args = parser.parse_args()
    repeats = 3 if args.quick else args.repeats
    with tempfile.TemporaryDirectory() as tmp:
        demo = Path(tmp) / "demo"
        subprocess.run([sys.executable, "-m", "avdata.cli", "demo", str(demo)], check=True, capture_output=True)
        commands = {"python -c pass": [sys.executable, "-c", "pass"],
                    "avdata --help": [sys.executable, "-m", "avdata.cli", "--help"],
                    "avdata info DEMO": [sys.executable, "-m", "avdata.cli", "info", str(demo)]}
        print(f"cli_startup: {repeats} runs each, median wall time and peak memory")
        for name, argv in commands.items():
            seconds, megabytes = measure(argv, repeats)
            print(f"{name:<18} {seconds:6.3f} s  {megabytes:6.1f} MB")


if __name__ == "__main__":
    main()
