"""A human-readable summary of a unified dataset (``avdata info``).

It reads the manifest and each scene's MCAP summary, message indexes and label messages only: not the
Parquet index, so the command runs without pyarrow for a local dataset (start-up time and memory of a quick
look). The counts are the index's: one frame per ``/labels/objects`` message, its ``annotated`` flag and its
objects' classes. A dataset in an object store (``s3://``, ``gs://``) is read through pyarrow's filesystems:
each scene's summary, message indexes and label messages by ranged requests, never its sensor data.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING

from avdata.schema.manifest import dataset_size_bytes, open_manifest, scene_file
from avdata.schema.scene_reader import SceneReader

if TYPE_CHECKING:
    from avdata.storage import Location


def describe_dataset(root: str | Path | Location) -> str:
    """Scenes, frames, duration, sensors and rates, classes with counts, frame tree, size on disk.

    Args:
        root: the dataset folder, or its prefix in an object store (``s3://bucket/prefix``).

    Raises:
        InputError: the manifest or a scene file is missing or damaged.
    """
    if isinstance(root, str) and "://" in root or not isinstance(root, str | Path):
        from avdata.schema.dataset import dataset_root, open_scene

        root = dataset_root(root)
    else:
        root = Path(root)
    manifest = open_manifest(root)
    scene_names: list[str] = [s["name"] for s in manifest["scenes"]]
    sensor_counts: Counter[str] = Counter()
    sensor_spans: dict[str, list[int]] = {}
    classes: Counter[str] = Counter()
    n_frames = n_annotated = 0
    first_tree = ""
    for name in scene_names:
        scene = SceneReader(scene_file(root, name)) if isinstance(root, Path) else open_scene(root, name)
        try:
            for topic in scene.topics:
                times = scene.times(topic)
                sensor_counts[topic] += len(times)
                span = sensor_spans.setdefault(topic, [0])
                span[0] += int(times[-1] - times[0]) if len(times) > 1 else 0
            for annotated, frame_classes in scene.frame_classes():
                n_frames += 1
                n_annotated += annotated
                classes.update(frame_classes)
            if not first_tree:
                first_tree = scene.graph.describe()
        finally:
            scene.close()
    source = manifest.get("source") or {}
    lines = [
        f"dataset:   {root}",
        f"format:    avdata {manifest.get('format_version')} "
        f"(source {source.get('name')} {source.get('version') or ''})".rstrip(),
        f"scenes:    {len(scene_names)}",
        f"frames:    {n_frames} ({n_annotated} annotated)",
    ]
    duration_ns = sum((s.get("end_ns") or 0) - (s.get("start_ns") or 0) for s in manifest["scenes"])
    lines.append(f"duration:  {duration_ns / 1e9:.2f} s")
    lines.append("topics:")
    for topic in sorted(sensor_counts):
        count = sensor_counts[topic]
        span_s = sensor_spans[topic][0] / 1e9
        rate = f"{(count - len(scene_names)) / span_s:.2f} Hz" if span_s > 0 else "-"
        lines.append(f"  {topic:<40} {count:>8} msgs  {rate}")
    lines.append("classes:")
    for cls, count in sorted(classes.items(), key=lambda kv: -kv[1]):
        lines.append(f"  {cls:<22} {count}")
    lines.append(f"frame tree (scene {scene_names[0] if scene_names else '-'}):")
    lines.extend("  " + line for line in first_tree.splitlines())
    lines.append(f"size:      {dataset_size_bytes(root) / 1e6:.2f} MB")
    return "\n".join(lines)
