"""Argoverse 2 detection protocol against av2-api 0.3.6's own ``evaluate`` (in its venv) on the real log.

Ground truth: the real val log's ``annotations.feather`` (11,364 cuboids, 156 sweeps), its real map
(the ROI raster) and ego poses. Detections: perturbed copies of the ground truth in the same format
(centre noise at several scales so every threshold matters, size and heading noise, dropped
cuboids, swapped categories, false positives, far-away boxes beyond 150 m, more than 100 boxes of
one category in one sweep), each with a distinct score.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather
import pytest

from avdata.eval.cli import add_eval_subparser
from avdata.eval.detection.av2 import (
    AVERAGE,
    CUBOID_COLUMNS,
    METRICS,
    Av2DetectionConfig,
    evaluate_av2_detection,
    read_detections,
    read_ground_truth,
)
from tests.eval.eval_oracle_env import run_oracle

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "realdata" / "argoverse2" / "sensor"
SPLIT = REAL / "val"
LOG = "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"


def ground_truth_table() -> pa.Table:
    table = feather.read_table(SPLIT / LOG / "annotations.feather")
    return table.append_column("log_id", pa.array([LOG] * table.num_rows))


def perturbed_detections(seed: int) -> pa.Table:
    """Perturbed copies of the real cuboids plus false positives; every score distinct."""
    rng = np.random.default_rng(seed)
    gts = ground_truth_table()
    n = gts.num_rows
    keep = rng.random(n) > 0.15
    columns = {c: gts.column(c).to_numpy().astype(np.float64)[keep] for c in CUBOID_COLUMNS}
    m = int(keep.sum())
    noise_m = rng.choice([0.1, 0.4, 0.8, 1.5, 3.0], size=m)
    for axis in ("tx_m", "ty_m", "tz_m"):
        columns[axis] = columns[axis] + rng.normal(0.0, 1.0, m) * noise_m / math.sqrt(3)
    for size in ("length_m", "width_m", "height_m"):
        columns[size] = columns[size] * rng.uniform(0.8, 1.25, m)
    yaw = rng.normal(0.0, 0.3, m) + np.where(rng.random(m) < 0.05, math.pi, 0.0)
    q = np.stack([columns[k] for k in ("qw", "qx", "qy", "qz")], axis=1)
    dq = np.stack([np.cos(yaw / 2), np.zeros(m), np.zeros(m), np.sin(yaw / 2)], axis=1)
    # q * dq (Hamilton): turn each cuboid about its own z axis
    w1, x1, y1, z1 = q.T
    w2, x2, y2, z2 = dq.T
    columns["qw"], columns["qx"] = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
    columns["qy"], columns["qz"] = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
    categories = np.asarray(gts.column("category").to_pylist())[keep]
    swap = rng.random(m) < 0.05
    categories[swap] = rng.choice(["REGULAR_VEHICLE", "PEDESTRIAN", "BICYCLE", "SIGN"], size=int(swap.sum()))
    times = gts.column("timestamp_ns").to_numpy()[keep]
    # false positives: random boxes near the ego at random annotated times, incl. beyond 150 m
    n_fp = 800
    fp_times = rng.choice(np.unique(times), size=n_fp)
    fp_xyz = rng.uniform(-60, 60, (n_fp, 3)) * np.array([1, 1, 0.05])
    fp_xyz[:40, 0] = rng.uniform(150, 170, 40)
    fp = {"tx_m": fp_xyz[:, 0], "ty_m": fp_xyz[:, 1], "tz_m": fp_xyz[:, 2],
          "length_m": rng.uniform(0.5, 5, n_fp), "width_m": rng.uniform(0.5, 2.5, n_fp),
          "height_m": rng.uniform(0.5, 3, n_fp), "qw": np.ones(n_fp), "qx": np.zeros(n_fp), "qy": np.zeros(n_fp),
          "qz": np.zeros(n_fp)}
    fp_categories = rng.choice(["REGULAR_VEHICLE", "PEDESTRIAN", "BOLLARD", "CONSTRUCTION_CONE"], size=n_fp)
    # 130 more vehicles in one sweep: av2 keeps the 100 best-scored per sweep and category
    crowd_time = int(np.unique(times)[10])
    crowd = 130
    crowd_xyz = rng.uniform(-40, 40, (crowd, 3)) * np.array([1, 1, 0])
    for key, values in (("tx_m", crowd_xyz[:, 0]), ("ty_m", crowd_xyz[:, 1]), ("tz_m", crowd_xyz[:, 2])):
        fp[key] = np.r_[fp[key], values]
    for key, values in (("length_m", np.full(crowd, 4.5)), ("width_m", np.full(crowd, 1.9)),
                        ("height_m", np.full(crowd, 1.6)), ("qw", np.ones(crowd)), ("qx", np.zeros(crowd)),
                        ("qy", np.zeros(crowd)), ("qz", np.zeros(crowd))):
        fp[key] = np.r_[fp[key], values]
    fp_times = np.r_[fp_times, np.full(crowd, crowd_time)]
    fp_categories = np.r_[fp_categories, np.full(crowd, "REGULAR_VEHICLE")]
    total = m + n_fp + crowd
    scores = rng.permutation(total).astype(np.float64) / total + 1e-3
    data = {
        "log_id": pa.array([LOG] * total),
        "timestamp_ns": pa.array(np.r_[times, fp_times].astype(np.int64)),
        "category": pa.array(np.r_[categories, fp_categories].tolist()),
        **{c: pa.array(np.r_[columns[c], fp[c]]) for c in CUBOID_COLUMNS},
        "score": pa.array(scores),
    }
    order = rng.permutation(total)
    return pa.table(data).take(pa.array(order))


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("av2_eval")
    gts, dts = folder / "gts.feather", folder / "dts.feather"
    feather.write_feather(ground_truth_table(), gts)
    feather.write_feather(perturbed_detections(7), dts)
    return {"folder": folder, "gts": gts, "dts": dts}


@pytest.mark.parametrize("roi", [True, False])
def test_metrics_equal_av2_evaluate(files, roi):
    start = time.perf_counter()
    oracle = run_oracle("av2", "av2_detection_eval.py", str(SPLIT), str(files["gts"]), str(files["dts"]),
                        str(int(roi)), timeout_s=1200)
    oracle_s = time.perf_counter() - start
    start = time.perf_counter()
    result = evaluate_av2_detection(
        read_detections(files["dts"]), read_ground_truth(SPLIT, [LOG]),
        Av2DetectionConfig(eval_only_roi_instances=roi), split_dir=SPLIT,
    )
    print(f"roi={roi}: avdata {time.perf_counter() - start:.1f} s, av2 evaluate {oracle_s:.1f} s (its own process)")
    # the per-row columns av2 adds (TP at each threshold, ATE, ASE, AOE, is_evaluated), row for row
    np.testing.assert_allclose(result.dts_outcome, np.array(oracle["dts_outcome"]), atol=1e-9, rtol=0)
    np.testing.assert_allclose(result.gts_outcome, np.array(oracle["gts_outcome"]), atol=1e-9, rtol=0)
    worst = 0.0
    assert sorted(result.metrics) == sorted(oracle["full"])
    for category, row in oracle["full"].items():
        for metric in METRICS:
            worst = max(worst, abs(result.metrics[category][metric] - row[metric]))
    print(f"roi={roi}: max |avdata - av2| over {len(oracle['full'])} rows x 5 metrics: {worst:.2e}")
    assert worst < 1e-6
    assert result.rounded() == oracle["rounded"]
    # the test exercises what it claims: real matches, filters and the 100-per-sweep cap
    assert 0.2 < result.metrics["REGULAR_VEHICLE"]["AP"] < 0.95
    assert result.metrics[AVERAGE]["CDS"] > 0
    evaluated = result.dts_outcome[:, -1].astype(bool)
    assert (~evaluated).sum() > 40
    if roi:
        assert (result.gts_outcome[:, -1] == 0).sum() > (np.array(
            feather.read_table(files["gts"]).column("num_interior_pts").to_numpy()) == 0).sum()


def test_cli_protocol_av2_prints_and_writes_the_table(files, tmp_path, capsys):
    parser = argparse.ArgumentParser(prog="avdata")
    add_eval_subparser(parser.add_subparsers())
    out = tmp_path / "av2.json"
    args = parser.parse_args(["eval", "detection", str(SPLIT), str(files["dts"]), "--protocol", "av2",
                              "--json", str(out), "--no-roi"])
    assert args.run(args) == 0
    table = json.loads(out.read_text())
    expected = evaluate_av2_detection(read_detections(files["dts"]), read_ground_truth(SPLIT),
                                      Av2DetectionConfig(eval_only_roi_instances=False), split_dir=SPLIT)
    assert table == expected.metrics
    printed = capsys.readouterr().out
    assert "REGULAR_VEHICLE" in printed and "CDS" in printed and AVERAGE in printed


def test_bad_detection_files_are_one_line_errors(files, tmp_path):
    from avdata.errors import InputError

    truncated = tmp_path / "truncated.feather"
    truncated.write_bytes(files["dts"].read_bytes()[:5000])
    with pytest.raises(InputError, match="truncated.feather: unreadable"):
        read_detections(truncated)
    table = feather.read_table(files["dts"]).drop_columns(["score"])
    feather.write_feather(table, tmp_path / "no_score.feather")
    with pytest.raises(InputError, match=r"missing \['score'\]"):
        read_detections(tmp_path / "no_score.feather")
    other = feather.read_table(files["dts"])
    other = other.set_column(other.column_names.index("log_id"), "log_id", pa.array(["nope"] * other.num_rows))
    feather.write_feather(other, tmp_path / "other_log.feather")
    with pytest.raises(InputError, match="without ground truth"):
        evaluate_av2_detection(read_detections(tmp_path / "other_log.feather"), read_ground_truth(SPLIT), split_dir=SPLIT)
