"""``--protocol opv2v``: OpenCOOD's BEV AP, on hand-worked cases and against an independent reimplementation.

Reference (public, not a package): OpenCOOD ``opencood/utils/eval_utils.py`` (``caluclate_tp_fp``,
``calculate_ap``, ``voc_ap``) and ``opencood/utils/box_utils.py`` / ``common_utils.py`` (corners, shapely
polygon IoU). :func:`reference_ap` below follows those functions line by line with Python lists, and its
polygon IoU is an independent Sutherland-Hodgman clip with the shoelace formula (not avdata's geometry).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from avdata.errors import InputError
from avdata.eval.cli import add_eval_subparser
from avdata.eval.detection.opv2v import EVAL_RANGES_M, evaluate_opv2v, frame_tp_fp, in_range, voc_ap
from tests.loaders.conftest import _write


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The loader tests' hand-checkable dataset (ego-frame boxes in its objects index)."""
    return _write(tmp_path_factory.mktemp("opv2v_eval") / "ds")


def box(x: float, y: float, length: float = 4.0, width: float = 2.0, yaw: float = 0.0) -> list[float]:
    return [x, y, 0.0, length, width, 1.5, yaw]


# ------------------------------------------------------------------ independent reimplementation
def corners(b) -> list[tuple[float, float]]:
    x, y, _, length, width, _, yaw = b
    c, s = np.cos(yaw), np.sin(yaw)
    half = ((length / 2, width / 2), (-length / 2, width / 2), (-length / 2, -width / 2), (length / 2, -width / 2))
    return [(x + c * dx - s * dy, y + s * dx + c * dy) for dx, dy in half]


def shoelace(poly) -> float:
    return 0.5 * abs(sum(p[0] * q[1] - q[0] * p[1] for p, q in zip(poly, poly[1:] + poly[:1], strict=True)))


def clip(subject, clipper):
    """Sutherland-Hodgman: ``subject`` clipped by the convex counter-clockwise ``clipper``."""
    out = subject
    for a, b in zip(clipper, clipper[1:] + clipper[:1], strict=True):
        def inside(p, a=a, b=b):
            return (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]) >= 0

        def cut(p, q, a=a, b=b):
            x1, y1, x2, y2 = p[0], p[1], q[0], q[1]
            x3, y3, x4, y4 = a[0], a[1], b[0], b[1]
            den = (x1 - x2) * (y3 - y4) - (y1 - y2) * (x3 - x4)
            t = ((x1 - x3) * (y3 - y4) - (y1 - y3) * (x3 - x4)) / den
            return (x1 + t * (x2 - x1), y1 + t * (y2 - y1))

        points, out = out, []
        for i, p in enumerate(points):
            q = points[i - 1]
            if inside(p):
                if not inside(q):
                    out.append(cut(q, p))
                out.append(p)
            elif inside(q):
                out.append(cut(q, p))
        if not out:
            return []
    return out


def polygon_iou(a, b) -> float:
    pa_, pb = corners(a), corners(b)
    inter = clip(pa_, pb)
    area = shoelace(inter) if len(inter) >= 3 else 0.0
    return area / (shoelace(pa_) + shoelace(pb) - area)


def reference_ap(frames, iou_thresh, global_sort=False) -> float:
    """OpenCOOD's caluclate_tp_fp + calculate_ap + voc_ap (list form), over frames [(dets, scores, gts)]."""
    stat = {"tp": [], "fp": [], "gt": 0, "score": []}
    for dets, scores, gts in frames:
        order = sorted(range(len(scores)), key=lambda i: -scores[i])
        remaining = list(gts)
        for i in order:
            ious = [polygon_iou(dets[i], g) for g in remaining]
            if not remaining or max(ious) < iou_thresh:
                stat["fp"].append(1)
                stat["tp"].append(0)
                continue
            stat["fp"].append(0)
            stat["tp"].append(1)
            remaining.pop(int(np.argmax(ious)))
        stat["score"] += [scores[i] for i in order]
        stat["gt"] += len(gts)
    fp, tp = stat["fp"], stat["tp"]
    if global_sort:
        order = sorted(range(len(tp)), key=lambda i: -stat["score"][i])
        fp, tp = [fp[i] for i in order], [tp[i] for i in order]
    cumsum = 0
    for idx, val in enumerate(fp):
        fp[idx] += cumsum
        cumsum += val
    cumsum = 0
    for idx, val in enumerate(tp):
        tp[idx] += cumsum
        cumsum += val
    rec = [float(t) / stat["gt"] for t in tp]
    prec = [float(t) / (f + t) for t, f in zip(tp, fp, strict=True)]
    mrec = [0.0, *rec, 1.0]
    mpre = [0.0, *prec, 0.0]
    for i in range(len(mpre) - 2, -1, -1):
        mpre[i] = max(mpre[i], mpre[i + 1])
    return sum((mrec[i] - mrec[i - 1]) * mpre[i] for i in range(1, len(mrec)) if mrec[i] != mrec[i - 1])


def evaluate(frames, **kwargs):
    gt = {("s", k): np.array(g, dtype=float).reshape(-1, 7) for k, (_, _, g) in enumerate(frames)}
    pred = {("s", k): (np.array(d, dtype=float).reshape(-1, 7), np.array(sc, dtype=float))
            for k, (d, sc, _) in enumerate(frames)}
    return evaluate_opv2v(gt, pred, **kwargs)


# ------------------------------------------------------------------ hand-worked cases
def test_one_false_positive_between_two_hits() -> None:
    # tp = [1, 0, 1]: recall [1/2, 1/2, 1], precision [1, 1/2, 2/3]; envelope [1, 1, 2/3, 2/3]
    frames = [([box(0, 0), box(30, 0), box(10, 5)], [0.9, 0.8, 0.7], [box(0, 0), box(10, 5)])]
    result = evaluate(frames)
    for t in (0.3, 0.5, 0.7):
        assert result.ap[t] == pytest.approx(0.5 * 1 + 0.5 * 2 / 3, abs=1e-9)
    np.testing.assert_allclose(result.precision[0.5], [1.0, 0.5, 2 / 3], atol=1e-12)


def test_iou_of_six_tenths_passes_0_3_and_0_5_but_not_0_7() -> None:
    # 4 x 2 boxes 1 m apart along x: overlap 3 x 2 = 6, union 16 - 6 = 10
    frames = [([box(1, 0)], [0.5], [box(0, 0)])]
    result = evaluate(frames)
    assert [result.ap[t] for t in (0.3, 0.5, 0.7)] == [pytest.approx(1.0, abs=1e-12)] * 2 + [0.0]


def test_rotated_square_iou_is_one_over_root_two() -> None:
    # a 2 x 2 square and itself turned 45 deg: octagon 8 (sqrt2 - 1), union 8 (2 - sqrt2): IoU 1/sqrt2 = 0.7071
    tp, _ = frame_tp_fp(np.array([box(0, 0, 2, 2, np.pi / 4)]), np.array([1.0]), np.array([box(0, 0, 2, 2)]), 0.7)
    assert tp.tolist() == [True]
    assert polygon_iou(box(0, 0, 2, 2, np.pi / 4), box(0, 0, 2, 2)) == pytest.approx(1 / np.sqrt(2), abs=1e-12)
    tp, _ = frame_tp_fp(np.array([box(0, 0, 2, 2, np.pi / 4)]), np.array([1.0]), np.array([box(0, 0, 2, 2)]), 0.71)
    assert tp.tolist() == [False]


def test_frame_order_against_global_sort() -> None:
    # frame 0: an FP at 0.5; frame 1: a TP at 0.9. Frame order tp [0, 1] -> AP 1/2; sorted [1, 0] -> AP 1
    frames = [([box(50, 0)], [0.5], []), ([box(0, 0)], [0.9], [box(0, 0)])]
    assert evaluate(frames).ap[0.5] == pytest.approx(0.5, abs=1e-12)
    assert evaluate(frames, global_sort=True).ap[0.5] == pytest.approx(1.0, abs=1e-12)


def test_greedy_matching_takes_the_best_remaining_ground_truth() -> None:
    # the 0.9 detection overlaps both; it takes the better (IoU 0.6), the 0.8 detection matches the other
    tp, scores = frame_tp_fp(np.array([box(2, 0), box(1, 0)]), np.array([0.8, 0.9]),
                             np.array([box(0, 0), box(4, 0)]), 0.3)
    assert scores.tolist() == [0.9, 0.8] and tp.tolist() == [True, True]
    tp, _ = frame_tp_fp(np.array([box(2, 0), box(1, 0)]), np.array([0.8, 0.9]), np.array([box(0, 0)]), 0.3)
    assert tp.tolist() == [True, False]


def test_the_range_drops_boxes_with_a_corner_outside() -> None:
    x_max = EVAL_RANGES_M["opv2v"][2]
    assert in_range(np.array([box(x_max - 2.0, 0), box(x_max - 1.9, 0), box(0, 38.9), box(0, 39.1)]),
                    EVAL_RANGES_M["opv2v"]).tolist() == [True, False, True, False]
    frames = [([box(0, 0), box(140, 0)], [0.9, 0.95], [box(0, 0), box(140, 0)])]
    result = evaluate(frames)
    assert result.n_gt == 1 and result.n_pred == 1 and result.ap[0.7] == pytest.approx(1.0, abs=1e-12)
    assert evaluate(frames, range_m=(-150, -40, 150, 40)).n_gt == 2


def test_voc_ap_of_a_hand_curve() -> None:
    # recall [0.25, 0.5, 0.5, 0.75], precision [1, 1, 2/3, 0.75]: 0.25 + 0.25 + 0.25 * 0.75
    assert voc_ap(np.array([0.25, 0.5, 0.5, 0.75]), np.array([1.0, 1.0, 2 / 3, 0.75])) == pytest.approx(0.6875, abs=1e-12)


def test_no_ground_truth_in_range_and_unknown_frames_are_errors() -> None:
    with pytest.raises(InputError, match="inside the range"):
        evaluate([([box(0, 0)], [0.5], [box(200, 0)])])
    with pytest.raises(InputError, match="frame 7"):
        evaluate_opv2v({("s", 0): np.array([box(0, 0)])}, {("s", 7): (np.array([box(0, 0)]), np.array([1.0]))})


@pytest.mark.parametrize("global_sort", [False, True])
def test_random_scenes_match_the_reference(global_sort: bool) -> None:
    rng = np.random.default_rng(5)
    frames = []
    for _ in range(12):
        gts = [box(*rng.uniform(-60, 60, 2), rng.uniform(3, 5), rng.uniform(1.5, 2.2), rng.uniform(-np.pi, np.pi))
               for _ in range(rng.integers(0, 7))]
        dets = [[g[0] + rng.normal(0, 0.25), g[1] + rng.normal(0, 0.25), 0.0, g[3] * rng.uniform(0.9, 1.1),
                 g[4] * rng.uniform(0.9, 1.1), 1.5, g[6] + rng.normal(0, 0.1)] for g in gts if rng.random() < 0.8]
        dets += [box(*rng.uniform(-60, 60, 2)) for _ in range(rng.integers(0, 3))]
        frames.append((dets, rng.uniform(0, 1, len(dets)).tolist(), gts))
    result = evaluate(frames, global_sort=global_sort, range_m=(-100.0, -100.0, 100.0, 100.0))
    for t in (0.3, 0.5, 0.7):
        assert result.ap[t] == pytest.approx(reference_ap(frames, t, global_sort), abs=1e-9)
    assert 0.1 < result.ap[0.7] < result.ap[0.5] <= result.ap[0.3] < 1.0  # the case is not trivial


def _run(argv):
    parser = argparse.ArgumentParser(prog="avdata")
    add_eval_subparser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(argv)
    return args.run(args)


def test_cli_scores_the_ground_truth_itself_as_perfect(tmp_path: Path, dataset: Path) -> None:
    objects = pq.read_table(dataset / "index" / "objects.parquet")
    columns = ["scene", "frame_index", "x_ego_m", "y_ego_m", "z_ego_m", "length_m", "width_m", "height_m", "yaw_ego_rad"]
    pred = objects.select(columns).append_column("score", pa.array(np.linspace(1, 0.5, len(objects))))
    pq.write_table(pred, tmp_path / "pred.parquet")
    out = tmp_path / "result.json"
    assert _run(["eval", "detection", str(dataset), str(tmp_path / "pred.parquet"), "--protocol", "opv2v",
                 "--json", str(out)]) == 0
    row = json.loads(out.read_text())["all"]
    assert [row["AP@0.3"], row["AP@0.5"], row["AP@0.7"]] == pytest.approx([1.0, 1.0, 1.0], abs=1e-9)
    assert row["GT"] == len(objects)
    half = pred.slice(0, len(pred) // 2)
    pq.write_table(half, tmp_path / "half.parquet")
    assert _run(["eval", "detection", str(dataset), str(tmp_path / "half.parquet"), "--protocol", "opv2v",
                 "--range-m", "-500", "-500", "500", "500", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["all"]["AP@0.5"] == pytest.approx(len(half) / len(objects), abs=1e-9)
