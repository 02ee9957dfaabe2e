"""Oracle: nuscenes-devkit 1.2.0 DetectionEval on a nuScenes-schema folder; prints JSON metrics.

    eval_nuscenes_detection.py DATAROOT RESULTS_JSON OUTPUT_DIR   (version v1.0-mini, split mini_val)
"""

import json
import sys

import numpy as np
from nuscenes import NuScenes
from nuscenes.eval.common.config import config_factory
from nuscenes.eval.detection.evaluate import DetectionEval


def main():
    dataroot, results, output = sys.argv[1:4]
    nusc = NuScenes(version="v1.0-mini", dataroot=dataroot, verbose=False)
    ev = DetectionEval(nusc, config_factory("detection_cvpr_2019"), results, "mini_val", output, verbose=False)
    metrics, md_list = ev.evaluate()
    out = metrics.serialize()

    def clean(x):
        if isinstance(x, dict):
            return {str(k): clean(v) for k, v in x.items()}
        if isinstance(x, float) and np.isnan(x):
            return None
        return x

    print(json.dumps(clean(out)))


if __name__ == "__main__":
    main()
