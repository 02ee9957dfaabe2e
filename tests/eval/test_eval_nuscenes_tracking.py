"""nuScenes AMOTA / AMOTP equal nuscenes-devkit 1.2.0 TrackingEval on randomised tables and tracks."""

import numpy as np
import pytest
from eval_nuscenes_synth import write_nuscenes
from eval_oracle_env import run_oracle

from avdata.eval.nuscenes_gt import load_nuscenes_bike_racks
from avdata.eval.tracking.nuscenes import evaluate_nuscenes_tracking, load_nuscenes_tracking


@pytest.mark.oracle
def test_amota_amotp_equal_devkit(tmp_path):
    write_nuscenes(tmp_path, 3)
    oracle = run_oracle("nuscenes", "eval_nuscenes_tracking.py", str(tmp_path), str(tmp_path / "tracking.json"),
                        str(tmp_path / "out"))
    gt, pred, order = load_nuscenes_tracking(tmp_path / "v1.0-mini", tmp_path / "tracking.json")
    racks = load_nuscenes_bike_racks(tmp_path / "v1.0-mini")
    assert len(racks.sample) > 3  # the devkit's bike-rack filter is exercised
    ours = evaluate_nuscenes_tracking(gt, pred, order, bike_racks=racks)
    for cls, ref in oracle.items():
        for metric in ("AMOTA", "AMOTP"):
            if ref[metric] is None:
                assert np.isnan(ours[cls][metric]), (cls, metric)
            else:
                assert ours[cls][metric] == pytest.approx(ref[metric], abs=1e-9), (cls, metric)
    assert 0.2 < ours["all"]["AMOTA"] < 0.9
