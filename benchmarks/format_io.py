"""Unified-format write and read speed, as ratios against plain file I/O in the same process.

Figures (issue 14, "Speed"):
  write throughput: a scene of 200 frames, each a 120k-point cloud (x, y, z, intensity float32)
      and one 1242x375 PNG, written with DatasetWriter (MCAP with a CRC-32 on every chunk, the
      data section and the summary, + manifest and Parquet index), against writing the same bytes
      with plain ``open().write()``. The inputs (arrays, pose, empty labels) are made before the
      clock starts for both. Target: ratio >= 0.9 (at least 0.8). Neither side calls fsync: the format
      promises whole files against a process that dies, not durability against power loss
      (docs/performance.md, "Write, second pass").
  write_mcap_cpu: the same messages through the MCAP layer alone (McapWriter: every CRC, chunk and message
      indexes; no scene checks, labels or Parquet index), CPU time against plain writes: what the checksums
      and the file layout cost, apart from the scene and index bookkeeping.
  random point-cloud read: one random frame's cloud through DatasetReader (page cache warm; a
      zero-copy view into the mapped file), against ``np.fromfile`` of the same points stored as
      a KITTI .bin. Target: time ratio <= 0.5.
  read into a caller's buffer: ``SceneReader.points_into`` (one ``preadv`` copy) against the same;
      and against ``np.fromfile`` of the same random frame's points from a flat file of all
      frames (both copies then read bytes that are not in the CPU cache).
  verified read: ``DatasetReader(verify=True)``, each frame read once, so every read checks its
      chunk's CRC; against ``np.fromfile``.

Inputs are the real KITTI velodyne sweep and image from ../shared/realdata (points repeated up to
120k). Usage: ``python benchmarks/format_io.py [--quick]``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from avdata.frames import Transform
from avdata.schema import DatasetReader, DatasetWriter, ObjectLabels
from avdata.schema.mcap.writer import McapWriter

#: The real KITTI sample (``AVDATA_REALDATA``, as in ``tests/realdata.py``, else the project's sibling ``shared/realdata``).
REALDATA = (Path(os.environ.get("AVDATA_REALDATA") or Path(__file__).resolve().parents[1].parent / "shared" / "realdata")
            / "kitti" / "object" / "training")
N_POINTS = 120_000


def load_inputs() -> tuple[np.ndarray, bytes]:
    sweep = np.fromfile(REALDATA / "velodyne" / "000000.bin", dtype=np.float32).reshape(-1, 4)
    reps = int(np.ceil(N_POINTS / len(sweep)))
    points = np.tile(sweep, (reps, 1))[:N_POINTS].copy()
    png = (REALDATA / "image_2" / "000000.png").read_bytes()
    return points, png


def write_avdata(root: Path, points: np.ndarray, png: bytes, n_frames: int) -> tuple[float, float]:
    structured = points.view(np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])).reshape(-1)
    pose = Transform.identity()
    labels = ObjectLabels.empty("world")
    start, cpu = time.perf_counter(), time.process_time()
    with DatasetWriter(root, source="benchmark") as writer:
        with writer.scene("bench") as scene:
            scene.add_static_transform("ego", "ego/lidar", pose)
            for i in range(n_frames):
                t = 1_000_000_000 + i * 100_000_000
                scene.add_transform("world", "ego", t, pose)
                scene.add_point_cloud("ego/lidar", t, structured)
                scene.add_image("ego/cam", t, png, "png")
                scene.add_frame(i, t, labels, {"ego/lidar": t, "ego/cam": t})
    return time.perf_counter() - start, time.process_time() - cpu


def write_mcap(path: Path, points: np.ndarray, png: bytes, n_frames: int) -> tuple[float, float]:
    cloud = memoryview(points).cast("B")
    start, cpu = time.perf_counter(), time.process_time()
    with open(path, "wb") as stream, McapWriter(stream, library="benchmark") as writer:
        schema = writer.register_schema("raw", "", b"")
        lidar = writer.register_channel("/ego/lidar/points", "", schema)
        camera = writer.register_channel("/ego/cam/image", "", schema)
        for i in range(n_frames):
            t = 1_000_000_000 + i * 100_000_000
            writer.add_message(lidar, t, t, i, [cloud])
            writer.add_message(camera, t, t, i, [png])
    return time.perf_counter() - start, time.process_time() - cpu


def write_plain(path: Path, points: np.ndarray, png: bytes, n_frames: int) -> tuple[float, float]:
    # The array's own memory, as the writer takes it: ``points.tobytes()`` here would add a copy of every
    # cloud to the baseline's cost, which avdata's writer does not pay.
    start, cpu = time.perf_counter(), time.process_time()
    with open(path, "wb") as stream:
        for _ in range(n_frames):
            stream.write(points.data)
            stream.write(png)
    return time.perf_counter() - start, time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="20 frames instead of 200")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    n_frames = 20 if args.quick else 200
    points, png = load_inputs()
    payload_mb = n_frames * (points.nbytes + len(png)) / 1e6
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        # Warm-up: imports, protobuf descriptor pools and the page cache's first allocation are
        # one-time costs that are not what the figure is about.
        write_avdata(tmp / "warmup", points, png, 2)
        ours, plain, mcap = [], [], []
        for repeat in range(args.repeats):
            if repeat:
                (tmp / "plain.bin").unlink()
                shutil.rmtree(tmp / "ds")
            plain.append(write_plain(tmp / "plain.bin", points, png, n_frames))
            ours.append(write_avdata(tmp / "ds", points, png, n_frames))
            mcap.append(write_mcap(tmp / "layer.mcap", points, png, n_frames))
            (tmp / "layer.mcap").unlink()
        ours_mbps, plain_mbps = payload_mb / min(t for t, _ in ours), payload_mb / min(t for t, _ in plain)
        print(f"write throughput: avdata {ours_mbps:.0f} MB/s, baseline open().write() {plain_mbps:.0f} MB/s, "
              f"ratio {ours_mbps / plain_mbps:.2f}")
        # CPU time (user + system, the page-cache copy included) moves less than wall time when
        # other jobs share the cores; on an idle machine the two ratios agree.
        ours_cpu, plain_cpu = min(c for _, c in ours), min(c for _, c in plain)
        print(f"write_cpu: avdata {payload_mb / ours_cpu:.0f} MB per CPU s, baseline {payload_mb / plain_cpu:.0f}, "
              f"ratio {plain_cpu / ours_cpu:.2f}")
        mcap_cpu = min(c for _, c in mcap)
        print(f"write_mcap_cpu: avdata MCAP layer {payload_mb / mcap_cpu:.0f} MB per CPU s, baseline "
              f"{payload_mb / plain_cpu:.0f}, ratio {plain_cpu / mcap_cpu:.2f}")

        kitti_bin = tmp / "000000.bin"
        points.tofile(kitti_bin)
        rng = np.random.default_rng(0)
        reader = DatasetReader(tmp / "ds")
        frames = rng.integers(0, n_frames, size=200)
        scene = reader.scene("bench")
        buffer = np.empty(points.nbytes, dtype=np.uint8)

        def fromfile(_frame: int) -> None:  # the same file whatever the frame
            np.fromfile(kitti_bin, dtype=np.float32).reshape(-1, 4)

        # The read figures are for a warm page cache, and a writer may drop its files' pages once
        # written back (past a tenth of memory per dataset), so both sides' files are read once first.
        for path in (*(tmp / "ds").rglob("*.mcap"), tmp / "plain.bin"):
            warm_page_cache(path)
        for frame in frames[:10]:
            reader.points("bench", int(frame), "ego/lidar")
            fromfile(int(frame))

        ours_ms, base_ms = time_pairs(frames, lambda f: reader.points("bench", f, "ego/lidar"), fromfile)
        print(f"random point-cloud read: avdata {ours_ms:.3f} ms, baseline np.fromfile {base_ms:.3f} ms, "
              f"ratio {ours_ms / base_ms:.2f}")

        def into(frame: int) -> None:
            scene.points_into("ego/lidar", reader.sensor_time("bench", frame, "ego/lidar"), buffer)

        ours_ms, base_ms = time_pairs(frames, into, fromfile)
        print(f"point-cloud read into a caller's buffer: avdata {ours_ms:.3f} ms, baseline np.fromfile "
              f"{base_ms:.3f} ms, ratio {ours_ms / base_ms:.2f}")
        frame_bytes = points.nbytes + len(png)
        ours_ms, base_ms = time_pairs(frames, into, lambda f: np.fromfile(
            tmp / "plain.bin", dtype=np.float32, count=points.size, offset=f * frame_bytes))
        print(f"  the same, baseline np.fromfile of the same random frame from a flat file: avdata {ours_ms:.3f} ms, "
              f"baseline {base_ms:.3f} ms, ratio {ours_ms / base_ms:.2f}")
        verified = DatasetReader(tmp / "ds", verify=True)
        once = rng.permutation(n_frames)  # every read is a chunk's first: its CRC is checked
        ours_ms, base_ms = time_pairs(once, lambda f: verified.points("bench", f, "ego/lidar"), fromfile)
        print(f"verified point-cloud read: avdata {ours_ms:.3f} ms, baseline np.fromfile {base_ms:.3f} ms, "
              f"ratio {ours_ms / base_ms:.2f}")


def warm_page_cache(path: Path) -> None:
    """Reads ``path`` once, so its pages are in the page cache."""
    buffer = bytearray(8 << 20)
    with open(path, "rb", buffering=0) as stream:
        while stream.readinto(buffer):
            pass


def time_pairs(frames: np.ndarray, ours: Callable[[int], object], baseline: Callable[[int], object]
               ) -> tuple[float, float]:
    """Median milliseconds of ``ours(frame)`` and ``baseline(frame)``, alternated so both see the same machine load."""
    ours_s, base_s = [], []
    for frame in frames:
        start = time.perf_counter()
        ours(int(frame))
        ours_s.append(time.perf_counter() - start)
        start = time.perf_counter()
        baseline(int(frame))
        base_s.append(time.perf_counter() - start)
    return 1e3 * float(np.median(ours_s)), 1e3 * float(np.median(base_s))


if __name__ == "__main__":
    main()
