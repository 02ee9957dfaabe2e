"""Prediction metrics on hand-worked cases that separate the two minADE definitions."""

import numpy as np
import pytest

from avdata.errors import InputError
from avdata.eval.prediction import PredictionConfig, evaluate_prediction


def test_two_min_ade_definitions_differ():
    # Ground truth along x: (1, 0), (2, 0), (3, 0), (4, 0).
    gt = np.array([[[1.0, 0], [2, 0], [3, 0], [4, 0]]])
    # Mode A: offset by 1 m in y at every step: ADE 1, FDE 1.
    mode_a = gt[0] + [0, 1.0]
    # Mode B: exact for three steps, 3 m off at the end: ADE 0.75, FDE 3.
    mode_b = gt[0].copy()
    mode_b[3] += [0, 3.0]
    pred = np.stack([mode_b, mode_a])[None]
    res = evaluate_prediction(gt, pred, probability=np.array([[0.6, 0.4]]), config=PredictionConfig(ks=(1, 2)))
    assert res["ADE"] == pytest.approx(0.75) and res["FDE"] == pytest.approx(3.0)
    assert res["minADE_nuscenes_2"] == pytest.approx(0.75)  # min ADE over modes: mode B
    assert res["minADE_argoverse_2"] == pytest.approx(1.0)  # ADE of the min-FDE mode: mode A
    assert res["minFDE_2"] == pytest.approx(1.0)
    # nuScenes miss: every mode's max distance > 2 m? Mode A's max is 1 m: no miss. Argoverse: minFDE 1: no miss.
    assert res["MR_nuscenes_2"] == 0.0 and res["MR_argoverse_2"] == 0.0
    assert res["MR_nuscenes_1"] == 1.0 and res["MR_argoverse_1"] == 1.0  # top-1 is mode B, 3 m off
    # Probabilities only rank: swapping them makes mode A the top-1.
    swapped = evaluate_prediction(gt, pred, probability=np.array([[0.1, 0.9]]), config=PredictionConfig(ks=(1,)))
    assert swapped["ADE"] == pytest.approx(1.0) and swapped["MR_argoverse_1"] == 0.0


def test_valid_mask_and_averaging():
    gt = np.zeros((2, 3, 2))
    pred = np.zeros((2, 1, 3, 2))
    pred[0, 0, :, 0] = [1.0, 2.0, 9.0]  # last step invalid for agent 0
    pred[1, 0, :, 0] = [3.0, 3.0, 3.0]
    valid = np.array([[True, True, False], [True, True, True]])
    res = evaluate_prediction(gt, pred, valid=valid, config=PredictionConfig(ks=(1,)))
    assert res["ADE"] == pytest.approx((1.5 + 3.0) / 2)
    assert res["FDE"] == pytest.approx((2.0 + 3.0) / 2)
    assert res["MR_argoverse_1"] == pytest.approx(0.5)


def test_shape_errors():
    with pytest.raises(InputError, match="expected gt"):
        evaluate_prediction(np.zeros((2, 3, 2)), np.zeros((2, 3, 2)))
