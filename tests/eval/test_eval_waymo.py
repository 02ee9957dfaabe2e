"""Waymo detection metrics (AP, APH at LEVEL_1/LEVEL_2 per type) against Waymo's own op.

Ground truth: the real v1 frame's 75 laser labels as Waymo's compat_v1 writes them (lidar_box), with
their difficulty levels; predictions: perturbed copies (centre, size, heading noise, some headings
flipped, some boxes dropped or of the wrong type, false positives, a few in no-label zones), three
frames with different perturbations.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from eval_oracle_env import run_oracle

from avdata.cli import main
from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.waymo import WaymoConverter
from avdata.eval.detection.waymo import (
    WaymoBoxes,
    WaymoDetectionConfig,
    WaymoType,
    evaluate_waymo_detection,
    ground_truth_difficulty,
    mean_average_precision,
)
from avdata.schema import DatasetReader

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "oracles"))
from waymo_fixture import waymo_v2_fixture  # noqa: E402


def real_labels() -> dict[str, np.ndarray]:
    src, info = waymo_v2_fixture()
    table = pq.read_table(src / "lidar_box" / f"{info['context']}.parquet").to_pydict()
    col = {k.rpartition("].")[2]: np.asarray(v) for k, v in table.items()}
    box = np.stack([col[f"box.center.{a}"] for a in "xyz"] + [col[f"box.size.{a}"] for a in "xyz"] + [col["box.heading"]], axis=1)
    difficulty = np.asarray([0 if d is None else d for d in table["[LiDARBoxComponent].difficulty_level.detection"]])
    return {"box": box.astype(np.float32), "type": col["type"].astype(np.int64), "difficulty": difficulty.astype(np.int64),
            "points": col["num_lidar_points_in_box"].astype(np.int64)}


def perturbed(labels: dict[str, np.ndarray], n_frames: int, seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    gt_parts, pd_parts = [], []
    for frame in range(n_frames):
        n = len(labels["box"])
        gt_parts.append((np.full(n, frame), labels["box"], labels["type"], labels["difficulty"]))
        keep = rng.random(n) > 0.15
        box = labels["box"][keep].astype(np.float64).copy()
        k = len(box)
        box[:, :3] += rng.normal(0, 0.15, (k, 3)) * np.array([1, 1, 0.5])
        box[:, 3:6] *= rng.uniform(0.85, 1.15, (k, 3))
        box[:, 6] += rng.normal(0, 0.2, k) + np.pi * (rng.random(k) < 0.1)
        types = labels["type"][keep].copy()
        flip = rng.random(k) < 0.05
        types[flip] = rng.integers(1, 5, flip.sum())
        fp = rng.integers(3, 9)
        fp_box = np.column_stack([rng.uniform(-40, 40, (fp, 2)), rng.uniform(-1, 1, fp), rng.uniform(0.5, 5, (fp, 3)),
                                  rng.uniform(-np.pi, np.pi, fp)])
        pd_box = np.vstack([box, fp_box])
        pd_type = np.concatenate([types, rng.integers(1, 5, fp)])
        score = np.round(rng.uniform(0, 1, len(pd_box)), 3)
        nlz = rng.random(len(pd_box)) < 0.05
        pd_parts.append((np.full(len(pd_box), frame), pd_box, pd_type, score, nlz))
    gt_frame, gt_box, gt_type, gt_diff = (np.concatenate(p) for p in zip(*gt_parts, strict=True))
    pd_frame, pd_box, pd_type, pd_score, pd_nlz = (np.concatenate(p) for p in zip(*pd_parts, strict=True))
    return {"gt_frame": gt_frame.astype(np.int64), "gt_box": gt_box.astype(np.float32), "gt_type": gt_type.astype(np.uint8),
            "gt_difficulty": gt_diff.astype(np.uint8), "pd_frame": pd_frame.astype(np.int64),
            "pd_box": pd_box.astype(np.float32), "pd_type": pd_type.astype(np.uint8),
            "pd_score": pd_score.astype(np.float32), "pd_nlz": pd_nlz}


def ours(data: dict[str, np.ndarray]) -> dict:
    gt = WaymoBoxes(frame_id=data["gt_frame"], box=data["gt_box"], type=data["gt_type"], difficulty=data["gt_difficulty"])
    pred = WaymoBoxes(frame_id=data["pd_frame"], box=data["pd_box"], type=data["pd_type"], score=data["pd_score"],
                      overlap_nlz=data["pd_nlz"])
    return evaluate_waymo_detection(gt, pred, WaymoDetectionConfig())


SEEDS = (0, 1, 2)


@pytest.fixture(scope="module")
def cases(tmp_path_factory: pytest.TempPathFactory) -> dict[int, tuple[dict, list]]:
    """seed -> (boxes, Waymo's records), one oracle run for all seeds."""
    folder = tmp_path_factory.mktemp("waymo_eval")
    labels = real_labels()
    data = {seed: perturbed(labels, n_frames=3, seed=seed) for seed in SEEDS}
    for seed in SEEDS:
        np.savez(folder / f"boxes_{seed}.npz", **data[seed])
    reference = run_oracle("waymo", "waymo_detection.py", *(str(folder / f"boxes_{seed}.npz") for seed in SEEDS))
    return {seed: (data[seed], reference[k]) for k, seed in enumerate(SEEDS)}


@pytest.mark.oracle
@pytest.mark.parametrize("seed", SEEDS)
def test_equals_waymo_metrics_op(cases: dict, seed: int) -> None:
    data, reference = cases[seed]
    mine = ours(data)
    assert len(reference) == 8
    for ref in reference:
        m = mine[(WaymoType(ref["type"]), ref["level"])]
        np.testing.assert_array_equal(m.tp, ref["tp"])
        np.testing.assert_array_equal(m.fp, ref["fp"])
        np.testing.assert_array_equal(m.fn, ref["fn"])
        np.testing.assert_allclose(m.precision, ref["precision"], atol=1e-6)
        np.testing.assert_allclose(m.recall, ref["recall"], atol=1e-6)
        np.testing.assert_allclose(m.precision_ha, ref["precision_ha"], atol=1e-6)
        assert abs(m.ap - ref["ap"]) <= 1e-6, (ref["type"], ref["level"], m.ap, ref["ap"])
        assert abs(m.aph - ref["aph"]) <= 1e-6, (ref["type"], ref["level"], m.aph, ref["aph"])
    # Not a test that cannot fail: the levels and types differ, and APH < AP where headings were flipped.
    vehicle_l1, vehicle_l2 = mine[(WaymoType.VEHICLE, 1)], mine[(WaymoType.VEHICLE, 2)]
    assert 0.1 < vehicle_l2.ap < 1.0 and vehicle_l2.aph < vehicle_l2.ap
    assert vehicle_l1.fn[0] <= vehicle_l2.fn[0]


def test_perfect_and_empty() -> None:
    labels = real_labels()
    n = len(labels["box"])
    gt = WaymoBoxes(frame_id=np.zeros(n), box=labels["box"], type=labels["type"], difficulty=labels["difficulty"])
    perfect = WaymoBoxes(frame_id=np.zeros(n), box=labels["box"], type=labels["type"], score=np.ones(n))
    result = evaluate_waymo_detection(gt, perfect)
    assert result[(WaymoType.VEHICLE, 2)].ap == pytest.approx(1.0, abs=1e-6)
    assert result[(WaymoType.VEHICLE, 2)].aph == pytest.approx(1.0, abs=1e-6)
    none = WaymoBoxes(frame_id=np.zeros(0), box=np.zeros((0, 7)), type=np.zeros(0), score=np.zeros(0))
    assert evaluate_waymo_detection(gt, none)[(WaymoType.PEDESTRIAN, 1)].ap == 0.0


def test_mean_average_precision_interpolates_every_recall_step() -> None:
    # One PR point (recall 0.5, precision 0.8): the envelope is 0.8 from recall 0 to 0.5, in 0.05 steps.
    assert mean_average_precision(np.array([0.8], np.float32), np.array([0.5], np.float32), 0.05) == pytest.approx(0.4, abs=1e-6)


def test_cli_on_converted_dataset(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``avdata eval detection --protocol waymo`` on the converted real frame = the library on the same boxes."""
    src, info = waymo_v2_fixture()
    run_conversion(WaymoConverter(ConvertConfig(src=src, dst=tmp_path / "waymo", quiet=True)))
    objects = DatasetReader(tmp_path / "waymo").objects()
    columns = ["x_ego_m", "y_ego_m", "z_ego_m", "length_m", "width_m", "height_m", "yaw_ego_rad"]
    box = np.stack([objects.column(c).to_numpy() for c in columns], axis=1)
    rng = np.random.default_rng(5)
    box[:, :2] += rng.normal(0, 0.2, (len(box), 2))
    box[:, 6] += rng.normal(0, 0.3, len(box))
    predictions = {c: box[:, k] for k, c in enumerate(columns)}
    predictions |= {"scene": objects.column("scene").to_pylist(), "frame_index": objects.column("frame_index").to_pylist(),
                    "source_class": objects.column("source_class").to_pylist(), "score": rng.uniform(0, 1, len(box))}
    pq.write_table(pa.table(predictions), tmp_path / "pred.parquet")
    status = main(["eval", "detection", "--protocol", "waymo", str(tmp_path / "waymo"), str(tmp_path / "pred.parquet"),
                   "--json", str(tmp_path / "metrics.json")])
    assert status == 0, capsys.readouterr().err
    table = json.loads((tmp_path / "metrics.json").read_text())
    labels = real_labels()
    order = np.argsort(np.asarray(objects.column("object_id").to_pylist()))
    src_ids = pq.read_table(src / "lidar_box" / f"{info['context']}.parquet").column("key.laser_object_id").to_pylist()
    src_order = np.argsort(np.asarray(src_ids))
    kept, difficulty = ground_truth_difficulty(labels["difficulty"][src_order], labels["points"][src_order])
    assert 0 < kept.sum() < len(kept) and set(difficulty[kept].tolist()) == {1, 2}
    gt = WaymoBoxes(frame_id=np.zeros(kept.sum()), box=labels["box"][src_order][kept], type=labels["type"][src_order][kept],
                    difficulty=difficulty[kept])
    pred = WaymoBoxes(frame_id=np.zeros(len(box)), box=box[order], type=labels["type"][src_order],
                      score=np.asarray(predictions["score"])[order])
    expected = evaluate_waymo_detection(gt, pred)
    assert table["VEHICLE"]["AP/L2"] == pytest.approx(expected[(WaymoType.VEHICLE, 2)].ap, abs=1e-6)
    assert table["PEDESTRIAN"]["APH/L1"] == pytest.approx(expected[(WaymoType.PEDESTRIAN, 1)].aph, abs=1e-6)
    # Both class columns: the same scores when they agree; a class naming another Waymo type is refused (it was
    # ignored, source_class winning without a word).
    classes = objects.column("class").to_pylist()
    pq.write_table(pa.table(predictions | {"class": classes}), tmp_path / "both.parquet")
    assert main(["eval", "detection", "--protocol", "waymo", str(tmp_path / "waymo"), str(tmp_path / "both.parquet"),
                 "--json", str(tmp_path / "both.json")]) == 0
    assert json.loads((tmp_path / "both.json").read_text()) == table
    row = classes.index("pedestrian")
    pq.write_table(pa.table(predictions | {"class": classes[:row] + ["car"] + classes[row + 1:]}), tmp_path / "bad.parquet")
    capsys.readouterr()
    assert main(["eval", "detection", "--protocol", "waymo", str(tmp_path / "waymo"), str(tmp_path / "bad.parquet")]) == 1
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith(
        f"bad.parquet: row {row}: class 'car' is Waymo's TYPE_VEHICLE, but source_class says 'TYPE_PEDESTRIAN'")
    assert 0.0 < table["VEHICLE"]["APH/L2"] < table["VEHICLE"]["AP/L2"] < 1.0


def test_ground_truth_preparation_follows_waymos_tool() -> None:
    # compute_detection_metrics_main.cc: no points -> dropped; unlabelled -> LEVEL_2 at <= 5 points; labelled kept.
    kept, level = ground_truth_difficulty(np.array([0, 0, 0, 2, 1, 0]), np.array([0, 5, 6, 100, 3, 1]))
    assert kept.tolist() == [False, True, True, True, True, True]
    assert level.tolist()[1:] == [2, 1, 2, 1, 2]
