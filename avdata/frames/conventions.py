"""Fixed axis conventions of the sources, each as an explicit transform.

Unified conventions (docs/conventions.md): body and lidar frames x forward, y left, z up (REP-103);
camera frames optical, x right, y down, z forward; everything on disk right-handed.
"""

from __future__ import annotations

import numpy as np

from avdata.frames.transform import Transform

#: ``xfwd_T_optical``: maps optical camera coordinates (x right, y down, z forward) into a camera
#: frame with x forward, y left, z up (Waymo's camera frame, REP-103 body axes). Columns are the
#: optical axes expressed in the x-forward frame: right = -y, down = -z, forward = +x.
XFWD_T_OPTICAL = Transform(
    rotation=np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]),
    translation=np.zeros(3),
)

#: ``rh_T_carla``: the reflection from CARLA/Unreal's left-handed axes (x forward, y right, z up)
#: into right-handed ones (x forward, y left, z up). Improper (det -1): y changes sign.
RH_T_CARLA = Transform(rotation=np.diag([1.0, -1.0, 1.0]), translation=np.zeros(3))


def carla_rotation_matrix(rotation_deg: np.ndarray) -> np.ndarray:
    """CARLA's rotation matrix for (roll, pitch, yaw) in degrees, in its left-handed coordinates.

    This is ``carla.Transform.get_matrix()`` (and OPV2V's ``x_to_world``) written out: yaw about z,
    pitch about y, roll about x, with CARLA's signs.

    Args:
        rotation_deg: (..., 3) roll, pitch, yaw in degrees.

    Returns:
        (..., 3, 3) matrices acting on left-handed coordinates.
    """
    roll, pitch, yaw = np.moveaxis(np.radians(np.asarray(rotation_deg, dtype=np.float64)), -1, 0)
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    return np.stack(
        [
            np.stack([cp * cy, cy * sp * sr - sy * cr, -cy * sp * cr - sy * sr], axis=-1),
            np.stack([cp * sy, sy * sp * sr + cy * cr, -sy * sp * cr + cy * sr], axis=-1),
            np.stack([sp, -cp * sr, cp * cr], axis=-1),
        ],
        axis=-2,
    )
