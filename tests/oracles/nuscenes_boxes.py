"""Reference values from nuscenes-devkit 1.2.0, printed as JSON (run in .oracle-envs/nuscenes).

Usage: python nuscenes_boxes.py VERSION DATAROOT

For every sample_data: ``NuScenes.get_sample_data(token, box_vis_level=BoxVisibility.NONE)`` boxes in
the sensor frame (every annotation of the sample, none dropped by the camera-visibility filter), the
sample_data's ego pose and calibration; for every sample_annotation ``box_velocity`` (null when the
devkit cannot compute it, e.g. a prev/next token that is not in the tables).
"""

import json
import sys

from nuscenes.nuscenes import NuScenes
from nuscenes.utils.geometry_utils import BoxVisibility


def main() -> None:
    version, dataroot = sys.argv[1], sys.argv[2]
    nusc = NuScenes(version=version, dataroot=dataroot, verbose=False)
    sample_data = []
    for record in nusc.sample_data:
        _, boxes, intrinsic = nusc.get_sample_data(record["token"], box_vis_level=BoxVisibility.NONE)
        calibration = nusc.get("calibrated_sensor", record["calibrated_sensor_token"])
        pose = nusc.get("ego_pose", record["ego_pose_token"])
        sample_data.append(
            {
                "token": record["token"],
                "channel": record["channel"],
                "timestamp": repr(record["timestamp"]),
                "ego_rotation": list(pose["rotation"]),
                "ego_translation": list(pose["translation"]),
                "sensor_rotation": list(calibration["rotation"]),
                "sensor_translation": list(calibration["translation"]),
                "camera_intrinsic": None if intrinsic is None else intrinsic.tolist(),
                "boxes": [
                    {
                        "token": box.token,
                        "center": box.center.tolist(),
                        "wlh": box.wlh.tolist(),
                        "orientation": list(box.orientation.elements),
                    }
                    for box in boxes
                ],
            }
        )
    velocities = {}
    for record in nusc.sample_annotation:
        try:
            velocities[record["token"]] = nusc.box_velocity(record["token"]).tolist()
        except KeyError:
            velocities[record["token"]] = None
    json.dump({"sample_data": sample_data, "velocity": velocities}, sys.stdout, allow_nan=True)


if __name__ == "__main__":
    main()
