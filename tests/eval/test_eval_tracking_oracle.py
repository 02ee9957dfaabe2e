"""Tracking metrics equal TrackEval 1.3.0 (to 1e-9) and py-motmetrics 1.4.0 on randomised sequences.

TrackEval's and motmetrics' CLEAR can disagree on identity switches (a ground truth continuing from a partner
matched before the previous timestep): ``clear`` follows TrackEval, ``clear_motmetrics`` follows motmetrics.
"""

import numpy as np
import pytest
from eval_oracle_env import run_oracle
from eval_synth import assert_equal_to_trackeval, random_sequence, save_npz, tracking_sequences

from avdata.eval.tracking import (
    Similarity,
    TrackingMetric,
    clear,
    clear_motmetrics,
    evaluate_tracking,
    summary,
)

FAMILIES = [TrackingMetric.HOTA, TrackingMetric.CLEAR, TrackingMetric.IDENTITY, TrackingMetric.VACE,
            TrackingMetric.IDEUCL]


def _sequences(seed: int) -> dict[str, dict]:
    rng = np.random.default_rng(seed)
    seqs = {f"seq{i}": random_sequence(rng, int(rng.integers(20, 60)), int(rng.integers(4, 14)), 10.0)
            for i in range(5)}
    # Edge cases TrackEval special-cases: a sequence whose tracker output is empty, and frames with no gt.
    empty = random_sequence(rng, 10, 3, 10.0)
    for k in ("tr_frame", "tr_id"):
        empty[k] = empty[k][:0]
    empty["tr_box"] = empty["tr_box"][:0]
    seqs["empty_tracker"] = empty
    return seqs


@pytest.mark.oracle
@pytest.mark.parametrize(("similarity", "name"), [(Similarity.IOU_2D, "iou"), (Similarity.EUCLIDEAN, "euclidean")])
@pytest.mark.parametrize("seed", [11, 12])
def test_equals_trackeval_and_motmetrics(tmp_path, similarity, name, seed):
    seqs = _sequences(seed)
    save_npz(tmp_path / "seqs.npz", seqs)
    oracle = run_oracle("trackeval", "eval_trackeval.py", str(tmp_path / "seqs.npz"), name, "--motmetrics")
    built = tracking_sequences(seqs, similarity)
    ours = evaluate_tracking(built, FAMILIES)
    assert assert_equal_to_trackeval(ours, oracle["results"]) >= 350
    combined = summary(ours["COMBINED_SEQ"])
    assert 0.2 < combined["HOTA"] < 0.95  # the random data exercises matching, not a degenerate case
    for seq_name, mm in oracle["motmetrics"].items():
        seq = built[seq_name]
        ours_mm = clear_motmetrics(seq)
        for key in ("num_matches", "num_switches", "num_false_positives", "num_misses"):
            assert ours_mm[key] == mm[key], (seq_name, key)
        flat = summary(ours[seq_name])
        if mm["num_detections"] > 0:
            assert ours_mm["mota"] == pytest.approx(mm["mota"], abs=1e-12)
            assert ours_mm["motp"] == pytest.approx(mm["motp"], abs=1e-9)
            # Identity metrics have no frame-order semantics: TrackEval's and motmetrics' agree.
            assert flat["IDF1"] == pytest.approx(mm["idf1"], abs=1e-12)
            assert flat["IDP"] == pytest.approx(mm["idp"], abs=1e-12)
            assert flat["IDR"] == pytest.approx(mm["idr"], abs=1e-12)
        # TrackEval's CLEAR differs from motmetrics only in which earlier match continues a track.
        assert flat["CLR_FP"] + flat["CLR_TP"] == mm["num_false_positives"] + mm["num_matches"] + mm["num_switches"]


@pytest.mark.oracle
def test_both_clear_definitions_where_they_disagree(tmp_path):
    # Seed 30: the third sequence is one where TrackEval and motmetrics count identity switches differently.
    rng = np.random.default_rng(30)
    seqs = {f"s{i}": random_sequence(rng, 40, 12, 10.0) for i in range(3)}
    save_npz(tmp_path / "seqs.npz", seqs)
    oracle = run_oracle("trackeval", "eval_trackeval.py", str(tmp_path / "seqs.npz"), "iou", "--metrics", "CLEAR",
                        "--motmetrics")
    built = tracking_sequences(seqs, Similarity.IOU_2D)
    te_idsw = oracle["results"]["s2"]["CLEAR"]["IDSW"]
    mm_idsw = oracle["motmetrics"]["s2"]["num_switches"]
    assert te_idsw != mm_idsw
    assert clear(built["s2"])["IDSW"] == te_idsw
    assert clear_motmetrics(built["s2"])["num_switches"] == mm_idsw
    assert clear_motmetrics(built["s2"])["mota"] == pytest.approx(oracle["motmetrics"]["s2"]["mota"], abs=1e-12)
