"""OPV2V / V2XSet / V2V4Real folders in the published layout, built around the real V2XSet frame file.

The ego (agent 4279) uses ``../shared/realdata/v2xset/.../4279/000069.yaml`` byte for byte as its first
frame; its later frames, a second CAV (4288) and an RSU (-1) are that file's structure with moved
poses and vehicle subsets. PCDs are written in the real header layout (``x y z rgb``, colour packed
into a float): the ego's ASCII, the CAV's binary, the RSU's binary_compressed.
"""

from __future__ import annotations

import copy
import shutil
from pathlib import Path

import cv2
import numpy as np
import yaml
from pypcd4 import Encoding
from pypcd4 import PointCloud as PypcdCloud

from tests.realdata import REALDATA

REPO = Path(__file__).resolve().parents[2]
REAL_SCENARIO = REALDATA / "v2xset" / "validate" / "2021_08_21_17_30_41"
REAL_YAML = REAL_SCENARIO / "4279" / "000069.yaml"
SCENARIO = "2021_08_21_17_30_41"
FRAMES = (69, 71, 73)
PCD_HEADER = (
    "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\n"
    "COUNT 1 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA ascii\n"
)
#: The hand-worked box: CARLA location (10, 5, 1), half extent (2, 1, 0.75), yaw +30 degrees.
HAND_BOX_ID = 9001
#: Points per synthetic cloud: dense enough that nearby boxes hold returns (visibility, evaluation).
N_POINTS = 3000


def real_frame() -> dict:
    with open(REAL_YAML) as stream:
        return yaml.safe_load(stream)


def _points(seed: int, n: int = N_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) float32 points and (n,) packed-rgb floats whose red byte is the intensity."""
    rng = np.random.default_rng(seed)
    xyz = rng.uniform([-40, -20, -2], [40, 20, 2], size=(n, 3)).astype(np.float32)
    grey = rng.integers(1, 255, size=n).astype(np.uint32)
    rgb = ((grey << 16) | (grey << 8) | grey).view(np.float32)
    return xyz, rgb


def write_pcd(path: Path, xyz: np.ndarray, rgb: np.ndarray, encoding: str) -> None:
    if encoding == "ascii":
        body = "".join(f"{x:.10g} {y:.10g} {z:.10g} {c:.10g}\n" for (x, y, z), c in zip(xyz.tolist(), rgb.tolist(), strict=True))
        path.write_text(PCD_HEADER.format(n=len(xyz)) + body)
        return
    cloud = PypcdCloud.from_points([xyz[:, 0], xyz[:, 1], xyz[:, 2], rgb], ("x", "y", "z", "rgb"),
                                   (np.float32, np.float32, np.float32, np.float32))
    cloud.save(path, encoding=Encoding(encoding))


def _plain(value: object) -> object:
    """numpy scalars inside dicts and lists -> Python numbers, for ``yaml.safe_dump``."""
    if isinstance(value, dict):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    return value.item() if isinstance(value, np.generic) else value


def _dump(path: Path, data: dict) -> None:
    path.write_text(yaml.safe_dump(_plain(data), sort_keys=True))


def build_opv2v(root: Path, frames: tuple[int, ...] = FRAMES, n_points: int = N_POINTS) -> Path:
    """Writes ``root/validate/<scenario>/{4279,4288,-1}/`` with ``frames`` (the first must be 69: the real
    file) of ``n_points`` points per cloud; returns the scenario folder (``benchmarks/v2x_loader.py``
    builds a longer one)."""
    scenario = root / "validate" / SCENARIO
    real = real_frame()
    vehicles = real["vehicles"]
    ids = sorted(vehicles)
    for step, number in enumerate(frames):
        shift = np.array([0.0, 1.6 * step, 0.0])  # the ego drives north (+y in CARLA) at 16 m/s
        ego = copy.deepcopy(real)
        for key in ("lidar_pose", "true_ego_pos", "predicted_ego_pos"):
            ego[key] = (np.asarray(ego[key]) + np.r_[shift, 0, 0, 0]).tolist()
        cav = copy.deepcopy(real)
        cav_pose = np.asarray(real["lidar_pose"]) + [20.0, 5.0 + 1.1 * step, 0.0, 0.0, 30.0, 0.0]
        cav["lidar_pose"] = cav_pose.tolist()
        cav["true_ego_pos"] = (cav_pose - [0, 0, 1.9, 0, 0, 0]).tolist()
        cav["predicted_ego_pos"] = (cav_pose - [0.3, -0.2, 1.9, 0, 1.0, 0]).tolist()
        cav["vehicles"] = {i: vehicles[i] for i in ids[:6]}
        cav["vehicles"][4279] = {  # the ego as its peer sees it
            "location": (np.asarray(real["true_ego_pos"][:3]) + shift).tolist(),
            "center": [0.0, 0.0, 0.75], "extent": [2.4, 1.05, 0.75],
            "angle": [real["true_ego_pos"][3], real["true_ego_pos"][4], real["true_ego_pos"][5]],
            "speed": 57.6,
        }
        rsu = {key: copy.deepcopy(real[key]) for key in ("camera0",)}
        rsu.update({"RSU": True, "lidar_pose": [-260.0, 0.0, 4.5, 0.0, 45.0, 0.0],
                    "vehicles": {i: vehicles[i] for i in ids[4:10]}})
        rsu["vehicles"][4288] = {"location": cav["true_ego_pos"][:3], "center": [0.0, 0.0, 0.75],
                                 "extent": [2.2, 1.0, 0.8], "angle": [0.0, cav_pose[4], 0.0], "speed": 39.6}
        rsu["vehicles"][HAND_BOX_ID] = {"location": [10.0, 5.0, 1.0], "center": [0.0, 0.0, 0.0],
                                        "extent": [2.0, 1.0, 0.75], "angle": [0.0, 30.0, 0.0], "speed": 0.0}
        for agent, data, encoding in (("4279", ego, "ascii"), ("4288", cav, "binary"), ("-1", rsu, "binary_compressed")):
            folder = scenario / agent
            folder.mkdir(parents=True, exist_ok=True)
            if agent == "4279" and number == FRAMES[0]:
                shutil.copyfile(REAL_YAML, folder / f"{number:06d}.yaml")
            else:
                _dump(folder / f"{number:06d}.yaml", data)
            xyz, rgb = _points(seed=number * 10 + len(agent), n=n_points)
            write_pcd(folder / f"{number:06d}.pcd", xyz, rgb, encoding)
            ok, png = cv2.imencode(".png", np.full((600, 800, 3), 40 + step, dtype=np.uint8))
            assert ok
            for camera in (key for key in data if key.startswith("camera")):
                (folder / f"{number:06d}_{camera}.png").write_bytes(png.tobytes())
    return scenario


def build_v2v4real(root: Path) -> Path:
    """``root/test/testoutput_CAV_data_2022-03-15-09-54-40_0/{0,1}/``: 4x4 poses, objects in each lidar frame."""
    scenario = root / "test" / "testoutput_CAV_data_2022-03-15-09-54-40_0"
    rng = np.random.default_rng(4)
    world_objects = {  # ass_id -> (world centre, yaw deg, half extent)
        0: (np.array([12.0, 3.0, 0.8]), 20.0, [2.3, 1.0, 0.8]),
        1: (np.array([-6.0, -9.0, 0.9]), -95.0, [2.0, 0.95, 0.85]),
    }
    for step in range(3):
        for cav in (0, 1):
            yaw = np.radians(10.0 + 40.0 * cav + step)
            world_T_lidar = np.eye(4)
            world_T_lidar[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
            world_T_lidar[:3, 3] = [1.0 * step + 15.0 * cav, -4.0 * cav, 1.8]
            lidar_T_world = np.linalg.inv(world_T_lidar)
            vehicles = {}
            for ass_id, (centre, object_yaw, extent) in world_objects.items():
                local = lidar_T_world[:3, :3] @ centre + lidar_T_world[:3, 3]
                vehicles[10 + ass_id + 5 * cav] = {
                    "location": (local - [0.0, 0.0, 0.1]).tolist(), "center": [0.0, 0.0, 0.1],
                    "extent": list(extent), "angle": [0.0, object_yaw - np.degrees(yaw), 0.0],
                    "ass_id": ass_id, "obj_type": "Car"}
            vehicles[30 + cav] = {"location": rng.uniform(-20, 20, 3).tolist(), "center": [0.0, 0.0, 0.0],
                                  "extent": [0.4, 0.4, 0.9], "angle": [0.0, 0.0, 0.0], "ass_id": -1,
                                  "obj_type": "Pedestrian"}
            folder = scenario / str(cav)
            folder.mkdir(parents=True, exist_ok=True)
            _dump(folder / f"{step:06d}.yaml", {"lidar_pose": world_T_lidar.tolist(), "vehicles": vehicles})
            xyz, rgb = _points(seed=100 + step * 2 + cav)
            write_pcd(folder / f"{step:06d}.pcd", xyz, rgb, "binary")
    return scenario
