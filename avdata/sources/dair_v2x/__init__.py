"""DAIR-V2X-C files: JSON readers, calibration transforms with checked orthonormality, 3D labels.

Official layout: ``cooperative/data_info.json`` (pairs with ``system_error_offset``),
``cooperative/label_world/<vehicle id>.json``, ``vehicle-side/{velodyne,label/lidar,calib/*}``,
``infrastructure-side/{velodyne,label/virtuallidar,calib/*}``. Calibration files hold ``rotation``
(3x3) and ``translation`` (3x1), at the top level (``novatel_to_world``, ``virtuallidar_to_world``) or
under ``transform`` (``lidar_to_novatel``), mapping the first-named frame into the second: the
camera extrinsics ``lidar_to_camera`` (vehicle) and ``virtuallidar_to_camera`` (infrastructure) map
lidar points into the camera's optical frame (x right, y down, z forward). ``calib/camera_intrinsic``
files hold ``cam_K`` (3x3 row-major, flat or nested) and ``cam_D`` (k1, k2, p1, p2, k3: ROS/OpenCV
plumb_bob order, the 5 numbers of a ROS CameraInfo ``D``).

Devkit formulas (DAIR-V2X ``v2x/v2x_utils`` / OpenCOOD ``dair`` datasets): vehicle lidar to world =
``novatel_to_world @ lidar_to_novatel``; infrastructure lidar to world = ``virtuallidar_to_world``
with ``system_error_offset`` added to its translation: ``t_x += delta_x``, ``t_y += delta_y``.
Labels: ``3d_location`` is the box centre, ``3d_dimensions`` {h, w, l}, ``rotation`` the yaw about z.
Camera projection (``tools/visualize/vis_utils.py`` ``get_cam_8_points`` + ``points_cam2img``,
``v2x/dataset/base_dataset.py`` ``get_annos``): pixel = ``cam_K @ (R @ p_lidar + t)`` divided by its
third row, with R, t of ``lidar_to_camera``; the devkit never applies ``cam_D``
(``tools/dataset_converter/gen_kitti/gen_calib2kitti.py`` reads and drops it).

The published rotations are re-calibrations that are orthonormal only to ~1e-7 .. 1e-3; they are
replaced by the nearest rotation (SVD) by the one rule of :mod:`avdata.frames.rotations`: silently up
to ``SILENT_TOLERANCE``, with a warning up to ``REPAIR_TOLERANCE``, refused above it. The residual is
max |RᵀR - I|.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from avdata.errors import InputError, one_line
from avdata.frames import Transform
from avdata.frames.rotations import repaired_rotation, rotation_deviation
from avdata.inputs import DuplicateKeyError, Source, read_regular_file, unique_object
from avdata.schema.limits import MAX_ANGLE_RAD, MAX_BOX_SIZE_M, MAX_CAMERA_VALUE_PX, MAX_COORDINATE_M

#: DAIR ``type`` -> unified class (the DAIR 3D detection classes).
CLASS_MAP = {
    "car": "car", "van": "car", "truck": "truck", "bus": "bus", "pedestrian": "pedestrian",
    "cyclist": "cyclist", "motorcyclist": "motorcycle", "tricyclist": "cyclist", "barrowlist": "other",
    "trafficcone": "traffic_cone",
}


def read_json(path: Source) -> Any:
    """A JSON file's (or object's, read whole) content; InputError naming the file and line on failure."""
    try:
        return json.loads(read_regular_file(path), object_pairs_hook=unique_object)
    except OSError as error:
        raise InputError(f"{path}: cannot read ({error.strerror or error})") from None
    except DuplicateKeyError as error:
        raise InputError(f"{path}: {error}") from None
    except (ValueError, RecursionError) as error:  # also an integer of 5000 digits, arrays nested 100000 deep
        raise InputError(f"{path}: malformed JSON ({one_line(error)})") from None


@dataclass(frozen=True, slots=True, kw_only=True)
class Calibration:
    """A calibration transform after orthonormalisation, and the residual of the published rotation."""

    transform: Transform
    residual: float


def read_calibration(path: Source, offset_xy: tuple[float, float] = (0.0, 0.0)) -> Calibration:
    """``<second>_T_<first>`` from a DAIR calibration JSON (``first_to_second``), translation + offset.

    Raises:
        InputError: missing file or fields, bad shapes, non-finite values, or a rotation farther from
            orthonormal than ``REPAIR_TOLERANCE`` (names the file, the field and the residual).
    """
    data = read_json(path)
    if isinstance(data, dict) and isinstance(data.get("transform"), dict):
        data = data["transform"]
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a JSON object with rotation and translation, got {type(data).__name__}")
    rotation = _matrix(data.get("rotation"), (3, 3), path, "rotation")
    translation = _matrix(data.get("translation"), (3, 1), path, "translation").reshape(3)
    translation = translation + np.array([offset_xy[0], offset_xy[1], 0.0])
    # The warning (residual beyond float noise) is the caller's: it knows which extrinsic this is.
    repaired, _ = repaired_rotation(rotation, f"{path}: field rotation")
    return Calibration(transform=Transform(rotation=repaired, translation=translation),
                       residual=float(rotation_deviation(rotation)))


#: The distortion model of ``cam_D``: five coefficients k1, k2, p1, p2, k3 (ROS CameraInfo's ``D``).
DISTORTION_MODEL = "plumb_bob"


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraIntrinsic:
    """A DAIR ``calib/camera_intrinsic`` file.

    Attributes:
        K: (3, 3) ``cam_K``, pixels.
        D: (5,) ``cam_D``: k1, k2, p1, p2, k3 of :data:`DISTORTION_MODEL`.
    """

    K: np.ndarray
    D: np.ndarray


def read_camera_intrinsic(path: Source) -> CameraIntrinsic:
    """``cam_K`` and ``cam_D`` of a DAIR camera intrinsic JSON.

    Raises:
        InputError: missing file or fields, wrong shapes, non-finite values, values beyond
            ``MAX_CAMERA_VALUE_PX``, or a K that is not upper triangular with focal lengths > 0 and
            last row (0, 0, 1) (names the file, the field and the value).
    """
    data = read_json(path)
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a JSON object with cam_K and cam_D, got {type(data).__name__}")
    K = _matrix(data.get("cam_K"), (3, 3), path, "cam_K")
    D = _matrix(data.get("cam_D"), (5,), path, "cam_D")
    if not (K[0, 0] > 0.0 and K[1, 1] > 0.0 and K[1, 0] == K[2, 0] == K[2, 1] == 0.0 and K[2, 2] == 1.0):
        raise InputError(f"{path}: field cam_K: expected [fx, s, cx, 0, fy, cy, 0, 0, 1] with fx, fy > 0, "
                         f"got {K.ravel().tolist()}")
    for field, values in (("cam_K", K), ("cam_D", D)):
        if np.abs(values).max() > MAX_CAMERA_VALUE_PX:
            raise InputError(f"{path}: field {field}: expected values within {MAX_CAMERA_VALUE_PX:g}, "
                             f"got {values.ravel().tolist()}")
    return CameraIntrinsic(K=K, D=D)


def _matrix(value: Any, shape: tuple[int, ...], path: Source, field: str) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{path}: field {field}: expected numbers, got {value!r:.80}") from None
    if array.size == math.prod(shape) and array.shape != shape:
        array = array.reshape(shape)  # a translation written as a flat [x, y, z], a flat cam_K
    if value is None or array.shape != shape or not np.all(np.isfinite(array)):
        raise InputError(f"{path}: field {field}: expected finite numbers of shape {shape}, got {value!r:.80}")
    return array


@dataclass(frozen=True, slots=True, kw_only=True)
class Labels3D:
    """DAIR 3D labels of one file, as arrays (N objects).

    Attributes:
        source_classes: (N,) ``type`` strings.
        center: (N, 3) ``3d_location`` (box centre) in the file's frame.
        size_lwh: (N, 3) from ``3d_dimensions`` {l, w, h}.
        yaw_rad: (N,) ``rotation`` about z.
    """

    source_classes: np.ndarray
    center: np.ndarray
    size_lwh: np.ndarray
    yaw_rad: np.ndarray


def read_labels(path: Source) -> tuple[Labels3D, list[str]]:
    """The labels that parse and one error line per entry that does not, or repeats an earlier one exactly."""
    data = read_json(path)
    if not isinstance(data, list):
        raise InputError(f"{path}: expected a JSON list of objects, got {type(data).__name__}")
    rows = []
    errors = []
    first_index: dict[tuple[str | float, ...], int] = {}
    for index, entry in enumerate(data):
        try:
            location = entry["3d_location"]
            dims = entry["3d_dimensions"]
            center = [float(location[k]) for k in "xyz"]
            size = [float(dims[k]) for k in "lwh"]
            yaw = float(entry["rotation"])
            kind = str(entry["type"])
        except (KeyError, TypeError, ValueError) as error:
            errors.append(f"{path}: object [{index}]: expected type, 3d_location, 3d_dimensions and rotation, "
                          f"got {type(error).__name__} {error}")
            continue
        # The scene writer's limits (beyond them it refused the whole frame), and yaws within two turns (DAIR's are
        # within +-pi, world labels add the vehicle's heading): 1e308 gave a box of arbitrary heading.
        sizes = np.asarray(size)  # numpy, not min/max: those skip a NaN depending on where it is
        if not (np.all(np.abs(center) <= MAX_COORDINATE_M) and np.all((sizes > 0.0) & (sizes <= MAX_BOX_SIZE_M))
                and abs(yaw) <= MAX_ANGLE_RAD):
            errors.append(f"{path}: object [{index}]: expected finite values within {MAX_COORDINATE_M:g} m, dimensions "
                          f"in (0, {MAX_BOX_SIZE_M:g}] m and a rotation within +-{MAX_ANGLE_RAD:.4g} rad (two turns), "
                          f"got location {center}, dimensions lwh {size}, rotation {yaw}")
            continue
        key: tuple[str | float, ...] = (kind, *center, *size, yaw)
        if key in first_index:  # a copied entry, not a second object at the same place
            errors.append(f"{path}: object [{index}]: expected one entry per object, got the same as object "
                          f"[{first_index[key]}]; dropped")
            continue
        first_index[key] = index
        rows.append((kind, center, size, yaw))
    n = len(rows)
    return Labels3D(
        source_classes=np.asarray([r[0] for r in rows], dtype=str).reshape(n),
        center=np.asarray([r[1] for r in rows], dtype=np.float64).reshape(n, 3),
        size_lwh=np.asarray([r[2] for r in rows], dtype=np.float64).reshape(n, 3),
        yaw_rad=np.asarray([r[3] for r in rows], dtype=np.float64).reshape(n),
    ), errors


def unified_class(source_class: str) -> str:
    """The unified class of a DAIR ``type`` (``other`` when unmapped)."""
    return CLASS_MAP.get(source_class.lower(), "other")
