"""A human-readable summary of a unified dataset (``avdata info``)."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from avdata.schema.dataset import DatasetReader


def describe_dataset(root: str | Path) -> str:
    """Scenes, frames, duration, sensors and rates, classes with counts, frame tree, size on disk.

    Raises:
        InputError: the manifest, an index table or a scene file is missing or damaged.
    """
    dataset = DatasetReader(root)
    manifest = dataset.manifest
    frames = dataset.frames()
    objects = dataset.objects()
    source = manifest.get("source") or {}
    lines = [
        f"dataset:   {dataset.root}",
        f"format:    avdata {manifest.get('format_version')} "
        f"(source {source.get('name')} {source.get('version') or ''})".rstrip(),
        f"scenes:    {len(dataset.scenes)}",
        f"frames:    {frames.num_rows} ({frames.column('annotated').to_pylist().count(True)} annotated)",
    ]
    duration_ns = sum((s.get("end_ns") or 0) - (s.get("start_ns") or 0) for s in manifest["scenes"])
    lines.append(f"duration:  {duration_ns / 1e9:.2f} s")
    sensor_counts: Counter[str] = Counter()
    sensor_spans: dict[str, list[int]] = {}
    first_tree = ""
    for name in dataset.scenes:
        scene = dataset.scene(name)
        for topic in scene.topics:
            times = scene.times(topic)
            sensor_counts[topic] += len(times)
            span = sensor_spans.setdefault(topic, [0])
            span[0] += int(times[-1] - times[0]) if len(times) > 1 else 0
        if not first_tree:
            first_tree = scene.graph.describe()
    lines.append("topics:")
    for topic in sorted(sensor_counts):
        count = sensor_counts[topic]
        span_s = sensor_spans[topic][0] / 1e9
        rate = f"{(count - len(dataset.scenes)) / span_s:.2f} Hz" if span_s > 0 else "-"
        lines.append(f"  {topic:<40} {count:>8} msgs  {rate}")
    lines.append("classes:")
    for cls, count in sorted(Counter(objects.column("class").to_pylist()).items(), key=lambda kv: -kv[1]):
        lines.append(f"  {cls:<22} {count}")
    lines.append(f"frame tree (scene {dataset.scenes[0] if dataset.scenes else '-'}):")
    lines.extend("  " + line for line in first_tree.splitlines())
    lines.append(f"size:      {dataset.size_bytes() / 1e6:.2f} MB")
    return "\n".join(lines)
