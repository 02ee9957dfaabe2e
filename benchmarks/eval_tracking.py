"""Benchmark: HOTA + CLEAR + Identity over 20 sequences x 500 frames x 50 objects, avdata vs TrackEval 1.3.0.

TrackEval runs in its oracle venv (``.oracle-envs/trackeval``, made by ``tests/oracles/make_envs.sh``) on the
same boxes, timed there over the same work: per-frame 2D IoU plus the three metric families, per sequence
and combined (loading the files is outside both timings). The script checks that every metric field agrees
to 1e-9 before printing the figures, at two densities (pedestrian-like boxes; larger, crowded boxes), as
wall-clock and as CPU time (the CPU figure is steadier on a shared machine). The sides take turns, 3 rounds
of one TrackEval run (in its own process, which stays up) and three avdata runs; each side's time is its best.
Targets (``benchmarks/targets.py``): CPU ratio >= 40x MOT17-like, >= 30x crowded. On the 2-core Xeon of
2026-11-29 TrackEval took ~0.32 s of CPU per sequence at both densities and avdata 14-18 ms (19-23x); figures
per machine and where avdata's time goes: docs/performance.md.

    python benchmarks/eval_tracking.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from avdata.eval.tracking import Similarity, TrackingMetric, TrackingSequence, evaluate_tracking

REPO = Path(__file__).resolve().parents[1]
FAMILIES = [TrackingMetric.HOTA, TrackingMetric.CLEAR, TrackingMetric.IDENTITY]
ROUNDS = 3


def make_sequence(
    rng: np.random.Generator, num_frames: int, num_objects: int, max_size_px: tuple[float, float]
) -> dict[str, np.ndarray]:
    """Objects walking in a 1920 x 1080 image; the tracker misses 10 %, jitters, switches ids, adds clutter.

    Box widths / heights are uniform in [max / 4, max]: (120, 240) px gives a crowded scene (most objects
    overlap several tracker boxes), (80, 200) px pedestrian-like MOT17 density.
    """
    low = (max_size_px[0] / 4, max_size_px[1] / 4)
    frames = np.repeat(np.arange(num_frames), num_objects)
    ids = np.tile(np.arange(num_objects), num_frames)
    start = rng.uniform([0, 0], [1800, 900], (num_objects, 2))
    walk = np.cumsum(rng.normal(0, 4, (num_frames, num_objects, 2)), axis=0).reshape(-1, 2)
    size = np.tile(rng.uniform(low, max_size_px, (num_objects, 2)), (num_frames, 1))
    top_left = np.tile(start, (num_frames, 1)) + walk
    gt_box = np.c_[top_left, top_left + size]
    keep = rng.random(len(frames)) > 0.1
    switch_frame = rng.integers(0, num_frames, num_objects)
    tr_id = ids + 1000 * (frames >= switch_frame[ids]) * (rng.random(num_objects) < 0.3)[ids]
    tr_box = gt_box + rng.normal(0, 6, gt_box.shape)
    n_fp = num_frames * num_objects // 20
    fp_frame = rng.integers(0, num_frames, n_fp)
    fp_tl = rng.uniform([0, 0], [1800, 900], (n_fp, 2))
    fp_box = np.c_[fp_tl, fp_tl + rng.uniform(low, max_size_px, (n_fp, 2))]
    return {
        "num_frames": np.array(num_frames),
        "gt_frame": frames, "gt_id": ids, "gt_box": gt_box,
        "tr_frame": np.r_[frames[keep], fp_frame],
        "tr_id": np.r_[tr_id[keep], 5000 + np.arange(n_fp)],
        "tr_box": np.r_[tr_box[keep], fp_box],
    }


def run_avdata(seqs: dict[str, dict[str, np.ndarray]]) -> tuple[float, float, dict]:
    start, start_cpu = time.perf_counter(), time.process_time()
    built = {
        name: TrackingSequence.from_boxes(
            num_frames=int(s["num_frames"]), gt_frame=s["gt_frame"], gt_id=s["gt_id"], gt_boxes=s["gt_box"],
            tracker_frame=s["tr_frame"], tracker_id=s["tr_id"], tracker_boxes=s["tr_box"],
            similarity=Similarity.IOU_2D,
        )
        for name, s in seqs.items()
    }
    result = evaluate_tracking(built, FAMILIES)
    return time.perf_counter() - start, time.process_time() - start_cpu, result


def compare(label: str, seqs: dict[str, dict[str, np.ndarray]], python: Path, size: str) -> bool:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "seqs.npz"
        np.savez(path, **{f"{n}/{k}": v for n, s in seqs.items() for k, v in s.items()})
        # TrackEval serves one timed evaluation per request, so the two sides take turns (TrackEval once, avdata
        # three times, per round): both are then measured in the same minutes of a shared machine, whose speed
        # drifts over minutes; timed one after the other, they caught different phases of it.
        oracle_process = subprocess.Popen(
            [str(python), str(REPO / "tests/oracles/eval_trackeval.py"), str(path), "iou",
             "--metrics", "HOTA", "CLEAR", "Identity", "--serve"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
        )
        assert oracle_process.stdin is not None and oracle_process.stdout is not None
        runs, oracle_runs = [], []
        for _ in range(ROUNDS):
            oracle_process.stdin.write("\n")
            oracle_process.stdin.flush()
            oracle_runs.append(json.loads(oracle_process.stdout.readline()))
            runs += [run_avdata(seqs) for _ in range(3)]
        oracle_out, _ = oracle_process.communicate()
        if oracle_process.returncode:
            raise RuntimeError(f"the TrackEval oracle failed (exit status {oracle_process.returncode})")
    oracle = json.loads(oracle_out)
    wall, cpu = min(r[0] for r in runs), min(r[1] for r in runs)
    oracle_wall, oracle_cpu = min(r["seconds"] for r in oracle_runs), min(r["cpu_seconds"] for r in oracle_runs)
    ours = runs[0][2]
    worst = 0.0
    for seq_name, per_metric in oracle["results"].items():
        for metric, fields in per_metric.items():
            for field, ref in fields.items():
                got = np.asarray(ours[seq_name][TrackingMetric(metric)][field], dtype=float)
                worst = max(worst, float(np.max(np.abs(got - np.asarray(ref, dtype=float)))))
    if worst > 1e-9:
        print(f"{label}: metrics differ from TrackEval: max abs difference {worst:.3g}", file=sys.stderr)
        return False
    print(f"tracking HOTA+CLEAR+Identity wall time, {label} ({size}): avdata {wall:.3f} s, "
          f"baseline trackeval {oracle_wall:.3f} s, ratio {oracle_wall / wall:.1f}x")
    print(f"tracking HOTA+CLEAR+Identity CPU time, {label} ({size}): avdata {cpu:.3f} s, "
          f"baseline trackeval {oracle_cpu:.3f} s, ratio {oracle_cpu / cpu:.1f}x")
    print(f"tracking metrics, {label}: max abs difference vs trackeval {worst:.2e}")
    return True


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="4 sequences x 100 frames x 20 objects")
    args = parser.parse_args()
    n_seq, n_frames, n_obj = (4, 100, 20) if args.quick else (20, 500, 50)
    python = REPO / ".oracle-envs" / "trackeval" / "bin" / "python"
    if not python.exists():
        print(f"TrackEval oracle env missing at {python}; run tests/oracles/make_envs.sh", file=sys.stderr)
        return 1
    size = f"{n_seq} seq x {n_frames} frames x {n_obj} objects"
    ok = True
    for label, max_size in (("MOT17-like density", (80.0, 200.0)), ("crowded", (120.0, 240.0))):
        rng = np.random.default_rng(2024)
        seqs = {f"seq{i:02d}": make_sequence(rng, n_frames, n_obj, max_size) for i in range(n_seq)}
        ok &= compare(label, seqs, python, size)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
