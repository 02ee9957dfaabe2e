"""V2X loading: avdata's FrameDataset over converted OPV2V scenes against an OpenCOOD-style loop over the source files.

The source is an OPV2V/V2XSet scenario in the published layout, built as ``tests/converters/opv2v_fixtures.py``
builds it around the real V2XSet frame file (``$AVDATA_REALDATA/v2xset/...``): an ego, a second CAV and an
RSU, ``--frames`` frames of ``--points`` points per cloud (the ego's PCDs ASCII, the CAV's binary, the RSU's
binary_compressed, as the fixture writes them). It is converted once with ``avdata convert opv2v``.

The baseline does per frame what OpenCOOD's ``basedataset.retrieve_base_data`` and its fusion datasets do:
every agent's YAML parsed with PyYAML's ``yaml.Loader`` (OpenCOOD's ``load_yaml``), its PCD read with
open3d (``pcd_utils.pcd_to_np``: x, y, z and ``colors[:, 0]`` as intensity), poses built with
``x_to_world`` / ``x1_to_x2`` (``transformation_utils.py``), then

- early fusion: every cloud projected into the ego's lidar frame and concatenated;
- intermediate fusion: the clouds kept, the pairwise transforms ``inv(T_j) @ T_i`` built.

avdata: ``FrameDataset`` with ``Collaboration(fusion="early" | "intermediate")`` over the converted scene,
items read one after another in the main process (as the baseline). Before timing, every frame's outputs
are checked equal: avdata's world is CARLA's reflected (y -> -y), so points compare with y negated and
transforms as ``R @ T @ R``, R = diag(1, -1, 1, 1).

Figures (frames per second, best of ``--repeats`` passes alternating the two sides):
``v2x_early`` and ``v2x_intermediate``.

Usage: ``python benchmarks/v2x_loader.py [--quick] [--frames N] [--points N] [--repeats R]``
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from avdata.converters.base import ConvertConfig, run_conversion  # noqa: E402
from avdata.converters.opv2v import Opv2vConverter  # noqa: E402
from avdata.generators._open3d import o3d  # noqa: E402
from avdata.loaders import Collaboration, FrameDataset, FrameOptions  # noqa: E402
from tests.converters.opv2v_fixtures import build_opv2v  # noqa: E402

#: Source agent folders in the order avdata names them: ego, cav_4288, infra_1.
AGENTS = ("4279", "4288", "-1")
REFLECT = np.diag([1.0, -1.0, 1.0, 1.0])


def x_to_world(pose: list[float]) -> np.ndarray:
    """OpenCOOD ``transformation_utils.x_to_world``: [x, y, z, roll, yaw, pitch] (degrees) -> 4x4."""
    x, y, z, roll, yaw, pitch = pose
    c_y, s_y = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
    c_r, s_r = np.cos(np.radians(roll)), np.sin(np.radians(roll))
    c_p, s_p = np.cos(np.radians(pitch)), np.sin(np.radians(pitch))
    matrix = np.identity(4)
    matrix[:3, 3] = x, y, z
    matrix[0, 0] = c_p * c_y
    matrix[0, 1] = c_y * s_p * s_r - s_y * c_r
    matrix[0, 2] = -c_y * s_p * c_r - s_y * s_r
    matrix[1, 0] = s_y * c_p
    matrix[1, 1] = s_y * s_p * s_r + c_y * c_r
    matrix[1, 2] = -s_y * s_p * c_r + c_y * s_r
    matrix[2, 0] = s_p
    matrix[2, 1] = -c_p * s_r
    matrix[2, 2] = c_p * c_r
    return matrix


def load_yaml(path: Path) -> dict:
    """OpenCOOD ``hypes_yaml.yaml_utils.load_yaml``: the full Python loader."""
    with open(path) as stream:
        return yaml.load(stream, Loader=yaml.Loader)


def pcd_to_np(path: Path) -> np.ndarray:
    """OpenCOOD ``pcd_utils.pcd_to_np``: (N, 4) float32 x, y, z, intensity (= the red channel).

    Open3D comes through avdata's one loader of it, which preloads the libusb that Open3D links (a bare import
    fails where libusb-1.0 is no system library).
    """
    pcd = o3d.io.read_point_cloud(str(path))
    xyz = np.asarray(pcd.points)
    intensity = np.expand_dims(np.asarray(pcd.colors)[:, 0], -1)
    return np.hstack((xyz, intensity)).astype(np.float32)


def baseline_frame(scenario: Path, number: int, fusion: str) -> dict[str, object]:
    """One frame the OpenCOOD way: YAML + PCD per agent, poses, then early or intermediate layout."""
    clouds, poses = [], []
    for agent in AGENTS:
        params = load_yaml(scenario / agent / f"{number:06d}.yaml")
        poses.append(x_to_world(params["lidar_pose"]))
        clouds.append(pcd_to_np(scenario / agent / f"{number:06d}.pcd"))
    if fusion == "early":
        ego_T_world = np.linalg.inv(poses[0])
        projected = []
        for cloud, world_T_cav in zip(clouds, poses, strict=True):
            t = ego_T_world @ world_T_cav  # x1_to_x2(cav, ego)
            xyz = cloud[:, :3] @ t[:3, :3].T + t[:3, 3]
            projected.append(np.hstack([xyz, cloud[:, 3:]]).astype(np.float32))
        return {"points": np.vstack(projected), "agent_index": np.repeat(np.arange(len(clouds)), [len(c) for c in clouds])}
    pairwise = np.tile(np.eye(4), (5, 5, 1, 1))
    for i, world_T_i in enumerate(poses):
        for j, world_T_j in enumerate(poses):
            pairwise[i, j] = np.linalg.inv(world_T_j) @ world_T_i
    return {"points": clouds, "pairwise": pairwise}


def check_equal(item: dict, expected: dict, fusion: str, where: str) -> None:
    flip = np.array([1.0, -1.0, 1.0], dtype=np.float32)
    if fusion == "early":
        fused = item["points"]["fused"].numpy()
        for a in range(len(AGENTS)):  # avdata concatenates in sensor-name order, with an agent_index field
            ours, theirs = fused[fused[:, 4] == a], expected["points"][expected["agent_index"] == a]
            if ours.shape[0] != theirs.shape[0] or not np.allclose(ours[:, :3] * flip, theirs[:, :3], atol=2e-3) \
                    or not np.allclose(ours[:, 3], theirs[:, 3], atol=1e-6):
                raise SystemExit(f"{where}: early-fusion clouds of {item['agents'][a]} differ")
        return
    for agent, theirs in zip(item["agents"], expected["points"], strict=True):
        ours = item["points"][agent].numpy()
        if ours.shape != theirs.shape or not np.allclose(ours[:, :3] * flip, theirs[:, :3], atol=1e-5) \
                or not np.allclose(ours[:, 3], theirs[:, 3], atol=1e-6):
            raise SystemExit(f"{where}: {agent}'s cloud differs")
    n = len(item["agents"])
    reflected = REFLECT @ expected["pairwise"][:n, :n] @ REFLECT
    if not np.allclose(item["pairwise_T"][:n, :n].numpy(), reflected, atol=1e-6):
        raise SystemExit(f"{where}: pairwise transforms differ")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="4 frames of 20k points, 2 passes")
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--points", type=int, default=60_000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    if args.quick:
        args.frames, args.points, args.repeats = 4, 20_000, 2
    numbers = tuple(69 + 2 * k for k in range(args.frames))
    with tempfile.TemporaryDirectory(prefix="avdata-v2x-bench-") as tmp:
        root = Path(tmp)
        scenario = build_opv2v(root / "src", frames=numbers, n_points=args.points)
        result = run_conversion(Opv2vConverter(ConvertConfig(src=root / "src", dst=root / "dst", quiet=True)))
        if result.problems:
            raise SystemExit(f"conversion problems: {result.problems}")
        for fusion in ("early", "intermediate"):
            options = FrameOptions(sensors=("*/lidar",), frame="ego/lidar",
                                   collaboration=Collaboration(agents=("*",), fusion=fusion))
            dataset = FrameDataset(root / "dst", options)
            if len(dataset) != len(numbers):
                raise SystemExit(f"expected {len(numbers)} frames, got {len(dataset)}")
            for k, number in enumerate(numbers):
                check_equal(dataset[k], baseline_frame(scenario, number, fusion), fusion, f"frame {number}")
            best = {"avdata": float("inf"), "opencood": float("inf")}
            for _ in range(args.repeats):
                start = time.perf_counter()
                for number in numbers:
                    baseline_frame(scenario, number, fusion)
                best["opencood"] = min(best["opencood"], time.perf_counter() - start)
                start = time.perf_counter()
                for k in range(len(dataset)):
                    dataset[k]
                best["avdata"] = min(best["avdata"], time.perf_counter() - start)
            ours, theirs = len(numbers) / best["avdata"], len(numbers) / best["opencood"]
            print(f"v2x_{fusion}: avdata {ours:.1f} frames/s, baseline opencood-style {theirs:.1f} frames/s, "
                  f"ratio {ours / theirs:.1f}x (outputs checked equal on {len(numbers)} frames, "
                  f"3 agents x {args.points} points)", flush=True)


if __name__ == "__main__":
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    main()
