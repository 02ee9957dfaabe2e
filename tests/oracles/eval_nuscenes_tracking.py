"""Oracle: nuscenes-devkit 1.2.0 TrackingEval (AMOTA, AMOTP) on a nuScenes-schema folder; prints JSON.

    eval_nuscenes_tracking.py DATAROOT RESULTS_JSON OUTPUT_DIR   (version v1.0-mini, split mini_val)
"""

import json
import sys

import numpy as np
from nuscenes.eval.common.config import config_factory
from nuscenes.eval.tracking.evaluate import TrackingEval


def main():
    dataroot, results, output = sys.argv[1:4]
    ev = TrackingEval(config_factory("tracking_nips_2019"), results, "mini_val", output, "v1.0-mini", dataroot,
                      verbose=False)
    metrics, _ = ev.evaluate()
    label = metrics.label_metrics
    out = {cls: {"AMOTA": label["amota"][cls], "AMOTP": label["amotp"][cls]} for cls in label["amota"]}
    out["all"] = {"AMOTA": metrics.compute_metric("amota"), "AMOTP": metrics.compute_metric("amotp")}

    def clean(v):
        return None if v is None or (isinstance(v, float) and np.isnan(v)) else float(v)

    print(json.dumps({c: {k: clean(v) for k, v in m.items()} for c, m in out.items()}))


if __name__ == "__main__":
    main()
