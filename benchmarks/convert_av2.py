"""Benchmark: Argoverse 2 conversion, avdata vs a loop over av2-api's own AV2SensorDataLoader and vs copytree.

Input: LOGS copies of the real val log (../shared/realdata/argoverse2/sensor/val/<log>) under new log
ids, each complete: the real annotations.feather (11,364 cuboids at 156 sweep times; ``--quick``
keeps the real rows of the first 30 times), poses, calibration and map, and one sweep per annotated
time (the sample ships 2 real sweeps of ~100k points; every sweep file is a copy of one of them,
so the bytes read are real AV2 sweeps). Input MB = the bytes of the files each side reads (sweeps,
annotations, poses, calibration).

Sides, each in its own process (wall time, CPU time, peak RSS):
- avdata: ``run_conversion`` (one worker) -> MCAP + Parquet index.
- av2 loop (in ``.oracle-envs/av2``): per log ``AV2SensorDataLoader``; per sweep ``Sweep.from_feather``,
  ``get_city_SE3_ego``, ``get_labels_at_lidar_timestamp`` -> ``CuboidList.transform(city_SE3_ego)``;
  the same outputs (points, pose, cuboids in the city frame with categories, camera calibrations)
  pickled to one file per log (av2 0.3.6's ``Cuboid`` drops ``track_uuid``; avdata keeps it).
- copytree: ``shutil.copytree`` of the same files (a lower bound on any conversion's I/O).

    python benchmarks/convert_av2.py [--quick] [--keep]
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
REAL_LOG = REPO.parent / "shared" / "realdata" / "argoverse2" / "sensor" / "val" / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"
READ_FILES = ("annotations.feather", "city_SE3_egovehicle.feather", "calibration/egovehicle_SE3_sensor.feather",
              "calibration/intrinsics.feather")


def build(root: Path, n_logs: int, n_times: int | None) -> int:
    """``root/val/<log>`` x n_logs; returns the input bytes a conversion reads."""
    import numpy as np
    import pyarrow.feather as feather

    annotations = feather.read_table(REAL_LOG / "annotations.feather")
    times = np.unique(annotations.column("timestamp_ns").to_numpy())
    if n_times is not None:
        times = times[:n_times]
        annotations = annotations.filter(np.isin(annotations.column("timestamp_ns").to_numpy(), times))
    sweeps = sorted((REAL_LOG / "sensors" / "lidar").glob("*.feather"))
    total = 0
    for i in range(n_logs):
        log = root / "val" / f"{i:08d}-0000-4000-8000-000000000000"
        (log / "calibration").mkdir(parents=True)
        (log / "sensors" / "lidar").mkdir(parents=True)
        feather.write_feather(annotations, log / "annotations.feather")
        for name in READ_FILES[1:]:
            shutil.copyfile(REAL_LOG / name, log / name)
        shutil.copytree(REAL_LOG / "map", log / "map")
        for k, time_ns in enumerate(times.tolist()):
            shutil.copyfile(sweeps[k % len(sweeps)], log / "sensors" / "lidar" / f"{time_ns}.feather")
        total += sum(p.stat().st_size for p in (log / "sensors" / "lidar").iterdir())
        total += sum((log / name).stat().st_size for name in READ_FILES)
    return total


def run_avdata(src: Path, dst: Path) -> dict:
    from avdata.converters import ConvertConfig, run_conversion
    from avdata.converters.argoverse2 import Argoverse2Converter

    start, cpu_start = time.perf_counter(), _cpu_seconds()
    result = run_conversion(Argoverse2Converter(ConvertConfig(src=src, dst=dst, quiet=True)))
    seconds, cpu = time.perf_counter() - start, _cpu_seconds() - cpu_start
    if result.failed or result.n_errors:
        raise SystemExit(f"avdata conversion failed: {result.problems[:3]}")
    return {"seconds": seconds, "cpu_seconds": cpu, "peak_mb": _peak_mb(), "logs": len(result.written)}


def run_av2_loop(src: Path, dst: Path) -> dict:
    """The obvious conversion with av2's own loader (run with the oracle venv's python)."""
    import pickle

    import numpy as np
    from av2.datasets.sensor.av2_sensor_dataloader import AV2SensorDataLoader
    from av2.structures.sweep import Sweep

    start, cpu_start = time.perf_counter(), _cpu_seconds()
    split = src / "val"
    loader = AV2SensorDataLoader(data_dir=split, labels_dir=split)
    dst.mkdir(parents=True, exist_ok=True)
    logs = loader.get_log_ids()
    for log in logs:
        with open(dst / f"{log}.pkl", "wb") as out:
            cameras = {}
            for camera in ("ring_front_center", "ring_front_left", "ring_front_right", "ring_rear_left",
                           "ring_rear_right", "ring_side_left", "ring_side_right", "stereo_front_left",
                           "stereo_front_right"):
                pinhole = loader.get_log_pinhole_camera(log, camera)
                cameras[camera] = (pinhole.ego_SE3_cam.transform_matrix, pinhole.intrinsics.K)
            pickle.dump(cameras, out)
            for time_ns in loader.get_ordered_log_lidar_timestamps(log):
                sweep = Sweep.from_feather(loader.get_lidar_fpath(log, time_ns))
                city_SE3_ego = loader.get_city_SE3_ego(log, time_ns)
                cuboids = loader.get_labels_at_lidar_timestamp(log, time_ns).transform(city_SE3_ego)
                pickle.dump({
                    "timestamp_ns": time_ns,
                    "xyz": sweep.xyz.astype(np.float32),
                    "intensity": sweep.intensity,
                    "laser_number": sweep.laser_number,
                    "offset_ns": sweep.offset_ns,
                    "city_SE3_ego": city_SE3_ego.transform_matrix,
                    "cuboids": [(c.category, c.dst_SE3_object.transform_matrix, c.dims_lwh_m, c.timestamp_ns)
                                for c in cuboids.cuboids],
                }, out)
    seconds, cpu = time.perf_counter() - start, _cpu_seconds() - cpu_start
    return {"seconds": seconds, "cpu_seconds": cpu, "peak_mb": _peak_mb(), "logs": len(logs)}


def run_copytree(src: Path, dst: Path) -> dict:
    start, cpu_start = time.perf_counter(), _cpu_seconds()
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("map"))
    seconds, cpu = time.perf_counter() - start, _cpu_seconds() - cpu_start
    return {"seconds": seconds, "cpu_seconds": cpu, "peak_mb": _peak_mb(), "logs": len(list((dst / "val").iterdir()))}


def measure(python: Path, side: str, src: Path, dst: Path) -> dict:
    proc = subprocess.run([str(python), __file__, f"--{side}", str(src), str(dst)], capture_output=True, text=True,
                          cwd=REPO)
    if proc.returncode:
        raise SystemExit(f"{side} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1 log of 30 sweeps (else 3 logs of 156 sweeps)")
    parser.add_argument("--keep", action="store_true", help="keep the temporary folder")
    for side in ("avdata", "av2-loop", "copytree"):
        parser.add_argument(f"--{side}", nargs=2, type=Path, metavar=("SRC", "DST"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    for mode, run in ((args.avdata, run_avdata), (args.av2_loop, run_av2_loop), (args.copytree, run_copytree)):
        if mode:
            print(json.dumps(run(*mode)))
            return
    oracle = REPO / ".oracle-envs" / "av2" / "bin" / "python"
    if not oracle.exists():
        raise SystemExit(f"baseline env missing at {oracle}; run tests/oracles/make_envs.sh")
    n_logs, n_times = (1, 30) if args.quick else (3, None)
    work = Path(tempfile.mkdtemp(prefix="bench_av2_"))
    try:
        single = work / "single"
        one_log_mb = build(single, 1, n_times) / 1e6
        src = work / "src"
        input_mb = build(src, n_logs, n_times) / 1e6
        print(f"input: {n_logs} logs, {input_mb:.0f} MB read (sweeps, annotations, poses, calibration); "
              f"machine: {_machine()}", flush=True)
        ours = measure(Path(sys.executable), "avdata", src, work / "avdata")
        shutil.rmtree(work / "avdata")
        base = measure(oracle, "av2-loop", src, work / "av2")
        shutil.rmtree(work / "av2")
        copy = measure(Path(sys.executable), "copytree", src, work / "copy")
        shutil.rmtree(work / "copy")
        ours_single = measure(Path(sys.executable), "avdata", single, work / "avdata_single")
        assert ours["logs"] == base["logs"] == n_logs
        for name, other in (("av2 AV2SensorDataLoader loop", base), ("shutil.copytree", copy)):
            print(f"convert throughput: avdata {input_mb / ours['seconds']:.1f} MB/s, baseline {name} "
                  f"{input_mb / other['seconds']:.1f} MB/s, ratio {other['seconds'] / ours['seconds']:.2f}x")
        print(f"convert cpu time: avdata {ours['cpu_seconds']:.2f} s, baseline av2 loop {base['cpu_seconds']:.2f} s, "
              f"ratio {base['cpu_seconds'] / ours['cpu_seconds']:.1f}x")
        print(f"convert peak memory: avdata {ours['peak_mb']:.0f} MB ({n_logs} logs), baseline avdata on 1 log "
              f"({one_log_mb:.0f} MB input) {ours_single['peak_mb']:.0f} MB, ratio "
              f"{ours['peak_mb'] / ours_single['peak_mb']:.2f}x")
        print(f"convert peak memory vs av2 loop: avdata {ours['peak_mb']:.0f} MB, baseline av2 loop "
              f"{base['peak_mb']:.0f} MB, ratio {base['peak_mb'] / ours['peak_mb']:.2f}x")
    finally:
        if args.keep:
            print(f"kept {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)


def _cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _machine() -> str:
    import os
    import platform

    return f"{platform.processor() or platform.machine()}, {os.cpu_count()} cpus"


if __name__ == "__main__":
    main()
