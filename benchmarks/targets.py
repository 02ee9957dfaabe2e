"""Prints each speed target with its verdict, from the log of ``benchmarks/run_all.sh``.

    python benchmarks/targets.py LOG

A figure measured several times in the log (``run_all.sh`` repeats the noisy ones) is judged by its median, and
every measurement is listed, since the machine's speed can swing within one run (docs/performance.md).
"""

from __future__ import annotations

import argparse
import re
import statistics
import sys
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True, slots=True, kw_only=True)
class Target:
    """One target: the log lines it reads (a regex whose group 1 is the value), the bound and its direction."""

    name: str
    pattern: str
    bound: float
    at_least: bool


TARGETS = (
    Target(name="format_io write vs plain write(), every CRC on (ratio)",
           pattern=r"^write throughput: .* ratio ([\d.]+)", bound=0.9, at_least=True),
    Target(name="format_io write, CPU time (ratio)", pattern=r"^write_cpu: .* ratio ([\d.]+)", bound=0.9, at_least=True),
    Target(name="format_io random cloud read vs np.fromfile (time ratio)",
           pattern=r"^random point-cloud read: .* ratio ([\d.]+)", bound=0.5, at_least=False),
    Target(name="tracking eval vs TrackEval, MOT17-like, CPU (x)",
           pattern=r"^tracking HOTA\+CLEAR\+Identity CPU time, MOT17-like density .* ratio ([\d.]+)x", bound=40.0,
           at_least=True),
    Target(name="tracking eval vs TrackEval, crowded, CPU (x)",
           pattern=r"^tracking HOTA\+CLEAR\+Identity CPU time, crowded .* ratio ([\d.]+)x", bound=30.0, at_least=True),
    Target(name="loaders ego frame vs hand loop, CPU (x)", pattern=r"^frame_dataset_cpu: .* ratio ([\d.]+)x",
           bound=2.0, at_least=True),
    Target(name="loaders world frame vs hand loop, CPU (x)",
           pattern=r"^frame_dataset_world_frame_cpu: .* ratio ([\d.]+)x", bound=2.0, at_least=True),
    Target(name="loaders collaborative vs hand loop, CPU (x)", pattern=r"^collaborative_cpu: .* ratio ([\d.]+)x",
           bound=2.0, at_least=True),
    Target(name="generate_lidar rays/s (M, wall)", pattern=r"^lidar rays/s .*: avdata ([\d.]+) M rays/s", bound=10.0,
           at_least=True),
    Target(name="object store: GETs per frame per sensor after opening",
           pattern=r"^object_store requests per frame per sensor: avdata ([\d.]+) GETs", bound=2.0, at_least=False),
    Target(name="one V2I frame (s, wall)", pattern=r"^v2i frame \(.*: avdata ([\d.]+) s/frame", bound=0.15,
           at_least=False),
    Target(name="avdata --help (s, wall)", pattern=r"^avdata --help\s+([\d.]+) s", bound=0.4, at_least=False),
    Target(name="avdata --help peak memory (MB)", pattern=r"^avdata --help\s+[\d.]+ s\s+([\d.]+) MB", bound=60.0,
           at_least=False),
    Target(name="avdata info (s, wall)", pattern=r"^avdata info DEMO\s+([\d.]+) s", bound=0.4, at_least=False),
    Target(name="avdata info peak memory (MB)", pattern=r"^avdata info DEMO\s+[\d.]+ s\s+([\d.]+) MB", bound=60.0,
           at_least=False),
)


def verdicts(log_text: str) -> list[tuple[Target, list[float], bool | None]]:
    """Per target: the values found in the log and whether their median meets it (None: not measured)."""
    out = []
    for target in TARGETS:
        values = [float(m.group(1)) for m in re.finditer(target.pattern, log_text, flags=re.MULTILINE)]
        if not values:
            out.append((target, values, None))
            continue
        median = statistics.median(values)
        out.append((target, values, median >= target.bound if target.at_least else median <= target.bound))
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log", type=Path, help="the log written by benchmarks/run_all.sh")
    args = parser.parse_args()
    results = verdicts(args.log.read_text())
    for target, values, met in results:
        sign = ">=" if target.at_least else "<="
        verdict = "not measured" if met is None else ("met" if met else "MISSED")
        shown = " / ".join(f"{v:g}" for v in values)
        print(f"{target.name}: target {sign} {target.bound:g}; measured {shown or '-'}: {verdict}")
    return 1 if any(met is False for _, _, met in results) else 0


if __name__ == "__main__":
    sys.exit(main())
