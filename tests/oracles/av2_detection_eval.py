"""av2-api 0.3.6's ``evaluation.detection.eval.evaluate`` (run with .oracle-envs/av2/bin/python).

Usage: av2_detection_eval.py SPLIT_DIR GTS.feather DTS.feather ROI(0|1)

GTS and DTS are av2's own tables (log_id, timestamp_ns, category, the 10 cuboid columns, and
num_interior_pts / score). Prints (JSON) av2's rounded summary, the unrounded summary (av2's own
``summarize_metrics`` on the tables ``evaluate`` returns, plus its mean row) and the per-row columns
``evaluate`` adds (in the input row order).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from av2.evaluation.detection.eval import evaluate, summarize_metrics
from av2.evaluation.detection.utils import DetectionCfg
from av2.utils.io import read_feather


def main() -> None:
    split_dir, gts_path, dts_path, roi = Path(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4] == "1"
    gts = read_feather(Path(gts_path))
    dts = read_feather(Path(dts_path))
    gts["row"] = np.arange(len(gts))
    dts["row"] = np.arange(len(dts))
    cfg = DetectionCfg(dataset_dir=split_dir, eval_only_roi_instances=roi)
    dts_out, gts_out, metrics = evaluate(dts, gts, cfg, n_jobs=2)
    full = summarize_metrics(dts_out, gts_out, cfg)
    full.loc["AVERAGE_METRICS"] = full.mean()
    columns = [*cfg.affinity_thresholds_m, "ATE", "ASE", "AOE", "is_evaluated"]
    dts_out = dts_out.sort_values("row")
    gts_out = gts_out.sort_values("row")
    json.dump(
        {
            "rounded": {c: {k: float(v) for k, v in row.items()} for c, row in metrics.iterrows()},
            "full": {c: {k: float(v) for k, v in row.items()} for c, row in full.iterrows()},
            "dts_outcome": dts_out[columns].to_numpy(dtype=float).tolist(),
            "gts_outcome": gts_out[columns].to_numpy(dtype=float).tolist(),
        },
        sys.stdout,
    )


if __name__ == "__main__":
    main()
