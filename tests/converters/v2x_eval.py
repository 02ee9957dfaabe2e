"""``avdata eval detection --protocol avdata`` on a converted collaborative dataset, with known counts.

Predictions are the visible ground truth (visible: some sensor has the object in its field of view with at
least one lidar point, computed here from the visibility table) minus three objects, plus one false
positive 500 m away, so the expected TP / FN / FP are known before the evaluation runs.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from avdata.schema import DatasetReader

COLUMNS = ["scene", "frame_index", "object_id", "class", "x_world_m", "y_world_m", "z_world_m", "length_m",
           "width_m", "height_m", "yaw_world_rad"]


def check_eval_three_missed_one_false(dst: Path, tmp_path: Path) -> dict:
    dataset = DatasetReader(dst)
    objects = dataset.objects().select(COLUMNS).to_pylist()
    visibility = dataset.visibility().to_pylist()
    seen = {(v["scene"], v["frame_index"], v["object_id"]) for v in visibility if v["in_fov"] and v["n_points"] > 0}
    visible = [o | {"score": 0.9} for o in objects if (o["scene"], o["frame_index"], o["object_id"]) in seen]
    assert len(visible) >= 5
    false_positive = visible[0] | {"object_id": "fp", "x_world_m": visible[0]["x_world_m"] + 500.0}
    preds = tmp_path / "preds.json"
    preds.write_text(json.dumps(visible[3:] + [false_positive]))
    out = tmp_path / "metrics.json"
    proc = subprocess.run([sys.executable, "-m", "avdata.cli", "eval", "detection", "--protocol", "avdata", str(dst),
                           str(preds), "--json", str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    metrics = json.loads(out.read_text())["all"]
    assert (metrics["TP"], metrics["FN"], metrics["FP"]) == (len(visible) - 3, 3, 1)
    assert np.isclose(metrics["recall"], (len(visible) - 3) / len(visible))
    return metrics
