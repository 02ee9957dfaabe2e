"""Randomised nuScenes-schema tables and a detection submission, written to a temporary folder."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

CATEGORIES = {
    "car": "vehicle.car", "truck": "vehicle.truck", "bus": "vehicle.bus.rigid", "trailer": "vehicle.trailer",
    "construction_vehicle": "vehicle.construction", "pedestrian": "human.pedestrian.adult",
    "motorcycle": "vehicle.motorcycle", "bicycle": "vehicle.bicycle", "traffic_cone": "movable_object.trafficcone",
    "barrier": "movable_object.barrier",
}
ATTRIBUTES = {
    "vehicle": ["vehicle.moving", "vehicle.parked", "vehicle.stopped"],
    "cycle": ["cycle.with_rider", "cycle.without_rider"],
    "pedestrian": ["pedestrian.moving", "pedestrian.standing", "pedestrian.sitting_lying_down"],
}
CLASS_ATTR = {"car": "vehicle", "truck": "vehicle", "bus": "vehicle", "trailer": "vehicle",
              "construction_vehicle": "vehicle", "pedestrian": "pedestrian", "motorcycle": "cycle",
              "bicycle": "cycle"}
SCENES = ["scene-0103", "scene-0916"]
TRACKING_CLASSES = ["bicycle", "bus", "car", "motorcycle", "pedestrian", "trailer", "truck"]  # the devkit's mini_val split


def quat_z(yaw: float) -> list[float]:
    return [float(np.cos(yaw / 2)), 0.0, 0.0, float(np.sin(yaw / 2))]


def write_nuscenes(root: Path, seed: int, samples_per_scene: int = 8, instances_per_scene: int = 40) -> Path:
    """Writes ``root/v1.0-mini/*.json``, ``root/maps/prior.png``, a detection submission ``root/results.json``
    (returned) and a tracking submission ``root/tracking.json``."""
    rng = np.random.default_rng(seed)
    t = {k: [] for k in ("category", "attribute", "visibility", "instance", "sensor", "calibrated_sensor",
                         "ego_pose", "log", "scene", "sample", "sample_data", "sample_annotation", "map")}
    for i, (cls, cat) in enumerate(CATEGORIES.items()):
        t["category"].append({"token": f"cat-{cls}", "name": cat, "description": "", "index": i})
    t["category"].append({"token": "cat-rack", "name": "static_object.bicycle_rack", "description": "",
                          "index": len(CATEGORIES)})
    attr_token = {}
    for names in ATTRIBUTES.values():
        for name in names:
            attr_token[name] = f"attr-{name}"
            t["attribute"].append({"token": attr_token[name], "name": name, "description": ""})
    t["sensor"].append({"token": "sensor-lidar", "channel": "LIDAR_TOP", "modality": "lidar"})
    t["calibrated_sensor"].append({"token": "cs-lidar", "sensor_token": "sensor-lidar", "translation": [0, 0, 1.8],
                                   "rotation": [1, 0, 0, 0], "camera_intrinsic": []})
    t["log"].append({"token": "log-0", "logfile": "", "vehicle": "", "date_captured": "", "location": "x"})
    t["map"].append({"token": "map-0", "log_tokens": ["log-0"], "category": "semantic_prior",
                     "filename": "maps/prior.png"})
    results: dict[str, list] = {}
    tracking: dict[str, list] = {}
    classes = list(CATEGORIES)
    for s_idx, scene in enumerate(SCENES):
        tokens = [f"s{s_idx}-{k}" for k in range(samples_per_scene)]
        ego = np.cumsum(rng.normal(0, 3, (samples_per_scene, 3)), axis=0) * [1, 1, 0] + [100 * s_idx, 50, 0]
        for k, tok in enumerate(tokens):
            ts = 1_000_000 * (10 * s_idx) + 500_000 * k
            t["sample"].append({"token": tok, "timestamp": ts, "scene_token": f"scene-{s_idx}",
                                "prev": tokens[k - 1] if k else "", "next": tokens[k + 1] if k + 1 < len(tokens) else ""})
            t["ego_pose"].append({"token": f"pose-{tok}", "timestamp": ts, "translation": ego[k].tolist(),
                                  "rotation": [1, 0, 0, 0]})
            t["sample_data"].append({"token": f"sd-{tok}", "sample_token": tok, "ego_pose_token": f"pose-{tok}",
                                     "calibrated_sensor_token": "cs-lidar", "timestamp": ts, "fileformat": "pcd",
                                     "is_key_frame": True, "height": 0, "width": 0, "filename": "", "prev": "",
                                     "next": ""})
            results[tok] = []
            tracking[tok] = []
        t["scene"].append({"token": f"scene-{s_idx}", "log_token": "log-0", "nbr_samples": samples_per_scene,
                           "first_sample_token": tokens[0], "last_sample_token": tokens[-1], "name": scene,
                           "description": ""})
        cycle_at: dict[str, np.ndarray] = {}  # sample -> centre of its first bicycle or motorcycle
        for inst in range(instances_per_scene):
            cls = classes[rng.integers(len(classes))]
            itok = f"inst-{s_idx}-{inst}"
            start = int(rng.integers(0, samples_per_scene - 1))
            stop = int(rng.integers(start + 1, samples_per_scene + 1))
            pos0 = ego[start] + np.r_[rng.uniform(-55, 55, 2), rng.normal(0, 0.5)]
            vel = rng.normal(0, 3, 3) * [1, 1, 0]
            size = rng.uniform([0.5, 0.5, 0.8], [3.0, 8.0, 3.5])  # w, l, h
            yaw = rng.uniform(-np.pi, np.pi)
            ann_tokens = [f"ann-{s_idx}-{inst}-{k}" for k in range(start, stop)]
            t["instance"].append({"token": itok, "category_token": f"cat-{cls}", "nbr_annotations": len(ann_tokens),
                                  "first_annotation_token": ann_tokens[0], "last_annotation_token": ann_tokens[-1]})
            switch_at = start + int(rng.integers(0, max(1, stop - start))) if rng.random() < 0.3 else stop
            for j, k in enumerate(range(start, stop)):
                pos = pos0 + vel * 0.5 * (k - start) + rng.normal(0, 0.05, 3)
                group = CLASS_ATTR.get(cls)
                attrs = [] if group is None or rng.random() < 0.1 else [attr_token[rng.choice(ATTRIBUTES[group])]]
                t["sample_annotation"].append({
                    "token": ann_tokens[j], "sample_token": tokens[k], "instance_token": itok,
                    "visibility_token": "", "attribute_tokens": attrs, "translation": pos.tolist(),
                    "size": size.tolist(), "rotation": quat_z(yaw + rng.normal(0, 0.02)),
                    "prev": ann_tokens[j - 1] if j else "", "next": ann_tokens[j + 1] if j + 1 < len(ann_tokens) else "",
                    "num_lidar_pts": int(rng.integers(0, 30)) if rng.random() > 0.1 else 0,
                    "num_radar_pts": int(rng.integers(0, 2)),
                })
                if cls in ("bicycle", "motorcycle"):
                    cycle_at.setdefault(tokens[k], pos)
                if cls in TRACKING_CLASSES and rng.random() < 0.8:
                    tracking[tokens[k]].append({
                        "sample_token": tokens[k], "translation": (pos + rng.normal(0, 0.5, 3) * [1, 1, 0.2]).tolist(),
                        "size": size.tolist(), "rotation": quat_z(yaw), "velocity": vel[:2].tolist(),
                        "tracking_id": f"{itok}-{int(k >= switch_at)}", "tracking_name": cls,
                        "tracking_score": float(rng.uniform(0.1, 1)),
                    })
                if rng.random() < 0.85:
                    p_cls = cls if rng.random() > 0.1 else classes[rng.integers(len(classes))]
                    p_group = CLASS_ATTR.get(p_cls)
                    results[tokens[k]].append({
                        "sample_token": tokens[k],
                        "translation": (pos + rng.normal(0, 0.7, 3) * [1, 1, 0.3]).tolist(),
                        "size": (size * rng.uniform(0.7, 1.3, 3)).tolist(),
                        "rotation": quat_z(yaw + rng.normal(0, 0.4) + (np.pi if rng.random() < 0.1 else 0)),
                        "velocity": (vel[:2] + rng.normal(0, 1, 2)).tolist(),
                        "detection_name": p_cls, "detection_score": float(rng.uniform(0.05, 1)),
                        "attribute_name": str(rng.choice(ATTRIBUTES[p_group])) if p_group else "",
                    })
        # A bicycle rack around the first cycle of every sample that has one: the devkit then drops that cycle
        # and every predicted cycle centred in the rack from the evaluation.
        for tok, centre in cycle_at.items():
            t["instance"].append({"token": f"rack-{tok}", "category_token": "cat-rack", "nbr_annotations": 1,
                                  "first_annotation_token": f"rack-ann-{tok}", "last_annotation_token": f"rack-ann-{tok}"})
            t["sample_annotation"].append({
                "token": f"rack-ann-{tok}", "sample_token": tok, "instance_token": f"rack-{tok}",
                "visibility_token": "", "attribute_tokens": [], "translation": centre.tolist(),
                "size": [2.5, 3.0, 2.0], "rotation": quat_z(0.3), "prev": "", "next": "",
                "num_lidar_pts": 10, "num_radar_pts": 0,
            })
        for tok, e in zip(tokens, ego, strict=True):
            for n_fp in range(int(rng.integers(1, 5))):
                tracking[tok].append({
                    "sample_token": tok, "translation": (e + np.r_[rng.uniform(-40, 40, 2), 0]).tolist(),
                    "size": [2.0, 4.0, 1.5], "rotation": quat_z(0.0), "velocity": [0.0, 0.0],
                    "tracking_id": f"fp-{tok}-{n_fp}", "tracking_name": TRACKING_CLASSES[rng.integers(7)],
                    "tracking_score": float(rng.uniform(0.05, 0.7)),
                })
            for _ in range(int(rng.integers(3, 12))):
                p_cls = classes[rng.integers(len(classes))]
                p_group = CLASS_ATTR.get(p_cls)
                results[tok].append({
                    "sample_token": tok, "translation": (e + np.r_[rng.uniform(-50, 50, 2), 0]).tolist(),
                    "size": rng.uniform([0.5, 0.5, 0.8], [3.0, 8.0, 3.5]).tolist(),
                    "rotation": quat_z(rng.uniform(-np.pi, np.pi)), "velocity": rng.normal(0, 2, 2).tolist(),
                    "detection_name": p_cls, "detection_score": float(rng.uniform(0.05, 0.8)),
                    "attribute_name": str(rng.choice(ATTRIBUTES[p_group])) if p_group else "",
                })
    tables = root / "v1.0-mini"
    tables.mkdir(parents=True, exist_ok=True)
    for name, rows in t.items():
        (tables / f"{name}.json").write_text(json.dumps(rows))
    (root / "maps").mkdir(exist_ok=True)
    (root / "maps" / "prior.png").write_bytes(b"")
    (root / "tracking.json").write_text(json.dumps({"meta": {"use_camera": False, "use_lidar": True,
                                                              "use_radar": False, "use_map": False,
                                                              "use_external": False}, "results": tracking}))
    submission = root / "results.json"
    submission.write_text(json.dumps({"meta": {"use_camera": False, "use_lidar": True, "use_radar": False,
                                               "use_map": False, "use_external": False}, "results": results}))
    return submission
