"""Loader throughput: avdata's FrameDataset against a hand-written KITTI-files loader, same frames.

Figures (samples per second through a ``torch.utils.data.DataLoader`` with 2 workers, batch 4,
``collate_list``, one warm epoch each, best of ``--repeats`` passes interleaved with the baseline's;
each figure has a ``<figure>_cpu`` line too: CPU milliseconds per sample of the main process and its
workers together, least of the passes, which a busy shared machine barely changes; its ratio is
baseline / avdata, so > 1 means avdata is cheaper):

- ``frame_dataset``: ``FrameDataset(sensors="ego/velodyne", frame="ego")`` points + boxes against the
  usual KITTI training set-up: ``velodyne/*.bin`` read with ``np.fromfile``, ``label_2/*.txt`` and
  ``calib/*.txt`` parsed per sample, camera boxes moved into the velodyne frame with numpy. As in
  avdata's KITTI conversion, the ego frame is the velodyne frame, so neither side moves points.
- ``frame_dataset_world_frame``: the same items asked in ``world`` (every point moved), against the same
  hand-written loader moving its points and boxes into the world frame by a pose file per frame (until
  2026-11-29 this figure compared with the ego-frame loader, which moves nothing: not the same items). What a
  non-identity frame costs avdata is the difference of the two figures' avdata CPU times.
- ``collaborative``: ego + 8 infrastructure lidars, everything in the ego frame and fused early,
  against a hand-written loader reading 9 ``.bin`` files and a pose file per frame.

The data are synthetic but KITTI-shaped (~120k points per ego sweep, 60k per infrastructure sweep,
~15 labelled objects), written once into both layouts under a temporary folder (~19 MB per frame for
both layouts together: ~1.9 GB at the default 100 frames).

CPU time is read from each thread's ``/proc/<pid>/task/<tid>/schedstat`` (nanoseconds on the CPU; where
the kernel keeps none, from clock ticks of 10 ms, which resolve only 10 / F ms per sample for a pass of F
frames). On a machine shared with other work the CPU figures still rise with the load (caches and memory
bandwidth are shared: on the Xeon an ego item cost 1.4 ms of CPU at load 4 and 2.1–3.6 ms at load 11), so judge the
targets from a default run (100 frames) on a quiet machine. To compare two versions of the loaders on a
busy machine, compare their ratios from runs at the same time, or their instruction counts
(``valgrind --tool=callgrind``).

Usage: ``python benchmarks/loaders.py [--quick] [--frames N] [--repeats R]``
"""

from __future__ import annotations

import argparse
import os

# One BLAS thread per process for both loaders: with 2 workers on 2 cores, OpenBLAS's own threads
# oversubscribe the CPU and slow the hand-written collaborative loader's (N, 3) @ (3, 3) severalfold.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from torch.utils.data import DataLoader, Dataset  # noqa: E402

from avdata.frames import Boxes3D, Transform  # noqa: E402
from avdata.loaders import Collaboration, FrameDataset, FrameOptions, LabelFilter, collate_list  # noqa: E402
from avdata.schema import DatasetWriter, ObjectLabels  # noqa: E402

PERIOD_NS = 100_000_000
CLASSES = ("car", "pedestrian", "cyclist")
KITTI_NAMES = {"car": "Car", "pedestrian": "Pedestrian", "cyclist": "Cyclist"}
#: KITTI's rectified camera 0 in the velodyne frame (rounded from a real calibration file).
VELO_T_CAM = Transform(rotation=np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]),
                       translation=np.array([0.27, 0.0, -0.08]))
#: As the KITTI converter writes it: the ego body frame is the velodyne frame.
EGO_T_VELO = Transform.identity()
N_INFRA = 8


def synthetic_cloud(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 4) float32 x, y, z, intensity."""
    cloud = np.empty((n, 4), dtype=np.float32)
    cloud[:, :2] = rng.uniform(-70.0, 70.0, (n, 2))
    cloud[:, 2] = rng.uniform(-2.0, 1.0, n)
    cloud[:, 3] = rng.uniform(0.0, 1.0, n)
    return cloud


def synthetic_boxes(rng: np.random.Generator, world_T_ego: Transform, k: int) -> Boxes3D:
    n = int(rng.integers(10, 20))
    classes = rng.choice(CLASSES, n)
    centers_ego = np.c_[rng.uniform(5, 60, n), rng.uniform(-20, 20, n), np.full(n, 0.8)]
    return Boxes3D.from_yaw(world_T_ego.apply(centers_ego), np.c_[rng.uniform(0.5, 5, n), rng.uniform(0.5, 2, n),
                            rng.uniform(1.4, 2, n)], rng.uniform(-np.pi, np.pi, n), "world",
                            ids=np.array([f"{k}_{i}" for i in range(n)]), classes=classes)


def world_T_ego_at(k: int) -> Transform:
    return Transform.from_yaw(0.01 * k, np.array([2.0 * k, 0.5 * k, 0.0]))


def world_T_infra(i: int) -> Transform:
    return Transform.from_yaw(i * np.pi / 4, np.array([40.0 * np.cos(i), 40.0 * np.sin(i), 0.0]))


INFRA_T_LIDAR = Transform.from_euler("ZYX", np.array([0.0, np.pi / 6, 0.0]), np.array([0.0, 0.0, 15.0]))


def write_data(root: Path, frames: int, ego_points: int, infra_points: int) -> tuple[Path, Path]:
    """Writes the same frames as an avdata dataset and as KITTI-style files; returns both folders."""
    rng = np.random.default_rng(0)
    avdata_root, kitti_root = root / "avdata", root / "kitti"
    for folder in ("velodyne", "label_2", "calib", "infra", "poses"):
        (kitti_root / folder).mkdir(parents=True, exist_ok=True)
    tr_velo_to_cam = VELO_T_CAM.inverse().as_matrix()[:3, :]
    calib_text = "\n".join([f"P2: {' '.join(['0'] * 12)}", f"R0_rect: {' '.join(map(str, np.eye(3).ravel()))}",
                            f"Tr_velo_to_cam: {' '.join(map(str, tr_velo_to_cam.ravel()))}"]) + "\n"
    with DatasetWriter(avdata_root, source="benchmark") as writer:
        for start in range(0, frames, 100):
            with writer.scene(f"bench_{start:06d}") as scene:
                scene.add_agent("ego", kind="vehicle", origin="rear axle")
                scene.add_sensor("ego/velodyne", kind="lidar")
                scene.add_static_transform("ego", "ego/velodyne", EGO_T_VELO)
                for i in range(N_INFRA):
                    scene.add_agent(f"infra_{i:02d}", kind="infrastructure", origin="pole foot")
                    scene.add_sensor(f"infra_{i:02d}/lidar", kind="lidar")
                    scene.add_static_transform("world", f"infra_{i:02d}", world_T_infra(i))
                    scene.add_static_transform(f"infra_{i:02d}", f"infra_{i:02d}/lidar", INFRA_T_LIDAR)
                for k in range(start, min(start + 100, frames)):
                    t = (k - start) * PERIOD_NS
                    world_T_ego = world_T_ego_at(k)
                    scene.add_transform("world", "ego", t, world_T_ego)
                    cloud = synthetic_cloud(rng, ego_points)
                    scene.add_point_cloud("ego/velodyne", t, {n: cloud[:, i] for i, n in enumerate("x y z intensity".split())})
                    cloud.tofile(kitti_root / "velodyne" / f"{k:06d}.bin")
                    times = {"ego/velodyne": t}
                    poses = [(world_T_ego @ EGO_T_VELO).as_matrix()[:3, :].ravel()]
                    for i in range(N_INFRA):
                        infra = synthetic_cloud(rng, infra_points)
                        sensor = f"infra_{i:02d}/lidar"
                        scene.add_point_cloud(sensor, t, {n: infra[:, j] for j, n in enumerate("x y z intensity".split())})
                        infra.tofile(kitti_root / "infra" / f"{k:06d}_{i:02d}.bin")
                        times[sensor] = t
                        poses.append((world_T_infra(i) @ INFRA_T_LIDAR).as_matrix()[:3, :].ravel())
                    np.savetxt(kitti_root / "poses" / f"{k:06d}.txt", np.array(poses))
                    boxes = synthetic_boxes(rng, world_T_ego, k)
                    scene.add_frame(k - start, t, ObjectLabels(boxes=boxes), times)
                    cam = boxes.transform((world_T_ego @ EGO_T_VELO @ VELO_T_CAM).inverse(), "cam")
                    hwl, bottom, ry = cam.to_kitti_camera()
                    lines = [f"{KITTI_NAMES[c]} 0.00 0 0.0 0 0 100 100 {h:.4f} {w:.4f} {l:.4f} "
                             f"{x:.4f} {y:.4f} {z:.4f} {r:.4f}"
                             for c, (h, w, l), (x, y, z), r in zip(cam.classes, hwl, bottom, ry, strict=True)]
                    (kitti_root / "label_2" / f"{k:06d}.txt").write_text("\n".join(lines) + "\n")
                    (kitti_root / "calib" / f"{k:06d}.txt").write_text(calib_text)
    return avdata_root, kitti_root


class KittiFilesDataset(Dataset):
    """The usual hand-written KITTI loader: .bin points, label .txt boxes moved into the velodyne frame."""

    def __init__(self, root: Path, frames: int):
        self.root = root
        self.frames = frames

    def __len__(self) -> int:
        return self.frames

    def __getitem__(self, index: int) -> dict:
        points = np.fromfile(self.root / "velodyne" / f"{index:06d}.bin", dtype=np.float32).reshape(-1, 4)
        calib = {}
        for line in (self.root / "calib" / f"{index:06d}.txt").read_text().splitlines():
            key, values = line.split(":", 1)
            calib[key] = np.array(values.split(), dtype=np.float64)
        rect_T_velo = np.eye(4)
        rect_T_velo[:3, :] = calib["Tr_velo_to_cam"].reshape(3, 4)
        rect = np.eye(4)
        rect[:3, :3] = calib["R0_rect"].reshape(3, 3)
        velo_T_rect = np.linalg.inv(rect @ rect_T_velo)
        rows = [line.split() for line in (self.root / "label_2" / f"{index:06d}.txt").read_text().splitlines()]
        rows = [r for r in rows if r[0] in ("Car", "Pedestrian", "Cyclist")]
        values = np.array([r[8:15] for r in rows], dtype=np.float64).reshape(-1, 7)
        h, w, l = values[:, 0], values[:, 1], values[:, 2]
        centre = values[:, 3:6] - np.c_[np.zeros_like(h), h / 2.0, np.zeros_like(h)]
        centre_velo = centre @ velo_T_rect[:3, :3].T + velo_T_rect[:3, 3]
        boxes = np.c_[centre_velo, l, w, h, -values[:, 6] - np.pi / 2.0].astype(np.float32)
        labels = np.array([("Car", "Pedestrian", "Cyclist").index(r[0]) for r in rows], dtype=np.int64)
        return {"points": torch.from_numpy(points), "boxes": torch.from_numpy(boxes), "labels": torch.from_numpy(labels)}


class KittiWorldFilesDataset(KittiFilesDataset):
    """The same loader in the world frame: points and boxes moved by the frame's pose file (its first row is the
    ego lidar's ``world_T_velo``), as a hand-written world-frame loader does."""

    def __getitem__(self, index: int) -> dict:
        item = super().__getitem__(index)
        world_T_velo = np.loadtxt(self.root / "poses" / f"{index:06d}.txt", max_rows=1).reshape(3, 4)
        rotation, translation = world_T_velo[:, :3].astype(np.float32), world_T_velo[:, 3].astype(np.float32)
        points, boxes = item["points"].numpy(), item["boxes"].numpy()
        points[:, :3] = points[:, :3] @ rotation.T + translation
        boxes[:, :3] = boxes[:, :3] @ rotation.T + translation
        boxes[:, 6] += np.arctan2(world_T_velo[1, 0], world_T_velo[0, 0])
        return item


class CollaborativeFilesDataset(Dataset):
    """Hand-written collaborative loader: 9 .bin clouds and a pose file per frame, fused in the ego frame."""

    def __init__(self, root: Path, frames: int):
        self.root = root
        self.frames = frames

    def __len__(self) -> int:
        return self.frames

    def __getitem__(self, index: int) -> dict:
        poses = np.loadtxt(self.root / "poses" / f"{index:06d}.txt").reshape(-1, 3, 4)
        world_T_sensor = np.tile(np.eye(4), (len(poses), 1, 1))
        world_T_sensor[:, :3, :] = poses
        ego_T_world = np.linalg.inv(world_T_sensor[0] @ np.linalg.inv(EGO_T_VELO.as_matrix()))
        paths = [self.root / "velodyne" / f"{index:06d}.bin"] + [
            self.root / "infra" / f"{index:06d}_{i:02d}.bin" for i in range(N_INFRA)]
        parts = []
        for agent, path in enumerate(paths):
            cloud = np.fromfile(path, dtype=np.float32).reshape(-1, 4)
            ego_T_sensor = (ego_T_world @ world_T_sensor[agent]).astype(np.float32)
            xyz = cloud[:, :3] @ ego_T_sensor[:3, :3].T + ego_T_sensor[:3, 3]
            parts.append(np.c_[xyz, cloud[:, 3:], np.full((len(cloud), 1), agent, dtype=np.float32)])
        return {"points": torch.from_numpy(np.concatenate(parts)), "pose": torch.from_numpy(ego_T_world)}


def cpu_seconds() -> float:
    """CPU time (user + system) of this process and its live child processes (the loader workers).

    Read from /proc (Linux): each thread's ``schedstat`` (nanoseconds on the CPU), or where the kernel
    has none, each process's ``stat`` (user and system clock ticks, 10 ms); NaN elsewhere. Workers stay
    alive between passes (persistent), so their counters cover exactly the passes in between two readings.
    """
    try:
        children = [pid for task in Path("/proc/self/task").iterdir() for pid in (task / "children").read_text().split()]
        try:
            return sum(int((task / "schedstat").read_text().split()[0]) for pid in ["self", *children]
                       for task in Path(f"/proc/{pid}/task").iterdir()) / 1e9
        except (OSError, IndexError, ValueError):
            total = sum(os.times()[:2])
            for pid in children:
                fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
                total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime
            return total
    except OSError:
        return float("nan")


def compare(ours: Dataset, theirs: Dataset, repeats: int, workers: int = 2,
            batch_size: int = 4) -> tuple[tuple[float, float], tuple[float, float]]:
    """Best samples/s and least CPU ms/sample of each dataset through a DataLoader.

    Passes are interleaved (ours, theirs, ours ...); each loader keeps its workers between passes and
    makes one untimed warm pass first; interleaving makes both sides see the same background load on
    a shared machine. CPU time per sample (main process and workers together) hardly depends on that
    load at all: on an otherwise idle machine with as many cores as workers, throughput is its inverse.
    """
    loaders = [DataLoader(d, batch_size=batch_size, num_workers=workers, collate_fn=collate_list,
                          persistent_workers=workers > 0) for d in (ours, theirs)]
    best = [0.0, 0.0]
    cpu_ms = [float("inf"), float("inf")]
    for repeat in range(repeats + 1):
        for side, loader in enumerate(loaders):
            start, start_cpu = time.perf_counter(), cpu_seconds()
            for _ in loader:
                pass
            if repeat:
                best[side] = max(best[side], len(loader.dataset) / (time.perf_counter() - start))
                cpu_ms[side] = min(cpu_ms[side], 1e3 * (cpu_seconds() - start_cpu) / len(loader.dataset))
    return (best[0], best[1]), (cpu_ms[0], cpu_ms[1])


def report(figure: str, baseline: str, rates: tuple[float, float], cpu_ms: tuple[float, float]) -> None:
    """Prints the throughput line and the CPU-cost line of one figure."""
    ours, theirs = rates
    print(f"{figure}: avdata {ours:.1f} samples/s, baseline {baseline} {theirs:.1f} samples/s, ratio {ours / theirs:.2f}x")
    print(f"{figure}_cpu: avdata {cpu_ms[0]:.2f} ms/sample, baseline {baseline} {cpu_ms[1]:.2f} ms/sample, "
          f"ratio {cpu_ms[1] / cpu_ms[0]:.2f}x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="small run for CI smoke checks")
    parser.add_argument("--frames", type=int, help="frames to write (default 100, quick 24)")
    parser.add_argument("--repeats", type=int, help="timed passes, best kept (default 3, quick 1)")
    args = parser.parse_args()
    frames = args.frames or (24 if args.quick else 100)
    repeats = args.repeats or (1 if args.quick else 3)
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory(prefix="avdata-bench-loaders-") as tmp:
        avdata_root, kitti_root = write_data(Path(tmp), frames, ego_points=120_000, infra_points=60_000)
        single = FrameDataset(avdata_root, sensors="ego/velodyne", frame="ego", classes=CLASSES)
        kitti = KittiFilesDataset(kitti_root, frames)
        report("frame_dataset", "kitti-bin-txt", *compare(single, kitti, repeats))
        in_world = FrameDataset(avdata_root, sensors="ego/velodyne", frame="world", classes=CLASSES)
        report("frame_dataset_world_frame", "kitti-bin-txt-world", *compare(in_world, KittiWorldFilesDataset(kitti_root, frames),
                                                                             repeats))
        fused = FrameDataset(avdata_root, FrameOptions(sensors=("*/velodyne", "*/lidar"), labels=LabelFilter(classes=CLASSES),
                                                       collaboration=Collaboration(agents=("ego", "infra_*"), fusion="early")))
        report("collaborative", "bin-files+poses", *compare(fused, CollaborativeFilesDataset(kitti_root, frames), repeats))


if __name__ == "__main__":
    main()
