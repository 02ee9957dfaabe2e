"""Format limits: finite values beyond these are damage, never data, and are refused.

One home for the magnitudes the scene writer refuses and the sources check their records against (a source
drops a record beyond them with one error; the writer refuses a frame that still holds one), so both use the
same numbers. Nothing here imports more of avdata than the frames' box type.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from avdata.frames import Boxes3D

#: Largest box length, width or height; sizes must also be >= 0.
MAX_BOX_SIZE_M = 1_000.0
#: Largest |coordinate| of a box centre or a transform's translation (UTM northings reach 1e7 m).
MAX_COORDINATE_M = 1e7
#: Largest |velocity| component of a box.
MAX_SPEED_MPS = 1_000.0
#: Times are int64 nanoseconds in [0, MAX_TIME_NS].
MAX_TIME_NS = 2**63 - 1
#: Largest |value| in pixels: a camera matrix entry (K, P), an image side, a 2D box or ignore-region corner
#: (projected boxes may reach past the image edge, not by orders of magnitude; the largest camera images are
#: ~10^4 pixels wide).
MAX_CAMERA_VALUE_PX = 1e6
#: Largest |angle| of a heading or rotation field, two turns: sources write them within +-pi (KITTI, Waymo) or
#: +-360 degrees (CARLA), and a world heading adds a vehicle's; beyond this a value is damage (an angle of
#: 1e308 rad gives a box of arbitrary heading, without a word).
MAX_ANGLE_RAD = 4 * np.pi
#: Largest finite float32: the visibility fields are stored as float32.
FLOAT32_MAX = float(np.finfo(np.float32).max)


def box_magnitude_problem(boxes: Boxes3D) -> str | None:
    """What is absurd about the first implausible box of (N,) boxes, or None (limits: module constants).

    Converters drop the objects :func:`implausible_boxes` flags before
    :meth:`~avdata.schema.scene_writer.SceneWriter.add_frame`, which refuses a frame that still holds one.
    """
    bad = implausible_boxes(boxes)
    if not np.any(bad):
        return None
    i = int(np.argmax(bad))
    name = "" if boxes.ids is None else f" {str(boxes.ids[i])!r}"
    velocity = "" if boxes.velocity is None else f", velocity {boxes.velocity[i].tolist()} m/s"
    return (f"object{name}: expected a size in [0, {MAX_BOX_SIZE_M:g}] m, a centre within {MAX_COORDINATE_M:g} m and "
            f"a speed within {MAX_SPEED_MPS:g} m/s per axis, got size {boxes.size_lwh[i].tolist()} m, centre "
            f"{boxes.center[i].tolist()} m{velocity}")


def implausible_boxes(boxes: Boxes3D) -> np.ndarray:
    """(N,) True where a box is finite but absurd: size < 0 or > 1 km, centre beyond 1e7 m, speed beyond 1 km/s.

    Non-finite sizes and centres count as absurd too; a NaN velocity means "unknown" and passes.
    """
    ok: np.ndarray = (np.all((boxes.size_lwh >= 0.0) & (boxes.size_lwh <= MAX_BOX_SIZE_M), axis=1)
                      & np.all(np.abs(boxes.center) <= MAX_COORDINATE_M, axis=1))
    if boxes.velocity is not None:
        ok &= ~np.any(np.abs(boxes.velocity) > MAX_SPEED_MPS, axis=1)
    return ~ok
