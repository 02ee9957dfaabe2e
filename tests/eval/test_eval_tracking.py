"""Tracking metrics on hand-worked sequences (the oracle tests cover the general case)."""

import numpy as np
import pytest

from avdata.errors import InputError
from avdata.eval.tracking import (
    Similarity,
    TrackingConfig,
    TrackingSequence,
    clear,
    hota,
    identity,
    track_rates,
)


def _seq(gt, tr, n_frames):
    """gt / tr: lists of (frame, id, x) for unit squares at (x, 0); IoU of squares offset by d is (1-d)/(1+d)."""
    g = np.array(gt, dtype=float).reshape(-1, 3)
    t = np.array(tr, dtype=float).reshape(-1, 3)
    box = lambda x: np.c_[x, np.zeros_like(x), x + 1, np.ones_like(x)]  # noqa: E731
    return TrackingSequence.from_boxes(
        num_frames=n_frames, gt_frame=g[:, 0].astype(int), gt_id=g[:, 1].astype(int), gt_boxes=box(g[:, 2]),
        tracker_frame=t[:, 0].astype(int), tracker_id=t[:, 1].astype(int), tracker_boxes=box(t[:, 2]),
        similarity=Similarity.IOU_2D,
    )


def test_identity_switch_and_fragmentation():
    # One object over 6 frames; the tracker follows it exactly with id 7 (frames 0-1), has no box on it in
    # frame 2, then follows it with id 8 (frames 3-5).
    gt = [(f, 1, 0.0) for f in range(6)]
    tr = [(0, 7, 0.0), (1, 7, 0.0)] + [(f, 8, 0.0) for f in (3, 4, 5)]
    c = clear(_seq(gt, tr, 6))
    # TrackEval skips frames without tracker boxes when it tracks fragmentation: no fragment here.
    assert (c["CLR_TP"], c["CLR_FN"], c["CLR_FP"], c["IDSW"], c["Frag"]) == (5, 1, 0, 1, 0)
    # A tracker box elsewhere in frame 2 makes it a frame with both kinds of boxes: the track fragments.
    seq = _seq(gt, tr + [(2, 9, 5.0)], 6)
    c = clear(seq)
    assert (c["CLR_TP"], c["CLR_FN"], c["CLR_FP"], c["IDSW"], c["Frag"]) == (5, 1, 1, 1, 1)
    assert c["MOTA"] == pytest.approx((5 - 1 - 1) / 6) and c["MOTP"] == pytest.approx(1.0)
    assert c["MT"] == 1  # tracked 5 / 6 > 0.8
    i = identity(seq)
    # Best id pairing: gt 1 <-> tracker 8 (3 frames): IDTP 3, IDFN 3, IDFP 2 + 1.
    assert (i["IDTP"], i["IDFN"], i["IDFP"]) == (3, 3, 3)
    assert i["IDF1"] == pytest.approx(0.5)
    h = hota(seq)
    # Every alpha: DetA = 5 / 7; AssA = (2 * 2/6 + 3 * 3/6) / 5 = 13 / 30.
    np.testing.assert_allclose(h["DetA"], 5 / 7)
    np.testing.assert_allclose(h["AssA"], 13 / 30)
    np.testing.assert_allclose(h["HOTA"], np.sqrt(5 / 7 * 13 / 30))


def test_localisation_threshold_per_alpha():
    # Offset 0.5: IoU = 0.5 / 1.5 = 1/3 -> a match for alpha <= 1/3 only (HOTA), never for CLEAR (0.5).
    seq = _seq([(0, 1, 0.0)], [(0, 2, 0.5)], 1)
    h = hota(seq)
    assert h["HOTA_TP"].tolist() == [1.0] * 6 + [0.0] * 13  # alphas 0.05 .. 0.30
    assert clear(seq)["CLR_TP"] == 0


def test_alpha_levels_at_the_thresholds():
    # One gt and one tracker box per frame, with similarities on, just below and just above thresholds
    # alpha - eps: a match counts for alpha exactly when sim >= alpha - eps (TrackEval's test).
    eps = np.finfo(np.float64).eps
    alphas = np.arange(0.05, 0.99, 0.05)
    sims = np.r_[alphas - eps, np.nextafter(alphas - eps, 0.0), alphas + eps, 0.5, 0.95, 1.0, 1e-300, 0.999]
    n = len(sims)
    seq = TrackingSequence.from_frames(
        gt_ids=[np.array([1])] * n, tracker_ids=[np.array([2])] * n, similarity=[np.array([[v]]) for v in sims]
    )
    expected = np.array([np.sum(sims >= alpha - eps) for alpha in alphas], dtype=float)
    np.testing.assert_array_equal(hota(seq)["HOTA_TP"], expected)
    assert expected[0] == n - 2  # all but 1e-300 and the value just below the first threshold


def test_false_and_missed_track_rates():
    # gt A tracked in 4 of 4 frames; gt B in 1 of 4; tracker C covers A; D covers B once and is elsewhere
    # 3 times; E never matches anything.
    gt = [(f, 1, 0.0) for f in range(4)] + [(f, 2, 10.0) for f in range(4)]
    tr = [(f, 3, 0.0) for f in range(4)] + [(0, 4, 10.0)] + [(f, 4, 30.0) for f in (1, 2, 3)] + [(2, 5, 50.0)]
    r = track_rates(_seq(gt, tr, 4))
    assert (r["FalseTracks"], r["MissedTracks"]) == (2, 1)  # D matched 1/4 < 0.5, E 0/1; B 1/4 < 0.5
    assert r["FTR"] == pytest.approx(2 / 3) and r["MTR_tracks"] == pytest.approx(1 / 2)
    strict = track_rates(_seq(gt, tr, 4), TrackingConfig(track_rate_threshold=0.2))
    assert (strict["FalseTracks"], strict["MissedTracks"]) == (1, 0)


def test_repeated_id_in_a_frame_is_input_error():
    with pytest.raises(InputError, match="unique within each frame"):
        _seq([(0, 1, 0.0), (0, 1, 3.0)], [], 1)


def test_one_id_per_detection_is_required():
    # Boxes are taken as they come when already in frame order: a longer id array must not slip through.
    box = np.array([[0.0, 0.0, 1.0, 1.0]])
    with pytest.raises(InputError, match="gt ids: expected one per detection"):
        TrackingSequence.from_boxes(
            num_frames=1, gt_frame=[0], gt_id=[1, 2], gt_boxes=box, tracker_frame=[0], tracker_id=[1],
            tracker_boxes=box, similarity=Similarity.IOU_2D,
        )


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_boxes_are_input_errors(bad):
    # A NaN x used to sort its tracker box out of its frame in the candidate search, pairing boxes of
    # different frames (gt 0 of frame 0 with tracker 1 of frame 1 here).
    gt_box = np.array([[0.0, 0.0, 10.0, 10.0], [0.0, 0.0, 10.0, 10.0]])
    tr_box = np.array([[bad, 0.0, 10.0, 10.0], [1.0, 1.0, 5.0, 5.0], [50.0, 50.0, 60.0, 60.0]])
    with pytest.raises(InputError, match="tracker boxes: expected finite values, got 1 boxes"):
        TrackingSequence.from_boxes(
            num_frames=2, gt_frame=[0, 1], gt_id=[1, 1], gt_boxes=gt_box, tracker_frame=[0, 1, 1],
            tracker_id=[1, 1, 2], tracker_boxes=tr_box, similarity=Similarity.IOU_2D,
        )


def test_finite_boxes_whose_sum_overflows_are_accepted():
    # The finiteness check sums the boxes first; a sum beyond float range must not refuse finite boxes.
    box = np.array([[1e307, 0.0, 1.5e307, 1e-300]] * 40)
    seq = TrackingSequence.from_boxes(
        num_frames=40, gt_frame=np.arange(40), gt_id=np.zeros(40, dtype=int), gt_boxes=box,
        tracker_frame=np.arange(40), tracker_id=np.zeros(40, dtype=int), tracker_boxes=box,
        similarity=Similarity.IOU_2D,
    )
    with np.errstate(over="ignore"):
        assert not np.isfinite(box.sum())
    np.testing.assert_array_equal(seq.pair_similarity, np.ones(40))


def test_typed_results_are_keyed_by_field_enums_and_strings():
    from avdata.eval.tracking import COMBINED, ClearField, FamilyResult, HotaField, TrackingMetric, evaluate_tracking

    seq = _seq([(f, 1, 0.0) for f in range(4)], [(f, 5, 0.0) for f in range(4)], 4)
    res = evaluate_tracking({"a": seq}, [TrackingMetric.HOTA, TrackingMetric.CLEAR])
    hota_res, clear_res = res[COMBINED][TrackingMetric.HOTA], res["a"][TrackingMetric.CLEAR]
    assert isinstance(hota_res, FamilyResult) and hota_res.family is TrackingMetric.HOTA
    assert set(hota_res) == {f.value for f in HotaField} and set(clear_res) == {f.value for f in ClearField}
    assert clear_res[ClearField.CLR_TP] == clear_res["CLR_TP"] == 4
    np.testing.assert_allclose(hota_res[HotaField.HOTA], 1.0)
    with pytest.raises(ValueError, match="CLEAR result: expected fields"):
        FamilyResult(family=TrackingMetric.CLEAR, fields={"MOTA": 1.0})
