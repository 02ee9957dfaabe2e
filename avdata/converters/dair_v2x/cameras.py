"""DAIR-V2X-C cameras: each side's image and its calibration files, read and checked."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from avdata.converters.base import Report
from avdata.converters.dair_v2x.pairs import SIDES, Pair, Side, frame_id, warn_residual
from avdata.errors import InputError
from avdata.frames import Transform
from avdata.inputs import Source, is_present, read_regular_file
from avdata.sources.dair_v2x import CameraIntrinsic, read_calibration, read_camera_intrinsic
from avdata.sources.jpeg import jpeg_problem


@dataclass(frozen=True, slots=True, kw_only=True)
class Camera:
    """One side's camera, read and checked before the scene opens (its ``/tf_static`` entry goes first)."""

    frame: str
    lidar: str
    source: str
    lidar_T_camera: Transform
    #: the extrinsic's name in the metadata's ``calibration_residuals`` and its residual there
    calibration: str
    calibration_path: Source
    residual: float
    intrinsic: CameraIntrinsic
    image: bytes
    width: int
    height: int
    time_ns: int


def declared_cameras(root: Source, pairs: list[Pair]) -> dict[str, Camera]:
    """Per camera frame, the first pair's camera that reads: its size and mount are the scene's declaration.

    Its problems are reported when each pair's camera is read again for writing (``_write_pair``).
    """
    cameras: dict[str, Camera] = {}
    quiet = Report("", strict=False)
    for side in SIDES:
        for pair in pairs:
            camera = read_camera(root, side, pair, quiet)
            if camera is not None:
                cameras[camera.frame] = camera
                break
    return cameras


def read_camera(root: Source, side: Side, pair: Pair, report: Report) -> Camera | None:
    """One side's image and calibration, checked; None (reported) when the camera cannot be converted."""
    frame = f"{side.agent}/camera"
    image_rel = pair.entry.get(side.image_field)
    row = pair.rows[side.name]
    if not (isinstance(image_rel, str) and image_rel):
        report.warn(pair.entry["_file"], f"field {side.image_field}: expected a relative path, got {image_rel!r:.80}; "
                                   f"camera {frame} not converted")
        return None
    image_path = root / image_rel
    if not is_present(image_path):  # a folder or FIFO there is an error below
        report.warn(image_path, f"image missing: camera {frame} not converted")
        return None
    try:
        image = read_regular_file(image_path)  # a FIFO is refused, not waited on
    except OSError as error:
        report.error(image_path, f"cannot read ({error.strerror or error}); camera {frame} not converted")
        return None
    except InputError as error:
        report.error(image_path, f"{error}; camera {frame} not converted")
        return None
    problem, (width, height) = jpeg_problem(image)
    if problem is not None:
        report.error(image_path, f"{problem}; camera {frame} not converted")
        return None
    try:
        intrinsic_path, extrinsic_path = _camera_files(root / side.folder, side, image_rel, row)
    except InputError as error:
        report.error(root / side.folder / "data_info.json", f"{error}; camera {frame} not converted")
        return None
    try:
        intrinsic = read_camera_intrinsic(intrinsic_path)
    except InputError as error:
        report.error(intrinsic_path, f"{error}; camera {frame} not converted")
        return None
    try:
        camera_T_lidar = read_calibration(extrinsic_path)
    except InputError as error:
        report.error(extrinsic_path, f"{error}; camera {frame} not converted")
        return None
    warn_residual(report, extrinsic_path, camera_T_lidar)
    # DAIR's lidar_to_camera maps lidar points into the camera (camera_T_lidar); /tf_static wants the
    # camera's pose in the lidar.
    return Camera(frame=frame, lidar=f"{side.agent}/lidar", source=image_rel,
                   lidar_T_camera=camera_T_lidar.transform.inverse(), calibration=f"{side.name} {side.extrinsic}",
                   calibration_path=extrinsic_path, residual=camera_T_lidar.residual, intrinsic=intrinsic, image=image,
                   width=width, height=height, time_ns=pair.image_time_ns(side))


def _camera_files(side_root: Source, side: Side, image_rel: str, row: dict[str, Any] | None) -> tuple[Source, Source]:
    """(camera_intrinsic, [virtual]lidar_to_camera) files: as the side's row names them, else by frame id.

    Raises:
        InputError: the row names another image than the pair, or a calibration path that is not a string.
    """
    image_frame = frame_id(image_rel)
    files = {"calib_camera_intrinsic_path": f"calib/camera_intrinsic/{image_frame}.json",
             f"calib_{side.extrinsic}_path": f"calib/{side.extrinsic}/{image_frame}.json"}
    if row is not None:
        where = f"{side_root / 'data_info.json'}: frame {frame_id(str(row.get('pointcloud_path')))}"
        named = row.get("image_path", image_rel.removeprefix(f"{side.folder}/"))
        if not (isinstance(named, str) and Path(side.folder, named) == Path(image_rel)):
            raise InputError(f"{where}: field image_path: expected {image_rel.removeprefix(side.folder + '/')!r} "
                             f"(the pair's {side.image_field}), got {named!r:.80}")
        files = {field: row.get(field, default) for field, default in files.items()}
        for field, value in files.items():
            if not (isinstance(value, str) and value):
                raise InputError(f"{where}: field {field}: expected a relative path, got {value!r:.80}")
    intrinsic, extrinsic = files.values()
    return side_root / intrinsic, side_root / extrinsic
