"""Reading a unified dataset from an S3 API server on this machine against reading it from local disk.

The server is moto's standalone S3 server (``moto[server]``, the test extra), started on 127.0.0.1 by this
script: it speaks the S3 HTTP protocol, so pyarrow's S3 client makes the same requests as to AWS, but it is a
Python server on the same 2 cores, so its throughput is a floor, not a forecast of a real store's. What carries
over is the request and byte counts, counted at the ranged-read layer
(:func:`avdata.schema.mcap.fileio.counting_requests`).

Figures, one line each:

- ``object_store frames/s``: ``FrameDataset(sensors=[lidar, camera])`` items per second in one process, every
  frame once, from ``s3://`` against the same dataset on local disk (ratio = s3 / local, same run);
- ``object_store frames/s vs plain ranged GETs``: the same s3 figure against fetching every chunk of every scene
  with its message index, one plain ``read_at`` each through the same pyarrow client, one after another, nothing
  decoded (the bytes and about the requests of a pass): what avdata adds to moving the bytes;
- ``object_store frames/s, warm cache``: the same from ``s3://`` with a filled ``cache_dir`` (ratio to local);
- ``object_store requests per frame per sensor``: GETs of a pass, after each scene's opening, per frame per
  sensor (target: at most 2);
- ``object_store opening requests per scene``: HEAD + GETs to open a scene and read its frame tree;
- ``object_store bytes per frame``: bytes fetched per frame against the scene file's bytes per frame (ratio:
  1.0 means nothing fetched twice and nothing fetched that the frame does not use);
- ``object_store convert kitti-object``: ``avdata convert kitti-object`` from ``s3://`` to ``s3://`` against
  local disk to local disk, the three real KITTI object samples repeated (``benchmarks/convert_kitti.py``'s
  input), 4 samples per scene, 1 worker, each the CLI in a fresh process (source MB/s; ratio = s3 / local).

The data are synthetic but KITTI-shaped: a 120k-point lidar sweep (1.9 MB), a 1242x375 PNG (~1.2 MB) and ~15
labelled boxes per frame, 20 frames per scene.

Usage: ``python benchmarks/object_store.py [--quick] [--frames N]``
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from avdata.frames import Boxes3D, Transform
from avdata.loaders import FrameDataset
from avdata.schema import DatasetWriter, ObjectLabels
from avdata.schema.mcap.fileio import counting_requests

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the moto server starter the tests use
from tests.storage.moto_server import start_moto_server  # noqa: E402

SENSORS = ["ego/velodyne", "ego/cam2"]
PERIOD_NS = 100_000_000
FRAMES_PER_SCENE = 20
EGO_T_CAM = Transform(rotation=np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]),
                      translation=np.array([0.27, 0.0, -0.08]))
K = np.array([[721.5, 0.0, 609.6], [0.0, 721.5, 172.9], [0.0, 0.0, 1.0]])


def write_data(root: Path, frames: int) -> Path:
    """A KITTI-shaped dataset of ``frames`` frames (lidar, camera, boxes) in scenes of 20 frames."""
    rng = np.random.default_rng(0)
    with DatasetWriter(root, source="benchmark") as writer:
        for start in range(0, frames, FRAMES_PER_SCENE):
            with writer.scene(f"bench_{start:06d}") as scene:
                scene.add_agent("ego", kind="vehicle", origin="rear axle")
                scene.add_sensor("ego/velodyne", kind="lidar")
                scene.add_sensor("ego/cam2", kind="camera", width=1242, height=375)
                scene.add_static_transform("ego", "ego/velodyne", Transform.identity())
                scene.add_static_transform("ego", "ego/cam2", EGO_T_CAM)
                for k in range(start, min(start + FRAMES_PER_SCENE, frames)):
                    t = (k - start) * PERIOD_NS
                    world_T_ego = Transform.from_yaw(0.01 * k, np.array([2.0 * k, 0.5 * k, 0.0]))
                    scene.add_transform("world", "ego", t, world_T_ego)
                    cloud = rng.uniform(-70.0, 70.0, (120_000, 4)).astype(np.float32)
                    scene.add_point_cloud("ego/velodyne", t, {n: cloud[:, i] for i, n in enumerate("x y z intensity".split())})
                    image = cv2.GaussianBlur(rng.integers(0, 255, (375, 1242, 3), dtype=np.uint8), (3, 3), 0)
                    scene.add_camera_calibration("ego/cam2", t, K, width=1242, height=375, D=np.zeros(5))
                    scene.add_image("ego/cam2", t, cv2.imencode(".png", image)[1].tobytes(), "png")
                    n = int(rng.integers(10, 20))
                    boxes = Boxes3D.from_yaw(world_T_ego.apply(np.c_[rng.uniform(5, 60, n), rng.uniform(-20, 20, n),
                                                                     np.full(n, 0.8)]),
                                             np.c_[rng.uniform(0.5, 5, n), rng.uniform(0.5, 2, n), rng.uniform(1.4, 2, n)],
                                             rng.uniform(-np.pi, np.pi, n), "world",
                                             ids=np.array([f"{k}_{i}" for i in range(n)]),
                                             classes=rng.choice(["car", "pedestrian", "cyclist"], n))
                    scene.add_frame(k - start, t, ObjectLabels(boxes=boxes), {"ego/velodyne": t, "ego/cam2": t})
    return root


def upload(root: Path, uri: str) -> None:
    from avdata.storage import location

    target = location(uri)
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        (target / str(path.relative_to(root))).upload(path)


def convert_seconds(src: str, dst: str) -> float:
    """Wall seconds of ``avdata convert kitti-object SRC DST`` in a fresh process (raises if it fails)."""
    start = time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "avdata.cli", "convert", "kitti-object", src, dst, "--scene-size", "4",
                             "--workers", "1", "--quiet"], capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise SystemExit(f"avdata convert {src} {dst} failed: {result.stderr.strip()[:300]}")
    return time.perf_counter() - start


def plain_gets(local_root: Path, uri: str) -> float:
    """Seconds to fetch every chunk (with its message index) of every scene object, one ``read_at`` each."""
    from avdata.schema.mcap.reader import McapReader
    from avdata.storage import location

    ranges = {}
    for path in sorted((local_root / "scenes").glob("*.mcap")):
        chunks = McapReader(path).chunks
        ranges[path.name] = [(c.offset, c.length + c.message_index_length) for c in chunks]
    start = time.perf_counter()
    for name, chunk_ranges in ranges.items():
        scene = location(uri) / "scenes" / name
        with scene.fs.open_input_file(scene.path) as handle:
            for offset, length in chunk_ranges:
                handle.read_at(length, offset)
    return time.perf_counter() - start


def one_pass(dataset: FrameDataset) -> float:
    """Seconds to read every item once, in order."""
    start = time.perf_counter()
    for index in range(len(dataset)):
        dataset[index]
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="small run for CI smoke checks")
    parser.add_argument("--frames", type=int, help="frames to write (default 60, quick 20)")
    args = parser.parse_args()
    frames = args.frames or (20 if args.quick else 60)
    try:
        import moto.server  # noqa: F401
    except ImportError:
        raise SystemExit("object_store: needs moto[server] (pip install 'avdata[test]')") from None
    try:
        server, endpoint = start_moto_server()
    except RuntimeError as exc:
        raise SystemExit(f"object_store: {exc}") from None
    os.environ.update(AWS_ACCESS_KEY_ID="benchmark", AWS_SECRET_ACCESS_KEY="benchmark", AWS_REGION="us-east-1",
                      AWS_ENDPOINT_URL=endpoint, AWS_EC2_METADATA_DISABLED="true")
    try:
        import boto3

        boto3.client("s3", endpoint_url=endpoint, region_name="us-east-1").create_bucket(Bucket="avdata-bench")
        with tempfile.TemporaryDirectory(prefix="avdata-bench-object-store-") as tmp:
            local_root = write_data(Path(tmp) / "local", frames)
            uri = "s3://avdata-bench/dataset"
            upload(local_root, uri)
            scene_bytes = sum(p.stat().st_size for p in (local_root / "scenes").glob("*.mcap"))
            n_scenes = len(list((local_root / "scenes").glob("*.mcap")))
            local = FrameDataset(local_root, sensors=SENSORS)
            one_pass(FrameDataset(local_root, sensors=SENSORS))  # page cache warm, as the local figure assumes
            local_s = one_pass(local)
            remote = FrameDataset(uri, sensors=SENSORS)
            with counting_requests() as opening:
                for scene in sorted({scene for scene, _ in remote.keys()}):
                    remote.transforms(scene)  # the scene's summary and frame tree
            with counting_requests() as frames_read:
                remote_s = one_pass(remote)
            plain_s = plain_gets(local_root, uri)
            cached = FrameDataset(uri, sensors=SENSORS, cache_dir=Path(tmp) / "cache")
            one_pass(cached)
            warm = FrameDataset(uri, sensors=SENSORS, cache_dir=Path(tmp) / "cache")
            warm_s = one_pass(warm)
            convert = None
            try:
                from convert_kitti import build_object

                kitti = build_object(Path(tmp) / "kitti", 12 if args.quick else 48)
            except (ImportError, FileNotFoundError) as error:
                print(f"object_store convert kitti-object: skipped (needs the real KITTI samples: {error})")
            else:
                upload(kitti, "s3://avdata-bench/kitti")
                source_mb = sum(p.stat().st_size for p in kitti.rglob("*") if p.is_file()) / 1e6
                convert = (source_mb, convert_seconds(str(kitti), str(Path(tmp) / "kitti-local")),
                           convert_seconds("s3://avdata-bench/kitti", "s3://avdata-bench/kitti-unified"))
    finally:
        server.terminate()
        server.wait(10)
    n = len(local)
    print(f"object_store frames/s (lidar 120k points + 1242x375 PNG, {n} frames): avdata s3 {n / remote_s:.1f} frames/s, "
          f"baseline local disk {n / local_s:.1f} frames/s, ratio {local_s / remote_s:.3f}")
    print(f"object_store frames/s vs plain ranged GETs: avdata s3 {n / remote_s:.1f} frames/s, "
          f"baseline pyarrow read_at of every chunk {n / plain_s:.1f} frames/s, ratio {plain_s / remote_s:.3f}")
    print(f"object_store frames/s, warm cache: avdata s3+cache {n / warm_s:.1f} frames/s, "
          f"baseline local disk {n / local_s:.1f} frames/s, ratio {local_s / warm_s:.3f}")
    print(f"object_store requests per frame per sensor: avdata {frames_read.gets / n / len(SENSORS):.2f} GETs, "
          f"target 2, ratio {frames_read.gets / n / len(SENSORS) / 2:.2f}")
    print(f"object_store opening requests per scene: avdata {(opening.gets + opening.heads) / n_scenes:.1f} requests "
          f"({opening.heads / n_scenes:.0f} HEAD + {opening.gets / n_scenes:.1f} GET, "
          f"{(opening.bytes + frames_read.bytes) and opening.bytes / n_scenes / 1e6:.2f} MB)")
    fetched = (opening.bytes + frames_read.bytes) / n
    print(f"object_store bytes per frame: avdata {fetched / 1e6:.2f} MB fetched, baseline scene file "
          f"{scene_bytes / n / 1e6:.2f} MB per frame, ratio {fetched / (scene_bytes / n):.3f}")
    if convert is not None:
        source_mb, local_convert_s, remote_convert_s = convert
        print(f"object_store convert kitti-object ({source_mb:.0f} MB of source): avdata s3 -> s3 "
              f"{source_mb / remote_convert_s:.1f} MB/s, baseline local -> local {source_mb / local_convert_s:.1f} MB/s, "
              f"ratio {local_convert_s / remote_convert_s:.3f}")


if __name__ == "__main__":
    main()
