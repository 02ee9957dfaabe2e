"""Benchmark: scenes per second on the executors (local pool, Ray with 1 and 2 workers), per-task
overhead, and a projection to full nuScenes and Waymo v2 on 1, 8 and 64 workers.

Input: the three real KITTI object samples of ../shared/realdata/kitti/object symlinked (never copied
into the repository) into a temporary ``training/`` of ``--samples`` samples, converted with
``--scene-size`` samples per scene, so every executor converts the same scenes. Each run starts from
an empty DST; Ray's start-up (``ray.init``) is timed separately and not counted in its runs.

Per-task overhead: the time an executor needs per task of a function that does nothing, over 200 tasks.

Projection (printed, and in README, as a projection, not a measurement): the single-Ray-worker
throughput measured here in source MB/s (whole run: listing, tasks, index) is applied to the published
sizes (nuScenes trainval ~300 GB in 850 scenes, Waymo v2 ~1 TB in 1,150 segments), plus the per-task
overhead per scene, divided by the workers: it assumes linear scaling (one scene per task, no shared
state) and a shared filesystem that delivers the aggregate bandwidth, and KITTI's per-byte cost for
formats that parse more (nuScenes JSON tables, Waymo range images).

    python benchmarks/scale.py [--quick]
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.kitti import KittiObjectConverter
from avdata.executors.base import Executor, LocalExecutor
from avdata.exporters.driver import ExportConfig
from avdata.exporters.kitti import export_kitti_object

REAL = (Path(os.environ.get("AVDATA_REALDATA") or Path(__file__).resolve().parents[1].parent / "shared" / "realdata")
        / "kitti" / "object" / "training")
FOLDERS = {"calib": ".txt", "label_2": ".txt", "velodyne": ".bin", "image_2": ".png"}
#: (name, source bytes, scenes) of the full datasets, as published.
FULL = [("nuScenes trainval", 300e9, 850), ("Waymo v2", 1.0e12, 1150)]


def build_source(root: Path, n_samples: int) -> int:
    """``root/training`` of ``n_samples`` samples, each a link to one of the three real ones; returns source bytes."""
    total = 0
    for folder, suffix in FOLDERS.items():
        (root / "training" / folder).mkdir(parents=True)
        for sample in range(n_samples):
            real = REAL / folder / f"{sample % 3:06d}{suffix}"
            (root / "training" / folder / f"{sample:06d}{suffix}").symlink_to(real)
            total += real.stat().st_size
    return total


def convert_seconds(src: Path, dst: Path, scene_size: int, executor: str, workers: int = 1) -> float:
    shutil.rmtree(dst, ignore_errors=True)
    start = time.perf_counter()
    result = run_conversion(KittiObjectConverter(ConvertConfig(
        src=src, dst=dst, quiet=True, executor=executor, workers=workers, options={"scene_size": scene_size})))
    seconds = time.perf_counter() - start
    if result.failed or result.n_errors:
        raise SystemExit(f"conversion failed: {result.problems[:3]}")
    return seconds


def export_seconds(dataset: Path, out: Path, executor: str, workers: int = 1) -> float:
    """One ``export kitti-object`` of the converted dataset into an empty ``out``."""
    shutil.rmtree(out, ignore_errors=True)
    start = time.perf_counter()
    result = export_kitti_object(dataset, out, config=ExportConfig(dataset=dataset, dst=out, executor=executor,
                                                                   workers=workers))
    seconds = time.perf_counter() - start
    if result.failed or result.n_errors:
        raise SystemExit(f"export failed: {result.problems[:3]}")
    return seconds


def _nothing(x: int) -> int:
    return x


def task_overhead_s(executor: Executor, n: int = 200) -> float:
    executor.map(_nothing, list(range(8)))  # workers started
    start = time.perf_counter()
    executor.map(_nothing, list(range(n)))
    return (time.perf_counter() - start) / n


def line(figure: str, value: float, unit: str, baseline: str, base_value: float, ratio: float) -> None:
    print(f"{figure}: avdata {value:.3g} {unit}, baseline {baseline} {base_value:.3g} {unit}, ratio {ratio:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="12 samples in 6 scenes instead of 96 in 24")
    args = parser.parse_args()
    n_samples, scene_size = (12, 2) if args.quick else (96, 4)
    n_scenes = n_samples // scene_size
    import ray

    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "src"
        source_bytes = build_source(src, n_samples)
        dst = Path(tmp) / "dst"
        convert_seconds(src, dst, scene_size, "local", 1)  # imports and page cache warm
        local1 = convert_seconds(src, dst, scene_size, "local", 1)
        local2 = convert_seconds(src, dst, scene_size, "local", 2)
        exported = Path(tmp) / "export"
        export_s = {"local-1": export_seconds(dst, exported, "local", 1), "local-2": export_seconds(dst, exported, "local", 2)}
        ray_s = {}
        ray_overhead = 0.0
        for cpus in (1, 2):
            start = time.perf_counter()
            ray.init(num_cpus=cpus, include_dashboard=False, log_to_driver=False, logging_level="ERROR")
            print(f"ray.init with {cpus} CPUs: {time.perf_counter() - start:.1f} s (not counted below)")
            convert_seconds(src, dst, scene_size, "ray")  # workers started and the code imported
            ray_s[cpus] = convert_seconds(src, dst, scene_size, "ray")
            if cpus == 2:
                export_s["ray-2"] = export_seconds(dst, exported, "ray")
                from avdata.executors.base import RayExecutor

                ray_overhead = task_overhead_s(RayExecutor())
            ray.shutdown()
        local_overhead = task_overhead_s(LocalExecutor(2))

    rate = {name: n_scenes / seconds for name, seconds in
            [("local-1", local1), ("local-2", local2), ("ray-1", ray_s[1]), ("ray-2", ray_s[2])]}
    print(f"input: {n_samples} KITTI object samples in {n_scenes} scenes, {source_bytes / 1e6:.0f} MB")
    line("scenes/s local pool 2 workers", rate["local-2"], "scenes/s", "local 1 worker", rate["local-1"],
         rate["local-2"] / rate["local-1"])
    line("scenes/s ray 1 worker", rate["ray-1"], "scenes/s", "local 1 worker", rate["local-1"], rate["ray-1"] / rate["local-1"])
    line("scenes/s ray 2 workers", rate["ray-2"], "scenes/s", "local 1 worker", rate["local-1"], rate["ray-2"] / rate["local-1"])
    line("scenes/s ray 2 workers vs local pool 2", rate["ray-2"], "scenes/s", "local 2 workers", rate["local-2"],
         rate["ray-2"] / rate["local-2"])
    for name in ("local-2", "ray-2"):
        line(f"export kitti-object scenes/s {name.replace('-', ' ')} workers", n_scenes / export_s[name], "scenes/s",
             "local 1 worker", n_scenes / export_s["local-1"], export_s["local-1"] / export_s[name])
    line("per-task overhead ray", ray_overhead * 1e3, "ms", "local pool", local_overhead * 1e3,
         ray_overhead / local_overhead)

    per_worker_bps = source_bytes / ray_s[1]
    print(f"projection (not a measurement): {per_worker_bps / 1e6:.0f} MB/s per Ray worker (measured with 1 worker, "
          f"whole run included), linear in the workers (measured here with 2: x{ray_s[1] / ray_s[2]:.2f} on a "
          f"2-core machine), plus {ray_overhead * 1e3:.1f} ms per task")
    for name, total_bytes, scenes in FULL:
        hours = []
        for workers in (1, 8, 64):
            seconds = (total_bytes / per_worker_bps + scenes * ray_overhead) / workers
            hours.append(f"{workers} workers {seconds / 3600:.2f} h")
        print(f"projection {name} ({total_bytes / 1e9:.0f} GB, {scenes} scenes): " + ", ".join(hours))

if __name__ == "__main__":
    main()
