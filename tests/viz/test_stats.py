"""Dataset statistics and the distances between datasets."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from scipy.stats import wasserstein_distance

from avdata.cli import main
from avdata.viz.stats import FEATURES, compare, dataset_stats


def test_counts_and_samples_come_from_the_index(generated: Path) -> None:
    stats = dataset_stats(generated)
    objects = pq.read_table(generated / "index" / "objects.parquet").to_pydict()
    classes, counts = np.unique(objects["class"], return_counts=True)
    assert stats.class_counts == dict(zip(classes.tolist(), counts.tolist(), strict=True))
    assert (stats.scenes, stats.frames, stats.annotated_frames) == (1, 3, 3)
    assert stats.duration_s == pytest.approx(0.2)
    cars = np.array(objects["class"]) == "car"
    np.testing.assert_array_equal(np.sort(stats.samples["car_length_m"]), np.sort(np.array(objects["length_m"])[cars]))
    ranges = np.hypot(objects["x_ego_m"], objects["y_ego_m"])
    np.testing.assert_allclose(np.sort(stats.samples["object_range_m"]), np.sort(ranges))
    assert set(stats.sensor_rates_hz) >= {"ego/lidar_top", "ego/cam_front"}
    assert stats.sensor_rates_hz["ego/lidar_top"] == pytest.approx(10.0)
    # The ego drives: a positive speed from its stored poses.
    assert stats.samples["ego_speed_mps"].min() >= 0 and len(stats.samples["ego_speed_mps"]) == 2


def test_distances(generated: Path, kitti_object: Path) -> None:
    gen, kitti = dataset_stats(generated, "gen"), dataset_stats(kitti_object, "kitti")
    same = compare([gen, dataset_stats(generated, "gen again")])[("gen", "gen again")]
    assert all(v == 0.0 for v in same.values())
    d = compare([gen, kitti])[("gen", "kitti")]
    assert d["car_length_m"] == pytest.approx(wasserstein_distance(gen.samples["car_length_m"], kitti.samples["car_length_m"]))
    assert np.isnan(d["ego_speed_mps"])  # KITTI object samples carry no ego motion: left out, not zero
    assert set(d) == set(FEATURES)


def test_stats_command(generated: Path, kitti_object: Path, tmp_path: Path) -> None:
    assert main(["stats", str(generated), str(kitti_object), "--out", str(tmp_path)]) == 0
    report = (tmp_path / "stats.md").read_text()
    assert "| v2i vs kitti-object |" in report and "## Objects per class" in report
    assert (tmp_path / "car_length_m.png").stat().st_size > 1000 and (tmp_path / "classes.png").is_file()
    assert main(["stats", str(tmp_path / "missing"), "--out", str(tmp_path)]) == 1
