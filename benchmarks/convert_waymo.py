"""Benchmark: Waymo v2 conversion throughput, avdata vs ``shutil.copytree`` of the same files.

Input: a segment of N frames built under a temporary folder from the real-data v2 fixture (the real v1
frame turned into v2 components by Waymo's own compat_v1, with range images made from its real laser
calibrations; tests/oracles/waymo_fixture.py, which needs the waymo oracle venv). Every frame-keyed
component is repeated N times with its times shifted by 0.1 s per frame (pyarrow only), one row group
per frame, written with pyarrow's defaults as Waymo's own ``compat_v1`` output is. Reports input MB/s
of a fresh conversion (best of the repeats) against copying the files, and the peak resident memory of
one conversion run alone (``avdata convert waymo`` in a child process) for 1/4 and all of the frames.

    python benchmarks/convert_waymo.py [--quick] [--frames N]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.waymo import WaymoConverter

TESTS = Path(__file__).resolve().parents[1] / "tests" / "oracles"
TIME_KEY = "key.frame_timestamp_micros"
POSE_TIME = "[CameraImageComponent].pose_timestamp"
FRAME_STEP_US = 100_000


def build_segment(fixture: Path, dst: Path, n_frames: int) -> None:
    """``dst/<component>/<context>.parquet`` with every frame-keyed component repeated ``n_frames`` times."""
    for path in sorted(fixture.glob("*/*.parquet")):
        table = pq.read_table(path)
        out = dst / path.parent.name / path.name
        out.parent.mkdir(parents=True, exist_ok=True)
        if TIME_KEY not in table.column_names:
            pq.write_table(table, out)
            continue
        with pq.ParquetWriter(out, table.schema) as writer:
            for k in range(n_frames):
                shifted = table.set_column(table.schema.get_field_index(TIME_KEY), TIME_KEY,
                                           pc.add(table.column(TIME_KEY), pa.scalar(k * FRAME_STEP_US, pa.int64())))
                if POSE_TIME in table.column_names:
                    shifted = shifted.set_column(shifted.schema.get_field_index(POSE_TIME), POSE_TIME,
                                                 pc.add(table.column(POSE_TIME), k * FRAME_STEP_US * 1e-6))
                writer.write_table(shifted)


def folder_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def best_time(function, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - start)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="5 frames, one repeat")
    parser.add_argument("--frames", type=int, default=None, help="frames in the segment (default 20, quick 5)")
    args = parser.parse_args()
    n_frames = args.frames or (5 if args.quick else 20)
    repeats = 1 if args.quick else 3
    sys.path.insert(0, str(TESTS))
    from waymo_fixture import waymo_v2_fixture

    fixture, _ = waymo_v2_fixture()
    with tempfile.TemporaryDirectory(prefix="avdata-bench-waymo-") as tmp:
        src, copy_dst, dst = Path(tmp) / "src", Path(tmp) / "copy", Path(tmp) / "out"
        build_segment(fixture, src, n_frames)
        mb = folder_bytes(src) / 1e6
        print(f"waymo v2 input: 1 segment of {n_frames} frames (5 lidars with both returns, 5 cameras, 75 boxes "
              f"per frame), {mb:.0f} MB")

        def copy() -> None:
            shutil.rmtree(copy_dst, ignore_errors=True)
            shutil.copytree(src, copy_dst)

        def convert() -> None:
            shutil.rmtree(dst, ignore_errors=True)
            result = run_conversion(WaymoConverter(ConvertConfig(src=src, dst=dst, quiet=True)))
            if result.n_errors or result.failed:
                raise RuntimeError(f"conversion had errors: {[str(p) for p in result.problems][:3]}")

        copy_s = best_time(copy, repeats)
        convert_s = best_time(convert, repeats)
        avdata_mbps, copy_mbps = mb / convert_s, mb / copy_s
        print(f"segment input throughput (1 worker): avdata {avdata_mbps:.1f} MB/s, baseline shutil.copytree "
              f"{copy_mbps:.1f} MB/s, ratio {avdata_mbps / copy_mbps:.2f}")
        for frames in sorted({max(1, n_frames // 4), n_frames}):
            small = Path(tmp) / f"src{frames}"
            if frames != n_frames:
                build_segment(fixture, small, frames)
            peak_mb = child_peak_mb(small if frames != n_frames else src, Path(tmp) / f"out{frames}")
            print(f"peak resident memory of one conversion, {frames} frames: {peak_mb:.0f} MB")


def child_peak_mb(src: Path, dst: Path) -> float:
    """Peak RSS (MB) of ``avdata convert waymo SRC DST`` run alone in a child process (its own getrusage)."""
    code = ("import resource, sys; from avdata.cli import main; main(sys.argv[1:]); "
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)")
    process = subprocess.run([sys.executable, "-c", code, "convert", "waymo", str(src), str(dst), "--quiet"],
                             check=True, capture_output=True, text=True)
    return int(process.stdout.strip().splitlines()[-1]) / 1024

if __name__ == "__main__":
    main()
