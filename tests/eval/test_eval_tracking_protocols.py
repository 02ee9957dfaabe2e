"""KITTI tracking and MOTChallenge protocols equal TrackEval's Kitti2DBox / MotChallenge2DBox end to end."""


import numpy as np
import pytest
from eval_oracle_env import run_oracle
from eval_synth import random_sequence

from avdata.eval.tracking import TrackingMetric, evaluate_tracking
from avdata.eval.tracking.kitti import kitti_tracking_sequences
from avdata.eval.tracking.mot import mot_sequences
from tests.realdata import REALDATA

METRICS = [TrackingMetric.HOTA, TrackingMetric.CLEAR, TrackingMetric.IDENTITY]


def _compare(ours_combined, oracle_combined):
    n = 0
    for metric, fields in oracle_combined.items():
        for field, ref in fields.items():
            got = np.asarray(ours_combined[TrackingMetric(metric)][field], dtype=float)
            np.testing.assert_allclose(got, np.asarray(ref, dtype=float), rtol=0, atol=1e-9, err_msg=f"{metric} {field}")
            n += 1
    return n


def _write_kitti(tmp_path, seed):
    rng = np.random.default_rng(seed)
    gt_dir, tr_dir = tmp_path / "gt", tmp_path / "trackers" / "mine" / "data"
    (gt_dir / "label_02").mkdir(parents=True)
    tr_dir.mkdir(parents=True)
    seqmap = []
    for s in range(3):
        n = int(rng.integers(20, 40))
        seq = random_sequence(rng, n, 12, 400.0)
        names = np.array(["Car", "Van", "Pedestrian", "Person", "Cyclist"])
        gt_cls = names[rng.integers(0, 5, seq["gt_id"].max() + 1)][seq["gt_id"]]
        lines = []
        for f, i, b, c in zip(seq["gt_frame"], seq["gt_id"], seq["gt_box"], gt_cls, strict=True):
            trunc, occ = int(rng.random() < 0.15), int(rng.integers(0, 4))
            lines.append(f"{f} {i} {c} {trunc} {occ} 0 {b[0]:.3f} {b[1]:.3f} {b[2]:.3f} {b[3]:.3f} 1 1 1 0 0 0 0")
        for f in range(0, n, 5):  # DontCare regions
            x, y = rng.uniform(0, 350, 2)
            lines.append(f"{f} -1 DontCare -1 -1 -10 {x:.3f} {y:.3f} {x + 60:.3f} {y + 60:.3f} -1 -1 -1 -1000 -1000 -1000 -10")
        (gt_dir / "label_02" / f"{s:04d}.txt").write_text("\n".join(lines) + "\n")
        tr_cls = np.array(["Car", "Pedestrian"])[rng.integers(0, 2, seq["tr_id"].max() + 1)][seq["tr_id"]]
        tr_lines = [f"{f} {i} {c} 0 0 0 {b[0]:.3f} {b[1]:.3f} {b[2]:.3f} {b[3]:.3f} 1 1 1 0 0 0 0 {rng.random():.3f}"
                    for f, i, b, c in zip(seq["tr_frame"], seq["tr_id"], seq["tr_box"], tr_cls, strict=True)]
        (tr_dir / f"{s:04d}.txt").write_text("\n".join(tr_lines) + "\n")
        seqmap.append(f"{s:04d} empty 000000 {n:06d}")
    (gt_dir / "evaluate_tracking.seqmap.training").write_text("\n".join(seqmap) + "\n")
    return gt_dir, tr_dir


@pytest.mark.oracle
def test_kitti_tracking_equals_trackeval(tmp_path):
    gt_dir, tr_dir = _write_kitti(tmp_path, 21)
    oracle = run_oracle("trackeval", "eval_trackeval_datasets.py", "kitti", str(gt_dir),
                        str(tmp_path / "trackers"), "mine", "training")
    seqs = kitti_tracking_sequences(gt_dir, tr_dir)
    n = 0
    for cls in ("car", "pedestrian"):
        n += _compare(evaluate_tracking(seqs[cls], METRICS)["COMBINED_SEQ"], oracle[cls])
    assert n > 80
    assert 0.1 < float(np.mean(oracle["car"]["HOTA"]["HOTA"])) < 0.9


@pytest.mark.oracle
def test_mot_challenge_equals_trackeval(tmp_path):
    rng = np.random.default_rng(5)
    gt_dir, tr_dir = tmp_path / "gt", tmp_path / "trackers" / "mine" / "data"
    tr_dir.mkdir(parents=True)
    names = []
    for s in range(3):
        name = f"MOT17-{s:02d}"
        names.append(name)
        n = int(rng.integers(20, 40))
        seq = random_sequence(rng, n, 12, 400.0)
        (gt_dir / name / "gt").mkdir(parents=True)
        (gt_dir / name / "seqinfo.ini").write_text(f"[Sequence]\nname={name}\nseqLength={n}\n")
        cls = np.array([1, 1, 1, 2, 7, 8, 12, 3])[rng.integers(0, 8, seq["gt_id"].max() + 1)][seq["gt_id"]]
        consider = (rng.random(len(cls)) > 0.1).astype(int)
        rows = [f"{f + 1},{i},{b[0]:.3f},{b[1]:.3f},{b[2] - b[0]:.3f},{b[3] - b[1]:.3f},{z},{c},1"
                for f, i, b, c, z in zip(seq["gt_frame"], seq["gt_id"], seq["gt_box"], cls, consider, strict=True)]
        (gt_dir / name / "gt" / "gt.txt").write_text("\n".join(rows) + "\n")
        tr_rows = [f"{f + 1},{i},{b[0]:.3f},{b[1]:.3f},{b[2] - b[0]:.3f},{b[3] - b[1]:.3f},1,-1,-1,-1"
                   for f, i, b in zip(seq["tr_frame"], seq["tr_id"], seq["tr_box"], strict=True)]
        (tr_dir / f"{name}.txt").write_text("\n".join(tr_rows) + "\n")
    seqmap = tmp_path / "seqmap.txt"
    seqmap.write_text("name\n" + "\n".join(names) + "\n")
    oracle = run_oracle("trackeval", "eval_trackeval_datasets.py", "mot", str(gt_dir), str(tmp_path / "trackers"),
                        "mine", str(seqmap))
    ours = evaluate_tracking(mot_sequences(gt_dir, tr_dir), METRICS)["COMBINED_SEQ"]
    assert _compare(ours, oracle["pedestrian"]) > 40


REAL_KITTI_TRACKING = REALDATA / "kitti" / "tracking"


@pytest.mark.oracle
def test_real_kitti_tracking_sequence_equals_trackeval(tmp_path):
    # The real KITTI tracking labels of sequence 0001 (shared conformance data) as ground truth, and a
    # perturbed copy as the tracker: rows dropped, boxes jittered, some identities swapped half-way.
    label = REAL_KITTI_TRACKING / "training" / "label_02" / "0001.txt"
    rows = [line.split() for line in label.read_text().splitlines() if line.strip()]
    n_frames = max(int(r[0]) for r in rows) + 1
    gt_dir, tr_dir = tmp_path / "gt", tmp_path / "trackers" / "mine" / "data"
    (gt_dir / "label_02").mkdir(parents=True)
    tr_dir.mkdir(parents=True)
    (gt_dir / "label_02" / "0001.txt").write_text(label.read_text())
    (gt_dir / "evaluate_tracking.seqmap.training").write_text(f"0001 empty 000000 {n_frames:06d}\n")
    rng = np.random.default_rng(0)
    out = []
    for r in rows:
        if r[2] == "DontCare" or rng.random() < 0.1:
            continue
        frame, tid = int(r[0]), int(r[1])
        if tid % 3 == 0 and frame > n_frames // 2:
            tid += 1000
        box = np.array([float(v) for v in r[6:10]]) + rng.normal(0, 4, 4)
        out.append(" ".join([r[0], str(tid), r[2], "0", "0", r[5], *(f"{v:.2f}" for v in box), *r[10:17], "0.9"]))
    (tr_dir / "0001.txt").write_text("\n".join(out) + "\n")
    oracle = run_oracle("trackeval", "eval_trackeval_datasets.py", "kitti", str(gt_dir), str(tmp_path / "trackers"),
                        "mine", "training")
    seqs = kitti_tracking_sequences(gt_dir, tr_dir)
    for cls in ("car", "pedestrian"):
        assert _compare(evaluate_tracking(seqs[cls], METRICS)["COMBINED_SEQ"], oracle[cls]) > 40
    assert 0.3 < float(np.mean(oracle["car"]["HOTA"]["HOTA"])) < 0.95
