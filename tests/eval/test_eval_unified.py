"""The avdata protocol on a unified dataset built in the test (tables, then through DatasetReader)."""

import numpy as np
import pyarrow as pa
import pytest
from eval_unified_synth import make_frames, make_tables

from avdata.errors import InputError
from avdata.eval.tracking import Similarity, TrackingMetric, evaluate_tracking, summary
from avdata.eval.unified import (
    UnifiedDetectionConfig,
    detection_breakdown,
    prediction_metrics,
    tracking_sequences,
    visible_mask,
)

BOX = ["scene", "frame_index", "object_id", "class", "x_world_m", "y_world_m", "z_world_m", "length_m",
       "width_m", "height_m", "yaw_world_rad"]


def _detections(objects: pa.Table, shift_m: float, drop: set[str], extra: int) -> pa.Table:
    table = objects.select(BOX).to_pylist()
    out = []
    for r in table:
        if r["object_id"] in drop:
            continue
        out.append(r | {"x_world_m": r["x_world_m"] + shift_m, "score": 0.9})
    for k in range(extra):
        out.append(table[k] | {"x_world_m": table[k]["x_world_m"] + 50, "object_id": f"fp{k}", "score": 0.4})
    return pa.Table.from_pylist(out)


def test_visibility_decides_misses():
    objects, visibility = make_tables()
    visible = visible_mask(objects, visibility)
    ids = np.array(objects["object_id"].to_pylist())
    assert not visible[ids == "obj0"].any() and visible[ids == "obj1"].all()
    # Detect everything except obj0 (never visible) and obj2; add 5 false positives far away.
    dets = _detections(objects, 0.5, {"obj0", "obj2"}, 5)
    res = detection_breakdown(objects, visibility, dets, frames=make_frames(objects))
    n_frames = 20
    # Visible objects: obj1..obj5 -> 5 per frame; obj2 missed -> FN 20; obj0 is not a miss.
    assert res["all"]["TP"] == 4 * n_frames and res["all"]["FN"] == n_frames and res["all"]["FP"] == 5
    assert res["all"]["recall"] == pytest.approx(0.8)
    assert res["all"]["precision"] == pytest.approx(80 / 85) and res["all"]["FPR"] == pytest.approx(5 / 85)
    assert res["class=car"]["FN"] == n_frames  # obj2 is a car
    assert res["sensor=ego/cam_front"]["recall"] == pytest.approx(0.8)
    assert res["sensor=ego/lidar_top"]["recall"] == pytest.approx(0.75)  # obj1 only in the camera
    # Matching distance: 0.5 m shift fails at 0.4 m; then every detection is a false positive.
    strict = detection_breakdown(objects, visibility, dets, UnifiedDetectionConfig(match_distance_m=0.4),
                                 frames=make_frames(objects))
    assert strict["all"]["TP"] == 0 and strict["all"]["FP"] == len(dets)
    # Detecting the invisible obj0 is neither a TP nor an FP.
    with_obj0 = detection_breakdown(objects, visibility, _detections(objects, 0.0, set(), 0),
                                   frames=make_frames(objects))
    assert with_obj0["all"]["FP"] == 0 and with_obj0["all"]["TP"] == 5 * n_frames
    total_bands = sum(v["FN"] for k, v in res.items() if k.startswith("distance="))
    assert total_bands == res["all"]["FN"]


def test_tracking_perfect_and_with_invisible_tracks():
    objects, visibility = make_tables()
    tracks = _detections(objects, 0.0, set(), 0).drop(["score"])
    seqs = tracking_sequences(objects, visibility, tracks, ["car", "pedestrian"], Similarity.IOU_3D)
    for cls in ("car", "pedestrian"):
        res = summary(evaluate_tracking(seqs[cls], [TrackingMetric.HOTA, TrackingMetric.CLEAR])["COMBINED_SEQ"])
        # The track of invisible obj0 (a car) is removed with its ground truth: still perfect.
        assert res["HOTA"] == pytest.approx(1.0) and res["MOTA"] == pytest.approx(1.0)
        assert res["CLR_FP"] == 0


def test_prediction_from_future_frames():
    objects, _ = make_tables()
    rows = []
    table = objects.to_pylist()
    by_key = {(r["frame_index"], r["object_id"]): r for r in table}
    for f in (0, 5):
        for o in ("obj3", "obj4"):
            for mode, (dx, p) in enumerate([(0.0, 0.7), (3.0, 0.3)]):
                for step in (1, 2, 3):
                    gt = by_key[(f + step, o)]
                    rows.append({"scene": "s0", "frame_index": f, "object_id": o, "mode": mode, "probability": p,
                                 "step": step, "x_world_m": gt["x_world_m"] + dx, "y_world_m": gt["y_world_m"]})
    res = prediction_metrics(objects, pa.Table.from_pylist(rows))
    assert res["ADE"] == pytest.approx(0.0) and res["minFDE_1"] == pytest.approx(0.0)
    assert "minADE_nuscenes_5" not in res  # only 2 modes
    with pytest.raises(InputError, match="agents x"):
        prediction_metrics(objects, pa.Table.from_pylist(rows[:-1]))


def test_unmatched_detection_distance_uses_frames_world_T_ego():
    # A false positive 5 m from the ego position stored in frames.parquet (not derived from object rows): moving
    # the stored ego pose of its frame moves it from the 0-20 m band to the 40-60 m band.
    objects, visibility = make_tables()
    frames = make_frames(objects)
    ego_x = frames["world_T_ego_x_m"].to_pylist()[3]
    fp = {c: v for c, v in _detections(objects, 0.0, set(), 0).to_pylist()[0].items()}
    fp |= {"scene": "s0", "frame_index": 3, "object_id": "fp", "x_world_m": ego_x + 5.0, "y_world_m": 0.0}
    dets = pa.Table.from_pylist([fp])
    near = detection_breakdown(objects, visibility, dets, frames=frames)
    assert near["distance=0-20m"]["FP"] == 1 and near["distance=40-60m"]["FP"] == 0
    moved = frames.set_column(frames.schema.get_field_index("world_T_ego_x_m"), "world_T_ego_x_m",
                              pa.array([x - 45.0 if i == 3 else x for i, x in enumerate(frames["world_T_ego_x_m"].to_pylist())]))
    far = detection_breakdown(objects, visibility, dets, frames=moved)
    assert far["distance=40-60m"]["FP"] == 1 and far["distance=0-20m"]["FP"] == 0
