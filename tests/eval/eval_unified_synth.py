"""A small unified dataset (objects + visibility tables) built in memory, and written through the schema."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq


def make_tables(seed: int = 0, n_frames: int = 20, n_objects: int = 6) -> tuple[pa.Table, pa.Table]:
    """Objects moving in a straight line past an ego vehicle at (10 t, 0) heading +x; object 0 is never seen
    by any sensor; object 1 only by the camera."""
    rng = np.random.default_rng(seed)
    rows, vis = [], []
    start = rng.uniform(-30, 30, (n_objects, 2))
    vel = rng.uniform(-2, 2, (n_objects, 2))
    classes = ["car", "pedestrian", "car", "cyclist", "car", "pedestrian"]
    for f in range(n_frames):
        ego = np.array([1.0 * f, 0.0])
        for o in range(n_objects):
            xy = start[o] + vel[o] * f + ego
            rows.append({
                "scene": "s0", "frame_index": f, "timestamp_ns": f * 100_000_000, "object_id": f"obj{o}",
                "class": classes[o % len(classes)], "source_class": classes[o % len(classes)],
                "x_world_m": xy[0], "y_world_m": xy[1], "z_world_m": 0.8, "length_m": 4.0, "width_m": 1.8,
                "height_m": 1.6, "yaw_world_rad": 0.3, "qw_world": np.cos(0.15), "qx_world": 0.0, "qy_world": 0.0,
                "qz_world": np.sin(0.15), "x_ego_m": xy[0] - ego[0], "y_ego_m": xy[1] - ego[1], "z_ego_m": 0.8,
                "yaw_ego_rad": 0.3, "vx_world_mps": vel[o, 0] * 10, "vy_world_mps": vel[o, 1] * 10, "vz_world_mps": 0.0,
            })
            for sensor in ("ego/lidar_top", "ego/cam_front"):
                seen = o != 0 and (sensor == "ego/cam_front" or o != 1)
                vis.append({
                    "scene": "s0", "frame_index": f, "timestamp_ns": f * 100_000_000, "sensor": sensor,
                    "object_id": f"obj{o}", "in_fov": bool(seen), "n_points": 10 if seen and "lidar" in sensor else 0,
                    "visible_fraction": 0.8 if seen and "cam" in sensor else float("nan"),
                    "occlusion": o % 3, "truncation": 0.0, "box2d_x0_px": 0.0, "box2d_y0_px": 0.0,
                    "box2d_x1_px": 10.0, "box2d_y1_px": 10.0,
                })
    return pa.Table.from_pylist(rows), pa.Table.from_pylist(vis)


def make_frames(objects: pa.Table) -> pa.Table:
    """The frames table of :func:`make_tables`' scenes: the ego vehicle at (frame_index, 0, 0), heading +x."""
    keys = sorted(set(zip(objects["scene"].to_pylist(), objects["frame_index"].to_pylist(), strict=True)))
    return pa.Table.from_pylist([
        {"scene": s, "frame_index": f, "timestamp_ns": f * 100_000_000, "annotated": True, "split": "train",
         "ego_frame": "ego", "world_T_ego_x_m": float(f), "world_T_ego_y_m": 0.0, "world_T_ego_z_m": 0.0,
         "world_T_ego_qw": 1.0, "world_T_ego_qx": 0.0, "world_T_ego_qy": 0.0, "world_T_ego_qz": 0.0,
         "n_objects": int(np.sum((objects["scene"].to_numpy(zero_copy_only=False) == s)
                                 & (objects["frame_index"].to_numpy() == f)))}
        for s, f in keys
    ])


def write_dataset(root: Path, objects: pa.Table, visibility: pa.Table) -> Path:
    """A dataset folder holding only the manifest and the index tables (what evaluation reads).

    The manifest records each table's checksum, as a written dataset's does: readers check them.
    """
    from avdata.schema.dataset import index_checksum
    from avdata.schema.index import SCHEMAS
    from avdata.schema.manifest import MANIFEST, manifest_text

    (root / "index").mkdir(parents=True, exist_ok=True)
    checksums = {}
    for name, table in (("frames", make_frames(objects)), ("objects", objects), ("visibility", visibility)):
        schema = SCHEMAS[name]
        cols = {f.name: (table[f.name].cast(f.type) if f.name in table.column_names else pa.nulls(len(table), f.type))
                for f in schema}
        pq.write_table(pa.table(cols, schema=schema), root / "index" / f"{name}.parquet")
        checksums[name] = index_checksum(root / "index" / f"{name}.parquet")
    manifest = {"format": "avdata", "format_version": "1.0", "scenes": [], "index": checksums}
    (root / MANIFEST).write_text(manifest_text(manifest))
    return root



def perfect_dataset(root: Path) -> tuple[Path, list[dict]]:
    """A dataset of :func:`make_tables` at ``root`` and its ground truth as detection rows of score 0.8."""
    objects, visibility = make_tables()
    write_dataset(root, objects, visibility)
    rows = [r | {"score": 0.8} for r in objects.select(
        ["scene", "frame_index", "object_id", "class", "x_world_m", "y_world_m", "z_world_m", "length_m",
         "width_m", "height_m", "yaw_world_rad"]).to_pylist()]
    return root, rows


def replace_index_table(root: Path, name: str, table: pa.Table) -> None:
    """Writes index table ``name`` of dataset ``root`` and records its checksum in the manifest.

    What a writer whose index disagrees with its scene files would leave: readers see a consistent
    dataset, as they would a real one whose content is the test's case.
    """
    from avdata.schema.dataset import index_checksum
    from avdata.schema.manifest import MANIFEST, manifest_text, read_manifest

    path = root / "index" / f"{name}.parquet"
    pq.write_table(table, path)
    manifest = read_manifest(root / MANIFEST)
    manifest["index"] = {**manifest["index"], name: index_checksum(path)}
    (root / MANIFEST).write_text(manifest_text(manifest))
