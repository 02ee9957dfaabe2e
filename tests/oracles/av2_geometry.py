"""av2-api 0.3.6's own geometry on one Argoverse 2 log (run with .oracle-envs/av2/bin/python).

Usage: av2_geometry.py SPLIT_DIR LOG_ID OUT.npz

Writes, with av2's own classes only:
- ``points_city_<ts>``: every sweep's points in the city frame, ``AV2SensorDataLoader.get_city_SE3_ego``
  then ``SE3.transform_point_cloud`` of ``Sweep.from_feather(...).xyz``;
- ``vertices_city`` (M, 8, 3), ``cuboid_ts`` (M,), ``cuboid_uuid`` (M,): every annotation's
  ``CuboidList.transform(city_SE3_ego).vertices_m`` at its timestamp, in annotations.feather row order;
- ``uv_<camera>``, ``valid_<camera>``: ``PinholeCamera.from_feather(...).project_ego_to_img`` of the
  first sweep's points (egovehicle frame);
and prints a JSON summary.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from av2.datasets.sensor.av2_sensor_dataloader import AV2SensorDataLoader
from av2.geometry.camera.pinhole_camera import PinholeCamera
from av2.structures.cuboid import CuboidList
from av2.structures.sweep import Sweep
from av2.utils.io import read_feather


def main() -> None:
    split_dir, log_id, out = Path(sys.argv[1]), sys.argv[2], Path(sys.argv[3])
    loader = AV2SensorDataLoader(data_dir=split_dir, labels_dir=split_dir)
    arrays: dict[str, np.ndarray] = {}
    sweep_times = loader.get_ordered_log_lidar_timestamps(log_id)
    first_xyz = None
    for ts in sweep_times:
        sweep = Sweep.from_feather(loader.get_lidar_fpath(log_id, ts))
        city_SE3_ego = loader.get_city_SE3_ego(log_id, ts)
        arrays[f"points_city_{ts}"] = city_SE3_ego.transform_point_cloud(sweep.xyz)
        if first_xyz is None:
            first_xyz = sweep.xyz
    log_dir = split_dir / log_id
    annotations = read_feather(log_dir / "annotations.feather")
    cuboids = CuboidList.from_feather(log_dir / "annotations.feather")
    vertices = np.zeros((len(cuboids.cuboids), 8, 3))
    for ts in sorted(set(annotations["timestamp_ns"].tolist())):
        index = [i for i, c in enumerate(cuboids.cuboids) if c.timestamp_ns == ts]
        sweep_cuboids = CuboidList([cuboids.cuboids[i] for i in index])
        city = sweep_cuboids.transform(loader.get_city_SE3_ego(log_id, ts))
        vertices[index] = city.vertices_m
    arrays["vertices_city"] = vertices
    arrays["cuboid_ts"] = annotations["timestamp_ns"].to_numpy()
    arrays["cuboid_uuid"] = annotations["track_uuid"].to_numpy().astype(str)
    cameras = read_feather(log_dir / "calibration" / "intrinsics.feather")["sensor_name"].tolist()
    for camera in cameras:
        pinhole = PinholeCamera.from_feather(log_dir, camera)
        uv, _, valid = pinhole.project_ego_to_img(first_xyz)
        arrays[f"uv_{camera}"] = uv
        arrays[f"valid_{camera}"] = valid
    np.savez(out, **arrays)
    print(json.dumps({"sweeps": [int(t) for t in sweep_times], "cuboids": len(vertices), "cameras": cameras}))


if __name__ == "__main__":
    main()
