"""Benchmark: nuScenes-schema conversion, avdata vs the obvious nuscenes-devkit 1.2.0 conversion.

Input: the real Lyft tables (../shared/realdata/nuscenes_schema/lyft) scaled up to SCENES x SAMPLES
key frames, each with the 10 Lyft channels (3 LiDARs, 7 cameras), 4 LIDAR_TOP sweeps per sample
and 30 objects tracked through every sample (nuScenes averages ~34 boxes per sample); the real
calibrations, Lyft float-microsecond timestamps and its one-pose-per-sample_data layout. Sensor files
are symlinks to one real nuScenes LIDAR_TOP sweep (its first 8192 points) and one real camera JPEG.

Baseline (in ``.oracle-envs/nuscenes``): load ``NuScenes``, loop scenes and samples, call
``get_sample_data`` for every key-frame sample_data and ``box_velocity`` for every box, walk each
LiDAR's sweeps, read every sensor file and write the same content (points, image bytes, poses,
calibrations, boxes) to one pickle stream per scene. avdata: ``run_conversion`` with one worker.
A second figure loads tables only (no sensor files) at nuScenes' density, ~76 sample_data and 34
annotations per sample, with nuScenes-length tokens and filenames: avdata's ``NuScenesTables`` vs the
devkit's ``NuScenes(...)``, at 100 scenes, or with ``--trainval-tables`` (that figure alone) at the
scale of nuScenes v1.0-trainval (850 scenes, 2.6M sample_data, 1.2M annotations).
The conversion figure defaults to 200 scenes (``--scenes``): below ~190 the memory ratio measures
what importing numpy, pyarrow and Parquet costs (64 MB, more than 1/5 of the devkit's 352 MB at 50
scenes), not what grows with the dataset. Each side runs in its own process; times are the
conversion's wall and CPU (user + system) time, memory the process's peak RSS. Both write the same
sensor bytes, so on a slow disk wall time is bounded by the writes; CPU time shows the converters'
own work.

    python benchmarks/convert_nuscenes.py [--quick] [--keep] [--scenes N] [--trainval-tables]
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
LYFT_TABLES = REPO.parent / "shared" / "realdata" / "nuscenes_schema" / "lyft" / "v1.01-train" / "v1.01-train"
NUSCENES = REPO.parent / "shared" / "realdata" / "nuscenes"
LIDAR_FILE = NUSCENES / "samples/LIDAR_TOP/n015-2018-07-24-11-22-45+0800__LIDAR_TOP__1532402927647951.pcd.bin"
JPEG_FILE = NUSCENES / "samples/CAM_FRONT/n015-2018-07-24-11-22-45+0800__CAM_FRONT__1532402927612460.jpg"
VERSION = "v1.01-train"
LIDAR_POINTS = 8192
N_OBJECTS = 30
#: The tables-only figure: nuScenes trainval has ~76 sample_data and ~34 annotations per sample.
TABLE_SWEEPS = 66
TABLE_OBJECTS = 34
#: ``--trainval-tables``: 850 scenes x 40 samples, 2.58M sample_data and 1.16M annotations (nuScenes
#: v1.0-trainval: 850 scenes, 2.63M sample_data, 1.17M sample_annotation).
TRAINVAL_SCENES = 850


def build_tables(root: Path, n_scenes: int, n_samples: int, n_sweeps: int, n_objects: int, files: bool = True,
                 nuscenes_names: bool = False) -> None:
    """Scaled Lyft tables under ``root/VERSION``, plus symlinked sensor files under ``root`` if ``files``.

    With ``nuscenes_names`` (tables only) every token is 32 hex digits and every filename as long as
    nuScenes' (``sweeps/LIDAR_TOP/n015-2018-07-24-11-22-45+0800__LIDAR_TOP__1532402927647951.pcd.bin``),
    so table memory is measured with nuScenes' string lengths, not the short names used otherwise.
    """
    import hashlib
    import math

    def tok(name: str) -> str:
        return hashlib.md5(name.encode()).hexdigest() if nuscenes_names else name

    def load(name: str) -> list[dict]:
        return json.loads((LYFT_TABLES / f"{name}.json").read_text())

    sensors = {s["token"]: s for s in load("sensor")}
    calibrations = load("calibrated_sensor")
    channel_of = {c["token"]: sensors[c["sensor_token"]]["channel"] for c in calibrations}
    real_sd = load("sample_data")
    offset_us = {channel_of[sd["calibrated_sensor_token"]]: sd["timestamp"] - 1556675185903083.2 for sd in real_sd}
    lidar_cs = {channel_of[c["token"]]: c["token"] for c in calibrations}
    categories = load("category")
    attributes = load("attribute")
    (root / "data").mkdir(parents=True)
    lidar = root / "data" / "lidar.bin"
    lidar.write_bytes(LIDAR_FILE.read_bytes()[: LIDAR_POINTS * 20])
    jpeg = root / "data" / "image.jpeg"
    jpeg.write_bytes(JPEG_FILE.read_bytes())
    (root / "maps").mkdir()
    (root / "maps" / "map_raster_palo_alto.png").symlink_to(LYFT_TABLES.parent / "maps" / "map_raster_palo_alto.png")
    for folder in ("lidar", "images"):
        (root / folder).mkdir()
    logs, scenes, samples, sample_data, ego_pose, instances, annotations = [], [], [], [], [], [], []
    for i in range(n_scenes):
        log_token = tok(f"log{i:04d}")
        logs.append(
            {"token": log_token, "logfile": "", "vehicle": "a101", "location": "Palo Alto", "date_captured": "2019-05-01"}
        )
        scene_token = tok(f"scene{i:04d}")
        sample_tokens = [tok(f"s{i:04d}_{j:04d}") for j in range(n_samples)]
        scenes.append(
            {
                "token": scene_token,
                "name": f"host-a101-scene-{i:04d}",
                "log_token": log_token,
                "description": "",
                "nbr_samples": n_samples,
                "first_sample_token": sample_tokens[0],
                "last_sample_token": sample_tokens[-1],
            }
        )
        previous_sd: dict[str, int] = {}
        for j, token in enumerate(sample_tokens):
            sample_time = 1556675185903083.2 + i * 1e8 + j * 2e5
            samples.append(
                {
                    "token": token,
                    "scene_token": scene_token,
                    "timestamp": sample_time,
                    "prev": sample_tokens[j - 1] if j else "",
                    "next": sample_tokens[j + 1] if j + 1 < n_samples else "",
                }
            )
            rows = [(channel, sample_time + offset, True) for channel, offset in offset_us.items()]
            rows += [("LIDAR_TOP", sample_time + 2e5 * (k + 1) / (n_sweeps + 1), False) for k in range(n_sweeps)]
            for k, (channel, timestamp, key) in enumerate(rows):
                sd_token = tok(f"sd{i:04d}_{j:04d}_{k:02d}")
                is_camera = channel.startswith("CAM")
                filename = f"{'images' if is_camera else 'lidar'}/{sd_token}.{'jpeg' if is_camera else 'bin'}"
                if nuscenes_names:
                    filename = (f"{'samples' if key else 'sweeps'}/{channel}/n015-2018-07-24-11-22-45+0800__{channel}__"
                                f"{int(timestamp)}.{'jpg' if is_camera else 'pcd.bin'}")
                if files:
                    (root / filename).symlink_to(jpeg if is_camera else lidar)
                sample_data.append(
                    {
                        "token": sd_token,
                        "sample_token": token,
                        "ego_pose_token": tok(f"ep{sd_token}"),
                        "calibrated_sensor_token": lidar_cs[channel],
                        "timestamp": timestamp,
                        "is_key_frame": key,
                        "fileformat": "jpeg" if is_camera else "bin",
                        "filename": filename,
                        "width": 1920 if is_camera else None,
                        "height": 1080 if is_camera else None,
                        "prev": sample_data[previous_sd[channel]]["token"] if channel in previous_sd else "",
                        "next": "",
                    }
                )
                if channel in previous_sd:
                    sample_data[previous_sd[channel]]["next"] = sd_token
                previous_sd[channel] = len(sample_data) - 1
                t = (timestamp - 1556675185903083.2) * 1e-6 - i * 100
                yaw = 0.05 * t
                ego_pose.append(
                    {
                        "token": tok(f"ep{sd_token}"),
                        "timestamp": sample_time,
                        "rotation": [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)],
                        "translation": [457.0 + 8.0 * t, 2679.0 + 1.0 * t, -18.6],
                    }
                )
        for k in range(n_objects):
            tokens = [tok(f"a{i:04d}_{k:02d}_{j:04d}") for j in range(n_samples)]
            instance_token = tok(f"inst{i:04d}_{k:02d}")
            instances.append(
                {
                    "token": instance_token,
                    "category_token": categories[k % 9]["token"],
                    "nbr_annotations": n_samples,
                    "first_annotation_token": tokens[0],
                    "last_annotation_token": tokens[-1],
                }
            )
            for j, token in enumerate(tokens):
                yaw = 0.1 * k + 0.01 * j
                annotations.append(
                    {
                        "token": token,
                        "sample_token": sample_tokens[j],
                        "instance_token": instance_token,
                        "visibility_token": "",
                        "attribute_tokens": [attributes[k % len(attributes)]["token"]],
                        "translation": [430.0 + 3 * k + 1.5 * j, 2700.0 - 2 * k, -17.1],
                        "size": [2.0, 4.5, 1.8],
                        "rotation": [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)],
                        "prev": tokens[j - 1] if j else "",
                        "next": tokens[j + 1] if j + 1 < n_samples else "",
                        "num_lidar_pts": -1,
                        "num_radar_pts": 0,
                    }
                )
    tables = {
        "scene": scenes,
        "sample": samples,
        "sample_data": sample_data,
        "ego_pose": ego_pose,
        "sample_annotation": annotations,
        "instance": instances,
        "log": logs,
        "map": [dict(load("map")[0], log_tokens=[log["token"] for log in logs])],
        "sensor": list(sensors.values()),
        "calibrated_sensor": calibrations,
        "category": categories,
        "attribute": attributes,
        "visibility": load("visibility"),
    }
    (root / VERSION).mkdir()
    for name, rows in tables.items():
        (root / VERSION / f"{name}.json").write_text(json.dumps(rows))


def run_avdata(src: Path, dst: Path) -> dict:
    """avdata's conversion in this process: wall time and peak RSS."""
    from avdata.converters import ConvertConfig, run_conversion
    from avdata.converters.nuscenes import NuScenesConverter

    start, cpu_start = time.perf_counter(), _cpu_seconds()
    result = run_conversion(NuScenesConverter(ConvertConfig(src=src, dst=dst, quiet=True, options={"version": VERSION})))
    seconds, cpu = time.perf_counter() - start, _cpu_seconds() - cpu_start
    if result.failed or result.n_errors:
        raise SystemExit(f"avdata conversion failed: {result.problems[:3]}")
    return {
        "seconds": seconds,
        "cpu_seconds": cpu,
        "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "scenes": len(result.written),
    }


def run_devkit(src: Path, dst: Path) -> dict:
    """The obvious devkit conversion (run with the oracle venv's python): wall time and peak RSS."""
    import pickle

    from nuscenes.nuscenes import NuScenes
    from nuscenes.utils.data_classes import LidarPointCloud
    from nuscenes.utils.geometry_utils import BoxVisibility

    start, cpu_start = time.perf_counter(), _cpu_seconds()
    nusc = NuScenes(version=VERSION, dataroot=str(src), verbose=False)
    dst.mkdir(parents=True, exist_ok=True)

    def sensor_message(sd: dict) -> dict:
        pose = nusc.get("ego_pose", sd["ego_pose_token"])
        calibration = nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])
        path = nusc.get_sample_data_path(sd["token"])
        if sd["sensor_modality"] == "camera":
            with open(path, "rb") as stream:
                data = stream.read()
        else:
            data = LidarPointCloud.from_file(path).points
        return {
            "channel": sd["channel"],
            "timestamp": sd["timestamp"],
            "ego_pose": pose,
            "calibration": calibration,
            "data": data,
        }

    for scene in nusc.scene:
        with open(dst / f"{scene['name']}.pkl", "wb") as out:
            token = scene["first_sample_token"]
            while token:
                sample = nusc.get("sample", token)
                for sd_token in sample["data"].values():
                    sd = nusc.get("sample_data", sd_token)
                    _, boxes, _ = nusc.get_sample_data(sd_token, box_vis_level=BoxVisibility.NONE)
                    message = sensor_message(sd)
                    message["boxes"] = [
                        (b.token, b.center, b.wlh, b.orientation.elements, nusc.box_velocity(b.token)) for b in boxes
                    ]
                    pickle.dump(message, out)
                    sweep = sd["next"]
                    while sweep and sd["sensor_modality"] == "lidar":
                        sweep_sd = nusc.get("sample_data", sweep)
                        if sweep_sd["is_key_frame"]:
                            break
                        pickle.dump(sensor_message(sweep_sd), out)
                        sweep = sweep_sd["next"]
                token = sample["next"]
    seconds, cpu = time.perf_counter() - start, _cpu_seconds() - cpu_start
    return {
        "seconds": seconds,
        "cpu_seconds": cpu,
        "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "scenes": len(nusc.scene),
    }


def load_avdata_tables(src: Path) -> dict:
    """avdata's table loading (every lookup the conversion uses): wall time and peak RSS."""
    from avdata.sources.nuscenes import NuScenesTables

    start = time.perf_counter()
    tables = NuScenesTables(src / VERSION)
    seconds = time.perf_counter() - start
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return {"seconds": seconds, "peak_mb": peak_mb, "sample_data": len(tables.sample_data["time_ns"])}


def load_devkit_tables(src: Path) -> dict:
    """``NuScenes(...)``: the devkit's table loading and reverse index, wall time and peak RSS."""
    from nuscenes.nuscenes import NuScenes

    start = time.perf_counter()
    nusc = NuScenes(version=VERSION, dataroot=str(src), verbose=False)
    seconds = time.perf_counter() - start
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return {"seconds": seconds, "peak_mb": peak_mb, "sample_data": len(nusc.sample_data)}


def build(src: Path, n_scenes: int, n_samples: int, n_sweeps: int, n_objects: int, kind: str) -> None:
    """Runs :func:`build_tables` in a child process: Linux keeps a process's peak RSS across exec, so
    the measured children must be started from a parent that never held the generated tables.

    ``kind``: "files" (tables and sensor files) or "tables" (tables only, nuScenes-length names).
    """
    counts = [str(n) for n in (n_scenes, n_samples, n_sweeps, n_objects)]
    subprocess.run([sys.executable, __file__, "--build", str(src), *counts, kind], check=True)


def measure(python: Path, side: str, *paths: Path) -> dict:
    proc = subprocess.run([str(python), __file__, f"--{side}", *map(str, paths)], capture_output=True, text=True, cwd=REPO)
    if proc.returncode:
        raise SystemExit(f"{side} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="5 scenes x 10 samples")
    parser.add_argument("--keep", action="store_true", help="keep the temporary folder")
    parser.add_argument("--scenes", type=int, default=200,
                        help="scenes of the conversion figure (default 200, ~16 GB written: the devkit's memory grows "
                             "~3.4 MB a scene, avdata's ~0.3 MB above ~110 MB of imports and one scene's working set, "
                             "so fewer scenes measure the imports)")
    parser.add_argument("--trainval-tables", action="store_true",
                        help=f"only the tables-only figure, at nuScenes trainval scale ({TRAINVAL_SCENES} scenes; the "
                             "devkit needs several GB and minutes)")
    parser.add_argument("--avdata", nargs=2, type=Path, metavar=("SRC", "DST"), help=argparse.SUPPRESS)
    parser.add_argument("--devkit", nargs=2, type=Path, metavar=("SRC", "DST"), help=argparse.SUPPRESS)
    parser.add_argument("--avdata-tables", type=Path, metavar="SRC", help=argparse.SUPPRESS)
    parser.add_argument("--devkit-tables", type=Path, metavar="SRC", help=argparse.SUPPRESS)
    parser.add_argument(
        "--build", nargs=6, metavar=("SRC", "SCENES", "SAMPLES", "SWEEPS", "OBJECTS", "FILES"), help=argparse.SUPPRESS
    )
    args = parser.parse_args()
    if args.build:
        root, *counts, files = args.build
        build_tables(Path(root), *map(int, counts), files=files == "files", nuscenes_names=files == "tables")
        return
    for mode, run in (
        (args.avdata, run_avdata),
        (args.devkit, run_devkit),
        (args.avdata_tables, load_avdata_tables),
        (args.devkit_tables, load_devkit_tables),
    ):
        if mode:
            print(json.dumps(run(*mode) if isinstance(mode, list) else run(mode)))
            return
    oracle = REPO / ".oracle-envs" / "nuscenes" / "bin" / "python"
    if not oracle.exists():
        raise SystemExit(f"baseline env missing at {oracle}; run tests/oracles/make_envs.sh")
    n_scenes, n_samples, n_sweeps = (5, 10, 4) if args.quick else (args.scenes, 40, 4)
    work = Path(tempfile.mkdtemp(prefix="bench_nuscenes_"))
    try:
        src = work / "src"
        if args.trainval_tables:
            tables_figure(src, oracle, TRAINVAL_SCENES)
            return
        build(src, n_scenes, n_samples, n_sweeps, N_OBJECTS, "files")
        n_sd = n_scenes * n_samples * (10 + n_sweeps)
        print(
            f"input: {n_scenes} scenes x {n_samples} samples, {n_sd} sample_data, "
            f"{n_scenes * n_samples * N_OBJECTS} boxes; machine: {_machine()}",
            flush=True,
        )
        ours = measure(Path(sys.executable), "avdata", src, work / "avdata")
        shutil.rmtree(work / "avdata")
        base = measure(oracle, "devkit", src, work / "devkit")
        shutil.rmtree(work / "devkit")
        assert ours["scenes"] == base["scenes"] == n_scenes
        print(
            f"convert time: avdata {ours['seconds']:.2f} s, baseline devkit {base['seconds']:.2f} s, "
            f"ratio {base['seconds'] / ours['seconds']:.1f}x"
        )
        print(
            f"convert cpu time: avdata {ours['cpu_seconds']:.2f} s, baseline devkit {base['cpu_seconds']:.2f} s, "
            f"ratio {base['cpu_seconds'] / ours['cpu_seconds']:.1f}x"
        )
        print(
            f"convert peak memory: avdata {ours['peak_mb']:.0f} MB, baseline devkit {base['peak_mb']:.0f} MB, "
            f"ratio {base['peak_mb'] / ours['peak_mb']:.1f}x"
        )
        shutil.rmtree(src)
        tables_figure(src, oracle, 10 if args.quick else 100)
    finally:
        if args.keep:
            print(f"kept {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)


def tables_figure(src: Path, oracle: Path, n_scenes: int) -> None:
    """Builds ``n_scenes`` x 40 samples of tables at nuScenes' density and prints both sides' load figures."""
    build(src, n_scenes, 40, TABLE_SWEEPS, TABLE_OBJECTS, "tables")
    n_sd = n_scenes * 40 * (10 + TABLE_SWEEPS)
    print(
        f"tables only, nuScenes density and name lengths: {n_scenes} scenes x 40 samples, {n_sd} sample_data, "
        f"{n_scenes * 40 * TABLE_OBJECTS} annotations; machine: {_machine()}",
        flush=True,
    )
    ours = measure(Path(sys.executable), "avdata-tables", src)
    base = measure(oracle, "devkit-tables", src)
    assert ours["sample_data"] == base["sample_data"] == n_sd
    print(
        f"table load time: avdata {ours['seconds']:.2f} s, baseline devkit {base['seconds']:.2f} s, "
        f"ratio {base['seconds'] / ours['seconds']:.1f}x"
    )
    print(
        f"table load peak memory: avdata {ours['peak_mb']:.0f} MB, baseline devkit {base['peak_mb']:.0f} MB, "
        f"ratio {base['peak_mb'] / ours['peak_mb']:.1f}x"
    )


def _cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _machine() -> str:
    import os
    import platform

    return f"{platform.processor() or platform.machine()}, {os.cpu_count()} cpus"


if __name__ == "__main__":
    main()
