"""av2-api 0.3.6's ROI raster of a log map and its sensor-dataset constants (run with .oracle-envs/av2/bin/python).

Usage: av2_map_and_constants.py LOG_DIR OUT.npz

Saves ``ArgoverseStaticMap.from_map_dir(LOG_DIR/map, build_raster=True)``'s ROI raster array and its
city -> raster Sim(2) (R, t, s) into OUT.npz, and prints the category, camera and timing constants as JSON.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from av2.datasets.sensor.constants import AnnotationCategories, RingCameras, StereoCameras
from av2.evaluation import SensorCompetitionCategories
from av2.map.map_api import ArgoverseStaticMap
from av2.utils.synchronization_database import SynchronizationDB


def main() -> None:
    log_dir, out = Path(sys.argv[1]), Path(sys.argv[2])
    avm = ArgoverseStaticMap.from_map_dir(log_dir / "map", build_raster=True)
    layer = avm.raster_roi_layer
    sim2 = layer.array_Sim2_city
    np.savez(out, roi=layer.array, R=sim2.rotation, t=sim2.translation, s=np.array(sim2.scale))
    print(json.dumps({
        "annotation_categories": [c.value for c in AnnotationCategories],
        "competition_categories": [c.value for c in SensorCompetitionCategories],
        "ring_cameras": [c.value for c in RingCameras],
        "stereo_cameras": [c.value for c in StereoCameras],
        "max_lidar_ring_cam_timestamp_diff_ns": int(SynchronizationDB.MAX_LIDAR_RING_CAM_TIMESTAMP_DIFF),
    }))


if __name__ == "__main__":
    main()
