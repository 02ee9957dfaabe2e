"""nuScenes detection metrics equal nuscenes-devkit 1.2.0 DetectionEval (1e-6) on randomised tables."""

import json

import numpy as np
import pytest
from eval_nuscenes_synth import write_nuscenes
from eval_oracle_env import run_oracle

from avdata.errors import InputError
from avdata.eval.detection.nuscenes import (
    NuScenesDetectionConfig,
    evaluate_nuscenes_detection,
    load_nuscenes_gt,
    load_nuscenes_submission,
)
from avdata.eval.nuscenes_gt import load_nuscenes_bike_racks, outside_bike_racks
from avdata.eval.problems import EvalWarning


@pytest.mark.oracle
@pytest.mark.parametrize("seed", [3, 4])
def test_equals_devkit(tmp_path, seed):
    results = write_nuscenes(tmp_path, seed)
    oracle = run_oracle("nuscenes", "eval_nuscenes_detection.py", str(tmp_path), str(results), str(tmp_path / "out"))
    gt, ego, samples = load_nuscenes_gt(tmp_path / "v1.0-mini")
    racks = load_nuscenes_bike_racks(tmp_path / "v1.0-mini")
    pred = load_nuscenes_submission(results, ego, samples)
    # The synthetic racks hold cycles of both kinds, so the devkit's bike-rack filter is exercised.
    assert len(racks.sample) > 3
    assert not np.all(outside_bike_racks(gt.name, gt.sample, gt.translation_m, racks))
    assert not np.all(outside_bike_racks(pred.name, pred.sample, pred.translation_m, racks))
    ours = evaluate_nuscenes_detection(gt, pred, bike_racks=racks)
    for cls, per_th in oracle["label_aps"].items():
        for th, ref in per_th.items():
            assert ours.label_aps[cls][float(th)] == pytest.approx(ref, abs=1e-6), (cls, th)
    for cls, per_metric in oracle["label_tp_errors"].items():
        for metric, ref in per_metric.items():
            got = ours.label_tp_errors[cls][metric]
            if ref is None:
                assert np.isnan(got), (cls, metric)
            else:
                assert got == pytest.approx(ref, abs=1e-6), (cls, metric)
    for metric, ref in oracle["tp_errors"].items():
        assert ours.tp_errors[metric] == pytest.approx(ref, abs=1e-6)
    assert ours.mean_ap == pytest.approx(oracle["mean_ap"], abs=1e-6)
    assert ours.nd_score == pytest.approx(oracle["nd_score"], abs=1e-6)
    assert 0.05 < ours.mean_ap < 0.9  # the data exercises matching at every threshold


def _boxes(xy, score=None, name="car"):
    from avdata.eval.detection.nuscenes import DetectionBoxes

    n = len(xy)
    xyz = np.c_[np.asarray(xy, dtype=float), np.zeros(n)]
    return DetectionBoxes(
        sample=np.array(["s"] * n, dtype=object), translation_m=xyz, size_m=np.tile([4.0, 2.0, 1.5], (n, 1)),
        yaw_rad=np.zeros(n), velocity_mps=np.zeros((n, 2)), name=np.array([name] * n, dtype=object),
        score=np.full(n, -1.0) if score is None else np.asarray(score, dtype=float),
        attribute=np.array(["vehicle.moving"] * n, dtype=object),
        num_points=np.full(n, 5 if score is None else -1), ego_translation_m=xyz,
    )


def test_hand_worked_single_class():
    # Two cars; predictions: 0.3 m off (score 0.9), a false positive (0.8), 1.5 m off (0.7).
    gt = _boxes([[10.0, 0.0], [20.0, 0.0]])
    pred = _boxes([[10.3, 0.0], [30.0, 0.0], [21.5, 0.0]], score=[0.9, 0.8, 0.7])
    with pytest.warns(EvalWarning, match=r"no object of class\(es\) truck, bus"):
        res = evaluate_nuscenes_detection(gt, pred)
    # At 0.5 m: TP, FP, FP, all at recall 0.5, precisions 1, 1/2, 1/3. np.interp over the repeated recall
    # gives 1 below 0.5, the last precision (1/3) at exactly 0.5, 0 above: AP = mean over recall points
    # 11..100 of max(0, p - 0.1) / 0.9 = (39 * 0.9 + (1/3 - 0.1)) / 90 / 0.9, as the devkit computes it.
    assert res.label_aps["car"][0.5] == pytest.approx((39 * 0.9 + (1 / 3 - 0.1)) / 90 / 0.9)
    # At 2 m: recall 0.5 (p 1), then FP, then recall 1.0 at precision 2/3: points 51..100 interpolate
    # linearly between (0.5, 1) and (1.0, 2/3).
    rec = np.linspace(0, 1, 101)[11:]
    prec = np.interp(rec, [0.5, 0.5, 1.0], [1.0, 0.5, 2 / 3])
    assert res.label_aps["car"][2.0] == pytest.approx(np.mean(np.maximum(prec - 0.1, 0)) / 0.9)
    # ATE at 2 m: cumulative mean of the match errors (0.3, then (0.3 + 1.5) / 2 = 0.9), interpolated over
    # the confidences of recall points 11..100.
    assert 0.3 < res.label_tp_errors["car"]["trans_err"] < 0.9
    assert res.label_tp_errors["car"]["scale_err"] == pytest.approx(0.0)
    assert res.label_aps["truck"][2.0] == 0.0 and res.label_tp_errors["truck"]["trans_err"] == 1.0


def test_too_many_boxes_is_input_error(tmp_path):
    gt = _boxes([[1.0, 0.0]])
    pred = _boxes([[1.0, 0.0]] * 3, score=[0.5] * 3)
    with pytest.raises(InputError, match="at most 2 boxes per sample, got 3"):
        evaluate_nuscenes_detection(gt, pred, NuScenesDetectionConfig(max_boxes_per_sample=2))
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"meta": {}, "results": {"unknown": []}}))
    with pytest.raises(InputError, match="expected a sample of the ground truth"):
        load_nuscenes_submission(bad, {"s": np.zeros(3)})
