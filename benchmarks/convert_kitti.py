"""Benchmark: KITTI conversion throughput, avdata vs kitti2mcap 0.1.1 and vs ``shutil.copytree``.

Inputs are built under a temporary folder from the real files in ../shared/realdata/kitti (copied
into the temporary folder, never into the repository):

- raw: a 100-frame drive in the raw layout (``2011_09_26/2011_09_26_drive_0001_sync``) with the
  real 2011_09_26 calibration and timestamps, the tracking sample's two velodyne sweeps and stereo
  PNGs repeated for every frame (image_02/03 also stand in for the grey image_00/01), and the
  tracking sequence's real oxts packets; all four cameras + velodyne, ~500 MB.
- object: the three real object samples repeated to 500 samples (``training/``).

kitti2mcap is installed into a temporary virtual environment (``python -m venv`` + pip) and run on
the same drive with all four cameras; if that fails the script says so and prints the other figures.
avdata and the copies take turns within each of the repeats (best of 3 each); the object figure is
also given against a plain read()/write() copy of every file, whose speed swings less than copytree's.

    python benchmarks/convert_kitti.py [--quick]
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.kitti import KittiObjectConverter, KittiRawConverter

REAL = Path(os.environ.get("AVDATA_REALDATA") or Path(__file__).resolve().parents[1].parent / "shared" / "realdata") / "kitti"
RAW_DAY = REAL / "raw" / "2011_09_26"
TRACKING = REAL / "tracking" / "training"
DATE = "2011_09_26"


def folder_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def build_raw_drive(root: Path, drive: str, n_frames: int) -> Path:
    """One raw-layout drive of ``n_frames`` frames from real files (see the module docstring)."""
    day = root / DATE
    day.mkdir(parents=True, exist_ok=True)
    for name in ("calib_cam_to_cam.txt", "calib_imu_to_velo.txt", "calib_velo_to_cam.txt"):
        shutil.copyfile(RAW_DAY / name, day / name)
    path = day / f"{DATE}_drive_{drive}_sync"
    oxts = (TRACKING / "oxts" / "0001.txt").read_text().splitlines()
    sources = {
        "velodyne_points": [TRACKING / "velodyne" / "0001" / f"00000{k}.bin" for k in (0, 1)],
        "image_00": [TRACKING / "image_02" / "0001" / f"00000{k}.png" for k in (0, 1)],
        "image_01": [TRACKING / "image_03" / "0001" / f"00000{k}.png" for k in (0, 1)],
        "image_02": [TRACKING / "image_02" / "0001" / f"00000{k}.png" for k in (0, 1)],
        "image_03": [TRACKING / "image_03" / "0001" / f"00000{k}.png" for k in (0, 1)],
    }
    for folder in [*sources, "oxts"]:
        (path / folder / "data").mkdir(parents=True)
        real = (RAW_DAY / f"{DATE}_drive_0001_sync" / folder / "timestamps.txt").read_text().splitlines()
        (path / folder / "timestamps.txt").write_text("\n".join(real[:n_frames]) + "\n")
    for folder in ("velodyne_points",):
        for name in ("timestamps_start.txt", "timestamps_end.txt"):
            real = (RAW_DAY / f"{DATE}_drive_0001_sync" / folder / name).read_text().splitlines()
            (path / folder / name).write_text("\n".join(real[:n_frames]) + "\n")
    shutil.copyfile(RAW_DAY / f"{DATE}_drive_0001_sync" / "oxts" / "dataformat.txt", path / "oxts" / "dataformat.txt")
    for frame in range(n_frames):
        (path / "oxts" / "data" / f"{frame:010d}.txt").write_text(oxts[frame] + "\n")
        for folder, files in sources.items():
            source = files[frame % 2]
            shutil.copyfile(source, path / folder / "data" / f"{frame:010d}{source.suffix}")
    return path


def build_object(root: Path, n_samples: int) -> Path:
    """``training/`` with the three real object samples repeated to ``n_samples``."""
    folders = {"calib": ".txt", "label_2": ".txt", "velodyne": ".bin", "image_2": ".png"}
    for folder, suffix in folders.items():
        (root / "training" / folder).mkdir(parents=True)
        for sample in range(n_samples):
            shutil.copyfile(REAL / "object" / "training" / folder / f"{sample % 3:06d}{suffix}",
                            root / "training" / folder / f"{sample:06d}{suffix}")
    return root


def cpu_seconds() -> float:
    """User + system time of this process and its finished children (the conversion's worker processes)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def timed(function) -> tuple[float, float]:
    """(wall, CPU) seconds of ``function()``."""
    start, cpu_start = time.perf_counter(), cpu_seconds()
    function()
    return time.perf_counter() - start, cpu_seconds() - cpu_start


def interleaved(runs: dict[str, tuple[Callable[[], object], Path]], repeats: int) -> dict[str, tuple[float, float]]:
    """name -> (best wall, best CPU) seconds of ``repeats`` passes, the runs taking turns within each pass.

    Taking turns puts every side in the same minutes of a shared machine, whose file-copy speed can swing
    severalfold within an hour (docs/performance.md): sides measured one after the other would catch
    different phases of it. Each run's ``dst`` is removed before
    it and after the last pass.
    """
    best = {name: (float("inf"), float("inf")) for name in runs}
    for _ in range(repeats):
        for name, (function, dst) in runs.items():
            shutil.rmtree(dst, ignore_errors=True)
            wall, cpu = timed(function)
            # Removed at once: the outputs of all sides kept together would pass the kernel's dirty-page
            # limits, and the next run would be throttled while they are written back.
            shutil.rmtree(dst, ignore_errors=True)
            best[name] = (min(best[name][0], wall), min(best[name][1], cpu))
    return best


def avdata_run(converter_class, src: Path, dst: Path, workers: int) -> tuple[Callable[[], None], Path]:
    """A fresh conversion of ``src`` into ``dst`` (raises if it reports any error)."""

    def run() -> None:
        result = run_conversion(converter_class(ConvertConfig(src=src, dst=dst, workers=workers, quiet=True)))
        if result.n_errors or result.failed:
            raise RuntimeError(f"avdata conversion had errors: {[str(p) for p in result.problems][:3]}")

    return run, dst


def copytree_run(src: Path, dst: Path) -> tuple[Callable[[], object], Path]:
    """``shutil.copytree`` (in-kernel ``sendfile`` per file on Linux)."""
    return (lambda: shutil.copytree(src, dst)), dst


def read_write_run(src: Path, dst: Path) -> tuple[Callable[[], None], Path]:
    """Every file read into memory and written with plain ``read()`` / ``write()``: the bytes pass through
    the process once, as they must for a converter that checks them; a steadier baseline than copytree's."""

    def run() -> None:
        for path in sorted(src.rglob("*")):
            target = dst / path.relative_to(src)
            if path.is_dir():
                target.mkdir(parents=True)
            else:
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(path.read_bytes())

    return run, dst


def install_kitti2mcap(venv: Path) -> tuple[Path | None, str]:
    """(path of the kitti2mcap command, "") or (None, why it is unavailable)."""
    try:
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, capture_output=True, text=True)
        subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "-q", "kitti2mcap==0.1.1"],
                       check=True, capture_output=True, text=True, timeout=600)
    except (subprocess.SubprocessError, OSError) as error:
        detail = getattr(error, "stderr", "") or str(error)
        return None, f"could not install kitti2mcap==0.1.1: {detail.strip().splitlines()[-1] if detail else error}"
    return venv / "bin" / "kitti2mcap", ""


def run_kitti2mcap(command: Path, kitti_dir: Path, output: Path) -> tuple[float | None, str]:
    start = time.perf_counter()
    process = subprocess.run([str(command), "--date", DATE, "--drive", "0001", "--kitti-dir", str(kitti_dir),
                              "--output", str(output), "--cameras", "0,1,2,3"], capture_output=True, text=True)
    elapsed = time.perf_counter() - start
    if process.returncode:
        return None, f"kitti2mcap failed: {(process.stderr or process.stdout).strip().splitlines()[-1:]}"
    return elapsed, ""


def line(figure: str, value: float, unit: str, baseline: str, baseline_value: float) -> None:
    print(f"{figure}: avdata {value:.1f} {unit}, baseline {baseline} {baseline_value:.1f} {unit}, "
          f"ratio {value / baseline_value:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="20-frame drive and 60 object samples")
    args = parser.parse_args()
    n_raw, n_object, repeats = (20, 60, 1) if args.quick else (100, 500, 3)
    with tempfile.TemporaryDirectory(prefix="avdata-bench-kitti-") as tmp:
        tmp_path = Path(tmp)
        raw_src = tmp_path / "raw"
        build_raw_drive(raw_src, "0001", n_raw)
        raw_mb = folder_bytes(raw_src) / 1e6
        print(f"raw input: {n_raw} frames, velodyne + 4 cameras, {raw_mb:.0f} MB")
        best = interleaved({"copy": copytree_run(raw_src, tmp_path / "raw-copy"),
                            "avdata": avdata_run(KittiRawConverter, raw_src, tmp_path / "raw-avdata", 1)}, repeats)
        (copy_s, copy_cpu), (avdata_s, avdata_cpu) = best["copy"], best["avdata"]
        avdata_mbps = raw_mb / avdata_s
        command, why = install_kitti2mcap(tmp_path / "venv")
        k2m_s = None
        if command is not None:
            k2m_s, why = run_kitti2mcap(command, raw_src, tmp_path / "kitti2mcap.mcap")
        if k2m_s is None:
            print(f"raw drive input throughput (1 worker): avdata {avdata_mbps:.1f} MB/s; baseline kitti2mcap "
                  f"unavailable ({why})")
        else:
            line("raw drive input throughput (1 worker)", avdata_mbps, "MB/s", "kitti2mcap-0.1.1", raw_mb / k2m_s)
        line("raw drive input throughput vs copy (1 worker)", avdata_mbps, "MB/s", "shutil.copytree", raw_mb / copy_s)
        line("raw drive input per CPU second vs copy (1 worker)", raw_mb / avdata_cpu, "MB/s", "shutil.copytree",
             raw_mb / copy_cpu)

        # Scaling: scenes are the unit of parallel work, so two drives for two workers.
        build_raw_drive(raw_src, "0002", n_raw)
        two_mb = folder_bytes(raw_src) / 1e6
        best = interleaved({str(workers): avdata_run(KittiRawConverter, raw_src, tmp_path / f"raw2-avdata-{workers}",
                                                     workers) for workers in (1, 2)}, repeats)
        one_worker, two_workers = best["1"][0], best["2"][0]
        line("raw 2 drives input throughput, 2 workers vs 1", two_mb / two_workers, "MB/s", "avdata-1-worker",
             two_mb / one_worker)
        shutil.rmtree(raw_src)

        object_src = build_object(tmp_path / "object", n_object)
        object_mb = folder_bytes(object_src) / 1e6
        print(f"object input: {n_object} samples, {object_mb:.0f} MB")
        best = interleaved({
            "copytree": copytree_run(object_src, tmp_path / "object-copy"),
            "read-write": read_write_run(object_src, tmp_path / "object-read-write"),
            **{str(workers): avdata_run(KittiObjectConverter, object_src, tmp_path / f"object-avdata-{workers}", workers)
               for workers in (1, 2)},
        }, repeats)
        copy_s, copy_cpu = best["copytree"]
        for workers in (1, 2):
            seconds, cpu = best[str(workers)]
            plural = "s" if workers > 1 else ""
            line(f"object {n_object} samples input throughput ({workers} worker{plural})",
                 object_mb / seconds, "MB/s", "shutil.copytree", object_mb / copy_s)
            # On a shared machine the wall times swing with the other jobs' disk writes; CPU time much less.
            line(f"object {n_object} samples input per CPU second ({workers} worker{plural})",
                 object_mb / cpu, "MB/s", "shutil.copytree", object_mb / copy_cpu)
        line(f"object {n_object} samples input throughput (1 worker) vs read/write copy", object_mb / best["1"][0],
             "MB/s", "read-write-copy", object_mb / best["read-write"][0])

if __name__ == "__main__":
    main()
