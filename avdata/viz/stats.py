"""Statistics of unified datasets, side by side, and how far apart their distributions are.

Per dataset: frames, scenes, duration, class counts, box sizes per class, object range and height relative
to the ego, lidar points per object against range, occlusion mix, ego speed and each sensor's rate. Between
datasets: the 1-D Wasserstein distance (earth mover's distance, ``scipy.stats.wasserstein_distance``) of each
numeric feature, in the feature's unit, so "how far is generated data from KITTI" is one table.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt
import pyarrow as pa
from scipy.stats import wasserstein_distance

from avdata.errors import InputError
from avdata.executors.lock import prepare_folder
from avdata.outputs import refuse_output_in_input, write_atomically
from avdata.schema import DatasetReader
from avdata.schema.dataset import dataset_root
from avdata.viz.html import Picture, Section, Table, png_picture, write_html_report

if TYPE_CHECKING:  # matplotlib is imported only when plotting
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = ["DatasetStats", "FEATURES", "compare", "dataset_stats", "histogram_edges", "write_stats_report"]

#: Numeric features compared between datasets, with their unit.
FEATURES = {
    "car_length_m": "m", "car_width_m": "m", "car_height_m": "m",
    "pedestrian_height_m": "m", "object_range_m": "m", "object_height_ego_m": "m",
    "lidar_points_per_object": "points", "ego_speed_mps": "m/s",
}
# ego_speed_mps: from consecutive world_T_ego positions; scenes whose stored ego pose never changes are left out.


@dataclass(frozen=True, slots=True, kw_only=True)
class DatasetStats:
    """What :func:`dataset_stats` measures of one dataset.

    Attributes:
        name: the dataset's label in reports.
        scenes: number of scenes.
        frames: number of frames.
        annotated_frames: frames with labels.
        duration_s: summed scene durations.
        class_counts: object rows per unified class.
        occlusion_counts: visibility rows per occlusion level (best level over sensors per object and frame).
        sensor_rates_hz: median message rate per sensor.
        samples: per feature of :data:`FEATURES`, the values (N,).
        points_vs_range: (M, 2) range and lidar points of each (object, frame) with a point count.
    """

    name: str
    scenes: int
    frames: int
    annotated_frames: int
    duration_s: float
    class_counts: dict[str, int]
    occlusion_counts: dict[int, int]
    sensor_rates_hz: dict[str, float]
    samples: dict[str, np.ndarray] = field(default_factory=dict)
    points_vs_range: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


def _np(table: pa.Table, name: str, dtype: npt.DTypeLike = float) -> np.ndarray:
    # pyarrow ships no types: the column's array is declared here, where it enters numpy.
    column: np.ndarray = table[name].to_numpy(zero_copy_only=False)
    return column.astype(dtype)


def dataset_stats(root: str | Path, name: str | None = None) -> DatasetStats:
    """Measures one unified dataset from its index (no scene file is decoded but for the sensor times)."""
    ds = DatasetReader(root, verify=True)
    frames, objects, visibility = ds.frames(), ds.objects(), ds.visibility()
    label = name or Path(root).name
    scene = _np(frames, "scene", str)
    t = _np(frames, "timestamp_ns", np.int64)
    duration = 0.0
    speeds = []
    for s in np.unique(scene).tolist():
        i = np.flatnonzero(scene == s)
        i = i[np.argsort(t[i])]
        duration += (t[i[-1]] - t[i[0]]) * 1e-9 if len(i) > 1 else 0.0
        xy = np.stack([_np(frames, "world_T_ego_x_m")[i], _np(frames, "world_T_ego_y_m")[i]], axis=1)
        dt = np.diff(t[i]) * 1e-9
        ok = dt > 0
        # A scene whose ego never moves in the stored poses has no pose information (KITTI object samples):
        # its "speed" would be a made-up zero, so it is left out.
        if ok.any() and np.all(np.isfinite(xy)) and np.ptp(xy, axis=0).max() > 0:
            speeds.append(np.linalg.norm(np.diff(xy, axis=0)[ok], axis=1) / dt[ok])
    classes = _np(objects, "class", str)
    class_counts = {c: int(n) for c, n in zip(*np.unique(classes, return_counts=True), strict=True)}
    size = {k: _np(objects, k) for k in ("length_m", "width_m", "height_m")}
    ego_xyz = np.stack([_np(objects, k) for k in ("x_ego_m", "y_ego_m", "z_ego_m")], axis=1)
    samples = {
        "car_length_m": size["length_m"][classes == "car"], "car_width_m": size["width_m"][classes == "car"],
        "car_height_m": size["height_m"][classes == "car"], "pedestrian_height_m": size["height_m"][classes == "pedestrian"],
        "object_range_m": np.hypot(ego_xyz[:, 0], ego_xyz[:, 1]), "object_height_ego_m": ego_xyz[:, 2],
        "ego_speed_mps": np.concatenate(speeds) if speeds else np.zeros(0),
    }
    occlusion_counts: dict[int, int] = {}
    points_vs_range = np.zeros((0, 2))
    if len(visibility):
        key = np.char.add(np.char.add(_np(visibility, "scene", str), "\x1f"),
                          np.char.add(np.char.add(_np(visibility, "frame_index", np.int64).astype(str), "\x1f"),
                                      _np(visibility, "object_id", str)))
        occ = _np(visibility, "occlusion", np.int64)
        order = np.lexsort((occ, key))
        first = np.r_[True, key[order][1:] != key[order][:-1]]
        best = occ[order][first]
        occlusion_counts = {int(o): int(n) for o, n in zip(*np.unique(best, return_counts=True), strict=True)}
        n_points = _np(visibility, "n_points", np.int64)
        # Points per object: the sum over lidars of each (object, frame); -1 means unknown (camera labels).
        lidar = n_points >= 0
        if lidar.any():
            ukey, inverse = np.unique(key[lidar], return_inverse=True)
            total = np.bincount(inverse, weights=n_points[lidar])
            okey = np.char.add(np.char.add(_np(objects, "scene", str), "\x1f"),
                               np.char.add(np.char.add(_np(objects, "frame_index", np.int64).astype(str), "\x1f"),
                                           _np(objects, "object_id", str)))
            pos = np.clip(np.searchsorted(ukey, okey), 0, len(ukey) - 1)
            found = ukey[pos] == okey
            points_vs_range = np.stack([samples["object_range_m"][found], total[pos[found]]], axis=1)
    samples["lidar_points_per_object"] = points_vs_range[:, 1]
    rates = {}
    for s in ds.scenes[:1]:
        reader = ds.scene(s)
        for sensor in reader.sensors():
            times = [reader.times(topic) for topic in reader.topics if topic.startswith(f"/{sensor}/") and
                     topic.rsplit("/", 1)[1] in ("points", "image")]
            if times and len(times[0]) > 1:
                rates[sensor] = float(1e9 / np.median(np.diff(times[0])))
    return DatasetStats(name=label, scenes=len(ds.scenes), frames=len(frames),
                        annotated_frames=int(_np(frames, "annotated", bool).sum()), duration_s=duration,
                        class_counts=class_counts, occlusion_counts=occlusion_counts, sensor_rates_hz=rates,
                        samples={k: v[np.isfinite(v)] for k, v in samples.items()}, points_vs_range=points_vs_range)


def compare(stats: list[DatasetStats]) -> dict[tuple[str, str], dict[str, float]]:
    """Wasserstein distance of every feature for every pair of datasets (NaN where a side has no samples)."""
    out = {}
    for i, a in enumerate(stats):
        for b in stats[i + 1:]:
            out[(a.name, b.name)] = {
                f: float(wasserstein_distance(a.samples[f], b.samples[f])) if len(a.samples[f]) and len(b.samples[f])
                else math.nan for f in FEATURES}
    return out


def _tables(stats: list[DatasetStats]) -> list[Table]:
    """The report's tables, each cell as text (the Markdown and the web page show the same cells)."""
    names = [s.name for s in stats]
    overview = Table("Datasets", ["dataset", "scenes", "frames", "annotated", "duration s", "objects", "sensors (rate Hz)"], [
        [s.name, str(s.scenes), str(s.frames), str(s.annotated_frames), f"{s.duration_s:.1f}", str(sum(s.class_counts.values())),
         ", ".join(f"{k} {v:.1f}" for k, v in sorted(s.sensor_rates_hz.items()))] for s in stats])
    all_classes = sorted({c for s in stats for c in s.class_counts})
    classes = Table("Objects per class", ["class", *names],
                    [[c, *(str(s.class_counts.get(c, 0)) for s in stats)] for c in all_classes])
    occlusion = Table("Occlusion (best level over sensors per object and frame; 0 none .. 3 full/unknown)",
                      ["level", *names], [[str(lvl), *(str(s.occlusion_counts.get(lvl, 0)) for s in stats)] for lvl in range(4)])
    rows = []
    for feature, unit in FEATURES.items():
        cells = []
        for s in stats:
            v = s.samples[feature]
            cells.append(f"{np.median(v):.2f} ({np.percentile(v, 10):.2f}-{np.percentile(v, 90):.2f}) {unit}" if len(v) else "-")
        rows.append([feature, *cells])
    features = Table("Feature distributions (median, 10th-90th percentile)", ["feature", *names], rows)
    tables = [overview, classes, occlusion, features]
    if len(stats) > 1:
        tables.append(Table("Distance between datasets (1-D Wasserstein, in the feature's unit)", ["pair", *FEATURES], [
            [f"{a} vs {b}", *("-" if math.isnan(v) else f"{v:.3f}" for v in row.values())]
            for (a, b), row in compare(stats).items()]))
    return tables


def _markdown(table: Table) -> list[str]:
    """The table in Markdown (its cells are text: :func:`_tables` gives no (text, number) cells)."""
    return ["", f"## {table.title}", "", "| " + " | ".join(table.columns) + " |", "|" + "---|" * len(table.columns),
            *("| " + " | ".join(str(cell) for cell in row) + " |" for row in table.rows)]


def histogram_edges(samples: list[np.ndarray], bins: int = 40) -> np.ndarray:
    """Bin edges shared by every dataset's histogram of one feature, also when all values are (nearly) equal.

    A feature whose values are all equal, or differ by float noise (a generator's fixed car length), has no
    range to split into ``bins`` finite bins; it gets a window of +/- 0.5 % (at least 1e-3) around its value.
    """
    values = np.concatenate(samples)
    low, high = float(values.min()), float(values.max())
    pad = max(abs(low), abs(high), 1.0) * 5e-3
    if high - low < pad * 1e-3:
        low, high = low - pad, high + pad
    return np.linspace(low, high, bins + 1)


def write_stats_report(roots: list[str | Path], out: str | Path) -> list[Path]:
    """Writes ``report.html``, ``stats.md`` and PNG plots comparing the datasets at ``roots`` into ``out``.

    Returns:
        The files written: ``report.html``, ``stats.md``, then the plots.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from avdata.viz.render import frame_pictures

    if not roots:
        raise InputError("stats: expected at least one dataset, got none")
    refuse_output_in_input(Path(out), [dataset_root(root) for root in roots], "DATASET")
    out = prepare_folder(Path(out))  # a FIFO, a file, a name too long: one line each
    names = [Path(r).name for r in roots]
    if len(set(names)) != len(names):
        names = [f"{i}:{n}" for i, n in enumerate(names)]
    stats = [dataset_stats(r, n) for r, n in zip(roots, names, strict=True)]
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    written: list[Path] = []
    tables = _tables(stats)
    lines = ["# Dataset statistics"]
    for table in tables:
        lines += _markdown(table)
    plots: list[tuple[str, Path]] = []
    for feature, unit in FEATURES.items():
        present = [s for s in stats if len(s.samples[feature])]
        if not present:
            continue
        edges = histogram_edges([s.samples[feature] for s in present])
        fig, ax = plt.subplots(figsize=(5, 3.2), dpi=100)
        for i, s in enumerate(stats):
            if len(s.samples[feature]):
                ax.hist(s.samples[feature], bins=edges.tolist(), density=True, histtype="step", linewidth=1.5,
                        color=colors[i % len(colors)], label=f"{s.name} (n={len(s.samples[feature])})")
        ax.set_xlabel(f"{feature} ({unit})")
        ax.set_ylabel("density")
        plots.append((feature, _save_plot(fig, ax, out / f"{feature}.png")))
    notes = []
    if any(len(s.points_vs_range) for s in stats):
        fig, ax = plt.subplots(figsize=(5, 3.2), dpi=100)
        for i, s in enumerate(stats):
            if len(s.points_vs_range):
                ax.scatter(s.points_vs_range[:, 0], np.maximum(s.points_vs_range[:, 1], 0.5), s=2, alpha=0.4,
                           color=colors[i % len(colors)], label=s.name)
        ax.set_yscale("log")
        ax.set_xlabel("range from ego (m)")
        ax.set_ylabel("lidar points in box")
        plots.append(("points vs range", _save_plot(fig, ax, out / "points_vs_range.png")))
    else:  # e.g. KITTI: camera labels without lidar point counts (n_points -1)
        notes.append("No points-vs-range plot: no dataset records lidar points per object.")
    all_classes = sorted({c for s in stats for c in s.class_counts})
    if all_classes:
        fig, ax = plt.subplots(figsize=(6, 3.2), dpi=100)
        width = 0.8 / len(stats)
        for i, s in enumerate(stats):
            total = max(sum(s.class_counts.values()), 1)
            ax.bar(np.arange(len(all_classes)) + i * width, [s.class_counts.get(c, 0) / total for c in all_classes], width,
                   color=colors[i % len(colors)], label=s.name)
        ax.set_xticks(np.arange(len(all_classes)) + width * (len(stats) - 1) / 2, all_classes, rotation=45, fontsize=7)
        ax.set_ylabel("fraction of objects")
        plots.append(("classes", _save_plot(fig, ax, out / "classes.png")))
    else:
        notes.append("No class plot: no dataset has labels.")
    lines += [f"\n{note}" for note in notes]
    lines += [f"\n![{title}]({path.name})" for title, path in plots]
    frames = [frame_pictures(root) for root in roots]
    sections = [Section("Tables", tables=tables, notes=notes),
                Section("Plots", pictures=[png_picture(title, path) for title, path in plots]),
                *(Section(f"Frames of {name}", pictures=[Picture(c, png) for c, png in pictures], notes=frame_notes)
                  for name, (pictures, frame_notes) in zip(names, frames, strict=True))]
    written.append(write_html_report(out / "report.html", "Dataset statistics: " + ", ".join(names), sections))
    write_atomically(out / "stats.md", "\n".join(lines) + "\n")
    written.append(out / "stats.md")
    return written + [path for _, path in plots]


def _save_plot(fig: Figure, ax: Axes, path: Path) -> Path:
    """Writes one plot (legend, tight layout) as PNG through the atomic writer, closes it; returns the path."""
    import io

    import matplotlib.pyplot as plt  # only when plotting (as above)

    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    plt.close(fig)
    write_atomically(path, buffer.getvalue())
    return path
