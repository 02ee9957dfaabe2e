"""What the three KITTI converters share: label conversion, sensor declarations (classes: ``sources.kitti.classes``)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from avdata.converters.base import Converter, ConverterOptions, Report
from avdata.errors import InputError
from avdata.frames import Boxes3D, Transform
from avdata.inputs import Source, read_regular_file
from avdata.schema import ObjectLabels, SceneWriter, VisibilityLabels
from avdata.sources.kitti import DONT_CARE, KittiCalib, KittiLabels, geometry, read_velodyne, unified_classes
from avdata.sources.png import png_problem

PERIOD_NS = 100_000_000
LICENCE = "CC BY-NC-SA 3.0 (KITTI Vision Benchmark Suite)"


@dataclass(frozen=True, slots=True, kw_only=True)
class KittiOptions(ConverterOptions):
    """Options of every KITTI converter."""

    decode_images: bool = field(default=False, metadata={
        "help": "fully decode every PNG to check it (default: check signature, header and end)"})


class KittiConverter(Converter):
    """What the three KITTI converters share: the licence and the image-check option."""

    licence = LICENCE
    Options = KittiOptions
AGENT = "ego"

#: Tracklet / tracking levels mapped onto the unified occlusion scale (0 none, 1 partly, 2 largely,
#: 3 fully or unknown). KITTI object and tracking already use 0..3 with the same meaning.
RAW_OCCLUSION = {-1: 3, 0: 0, 1: 1, 2: 3}


def add_png(scene: SceneWriter, sensor_frame: str, time_ns: int, path: Source, report: Report, record: str) -> bool:
    """Writes one KITTI PNG after checking it whole (every chunk's CRC); a damaged one is reported and left out.

    The first pass read only each image's header and trailer (for the camera sizes); the bytes read here
    to be written are checked in full, so a damaged byte anywhere costs that image, and ``record`` (e.g.
    "frame 12") is written without it.

    Returns:
        Whether the image was written.
    """
    try:
        data = read_regular_file(path)
    except InputError as error:  # replaced by a FIFO since the first pass read its header
        report.error(path, f"{error}; {record} written without it")
        return False
    except OSError as error:  # removed or replaced by a folder since then
        report.error(path, f"cannot read ({error.strerror or error}); {record} written without it")
        return False
    problem, _ = png_problem(data)
    if problem is not None:
        report.error(path, f"{problem}; {record} written without it")
        return False
    scene.add_image(sensor_frame, time_ns, data, "png")
    return True


def add_velodyne(scene: SceneWriter, sensor_frame: str, time_ns: int, path: Source, report: Report, record: str) -> bool:
    """Writes one velodyne scan; a damaged one is reported and left out, ``record`` written without it.

    Damaged: not a whole number of points, or a value no lidar measures (a damaged float; see
    :func:`~avdata.sources.kitti.read_velodyne`). ``record`` names what is written without it, e.g. "frame 12".

    Returns:
        Whether the scan was written.
    """
    try:
        points = read_velodyne(path)
    except InputError as error:
        report.error(path, f"{error}; {record} written without it")
        return False
    scene.add_point_cloud(sensor_frame, time_ns, points)
    return True


def report_calib_warnings(report: Report, calib: KittiCalib) -> None:
    """Passes on the calibration's repairs beyond float noise (each names its file and key)."""
    for file, message in calib.warnings:
        report.warn(file, message)


def frame_ranges(frames: list[int]) -> str:
    """Sorted frame numbers as ranges: [1, 2, 3, 7] -> "1-3, 7"."""
    values = np.unique(np.asarray(frames, dtype=np.int64))
    breaks = np.flatnonzero(np.diff(values) != 1) + 1
    runs = np.split(values, breaks) if len(values) else []
    return ", ".join(f"{run[0]}" if len(run) == 1 else f"{run[0]}-{run[-1]}" for run in runs)


def sensor(name: str) -> str:
    """``ego/<name>``."""
    return f"{AGENT}/{name}"


def camera_size(image_size: dict[int, tuple[int, int]], camera: int) -> tuple[int, int] | None:
    """(width, height) of rectified ``camera``, or None when no image size is known.

    KITTI crops the four rectified images of a drive to one size (raw ``S_rect_00..03`` are equal), so
    a camera without images of its own (cam0, cam1; cam3 without ``image_3``) has the size of any other.
    """
    if camera in image_size:
        return image_size[camera]
    return image_size[min(image_size)] if image_size else None


def declare_sensors(scene: SceneWriter, cameras: list[int], image_size: dict[int, tuple[int, int]]) -> None:
    """Declares the velodyne and the given cameras of the ego agent in the scene metadata."""
    scene.add_sensor(sensor(geometry.VELODYNE), kind="lidar", model="Velodyne HDL-64E", beams=64, rate_hz=10.0,
                     fields="x, y, z, intensity (float32, KITTI reflectance 0..1)")
    for i in cameras:
        size = camera_size(image_size, i)
        dims = {} if size is None else {"width": size[0], "height": size[1]}
        scene.add_sensor(sensor(geometry.camera_frame(i)), kind="camera", rate_hz=10.0, **dims,
                         model=("PointGrey Flea2 FL2-14S3M (grey)" if i < 2 else "PointGrey Flea2 FL2-14S3C (colour)"),
                         rectified=True)


def source_calibration(calib: KittiCalib) -> dict[str, list[float]]:
    """The calibration's matrices as KITTI printed them (row-major), for scene metadata and exact export."""
    matrices = {f"P{i}": calib.P[i] for i in range(4)}
    matrices.update(R0_rect=calib.R0_rect, Tr_velo_to_cam=calib.velo_to_cam)
    if calib.imu_to_velo is not None:
        matrices["Tr_imu_to_velo"] = calib.imu_to_velo
    return {key: [float(v) for v in matrix.ravel()] for key, matrix in matrices.items()}


#: The empty distortion and identity rectification of KITTI's rectified cameras (read-only, shared).
_NO_DISTORTION = np.zeros(0)
_IDENTITY_3X3 = np.eye(3)
_NO_DISTORTION.flags.writeable = False
_IDENTITY_3X3.flags.writeable = False
#: :func:`_calibration_messages` by calibration and ego_T_velo: the samples of KITTI object share a
#: few calibrations, and composing the poses again cost more than writing them.
_MESSAGES_BY_CALIB: dict[bytes, tuple[dict[str, Transform], list[tuple[np.ndarray, np.ndarray]]]] = {}
_MESSAGES_CACHE_SIZE = 256


def _calibration_messages(calib: KittiCalib, velo_T_sensors: dict[str, Transform], ego_T_velo: Transform,
                          ) -> tuple[dict[str, Transform], list[tuple[np.ndarray, np.ndarray]]]:
    """({sensor name: ego_T_sensor}, [(K_i, [K_i | 0]) for cameras 0..3]) of a calibration, cached."""
    key = (geometry.calibration_key(calib) + b"|" + ego_T_velo.rotation.tobytes()
           + ego_T_velo.translation.tobytes())
    messages = _MESSAGES_BY_CALIB.get(key)
    if messages is None:
        if len(_MESSAGES_BY_CALIB) >= _MESSAGES_CACHE_SIZE:
            _MESSAGES_BY_CALIB.clear()
        poses = {name: ego_T_velo @ velo_T_sensor for name, velo_T_sensor in velo_T_sensors.items()}
        intrinsics = []
        for i in range(4):
            K = geometry.intrinsics(calib, i)
            P = np.hstack([K, np.zeros((3, 1))])
            K.flags.writeable = False
            P.flags.writeable = False
            intrinsics.append((K, P))
        messages = _MESSAGES_BY_CALIB[key] = (poses, intrinsics)
    return messages


def write_calibration(scene: SceneWriter, time_ns: int, calib: KittiCalib, ego_T_velo: Transform,
                      cameras: list[int], image_size: dict[int, tuple[int, int]], stamped: bool) -> dict[str, Transform]:
    """Writes every sensor pose below ``ego`` and each camera's CameraCalibration at ``time_ns``.

    The frames: ``ego/velodyne``, ``ego/cam0_unrectified`` (camera 0 before ``R0_rect``, kept so that
    ``R0_rect`` and ``Tr_velo_to_cam`` can be exported separately), ``ego/cam0..cam3`` (rectified,
    optical), and ``ego/imu`` when the calibration has ``Tr_imu_to_velo`` and ego is not the IMU.

    Each camera frame sits at that camera's own optical centre (``cam_i_T_cam0 = (I, t_i)``), so its
    CameraCalibration's ``P`` is ``[K_i | 0]``: a ROS / Foxglove pinhole model projecting points of
    the calibration's ``frame_id`` (``u = (fx x + Tx) / z + cx``, Tx = 0) lands where KITTI's
    ``P_i · R0_rect · Tr_velo_to_cam`` does. KITTI's own ``P_i`` (4th column = K_i t_i, the baseline to
    camera 0) is kept in the scene metadata (:func:`source_calibration`). A camera whose image size is
    unknown (no image of any camera in the sample) gets no CameraCalibration: Foxglove rejects 0x0.

    Args:
        scene: the scene writer.
        time_ns: the time of the calibration (the sample's time).
        calib: the parsed calibration file.
        ego_T_velo: the velodyne's pose in the ego body frame.
        cameras: the camera indices (0-3) to write.
        image_size: (width, height) of each camera's images.
        stamped: write the camera poses on ``/tf`` at ``time_ns`` (KITTI object: every sample has its
            own calibration) instead of ``/tf_static``.

    Returns:
        :func:`geometry.velo_T_sensors` of the calibration (the poses in the velodyne frame), for reuse.
    """
    velo_T_sensors = geometry.velo_T_sensors(calib)
    poses, intrinsics = _calibration_messages(calib, velo_T_sensors, ego_T_velo)
    for name, ego_T_sensor in poses.items():
        if not stamped:
            if name != geometry.IMU:  # tracking and raw: ego is the IMU itself
                scene.add_static_transform(AGENT, sensor(name), ego_T_sensor)
        else:
            scene.add_transform(AGENT, sensor(name), time_ns, ego_T_sensor)
    for i in cameras:
        size = camera_size(image_size, i)
        if size is None:
            continue
        K, P = intrinsics[i]
        scene.add_camera_calibration(sensor(geometry.camera_frame(i)), time_ns, K, size[0], size[1], D=_NO_DISTORTION,
                                     R=_IDENTITY_3X3, P=P)
    return velo_T_sensors


def camera_labels(frames: list[tuple[KittiLabels, np.ndarray, Transform]], tracking: bool,
                  extras: list[dict[str, float]] | None = None) -> list[tuple[ObjectLabels, VisibilityLabels]]:
    """Each frame's label lines as objects in ``world`` and camera 2 visibility.

    The boxes of frames with the same ``world_T_cam0`` (KITTI object: the samples of one calibration)
    are converted and moved in one batch: each step works row by row (the matrix products one box at
    a time, the rotations as element-wise arithmetic), so a box gets the bits it gets on its own,
    without the per-call cost of a few boxes per frame.

    Args:
        frames: per frame (its rows, DontCare included: they become ignore regions; (N,) object ids
            for the rows, DontCare rows' unused; world_T_cam0: rectified camera 0 in ``world`` at
            the frame's time).
        tracking: truncation is a level 0/1/2 (tracking) rather than a fraction (object).
        extras: per frame, added to every object's extras after ``kitti_label_line`` (KITTI object:
            ``kitti_sample``); None adds nothing.

    Returns:
        Per frame, in order: (objects, visibility).
    """
    groups: dict[tuple[bytes, bytes], list[int]] = {}
    for i, (_, _, world_T_cam0) in enumerate(frames):
        groups.setdefault((world_T_cam0.rotation.tobytes(), world_T_cam0.translation.tobytes()), []).append(i)
    results: dict[int, tuple[ObjectLabels, VisibilityLabels]] = {}
    for members in groups.values():
        cares = [frames[i][0].cls != DONT_CARE for i in members]
        objects = [frames[i][0].select(care) for i, care in zip(members, cares, strict=True)]
        ids = [np.asarray(frames[i][1], dtype=str)[care] for i, care in zip(members, cares, strict=True)]
        hwl, location, rotation_y, cls = (np.concatenate([getattr(o, name) for o in objects])
                                          for name in ("hwl", "location", "rotation_y", "cls"))
        boxes_cam0 = Boxes3D.from_kitti_camera(hwl, location, rotation_y, sensor("cam0"), ids=np.concatenate(ids),
                                               classes=unified_classes(cls))
        pieces = boxes_cam0.transform(frames[members[0]][2], "world").split([len(o) for o in objects])
        for i, care, frame_objects, frame_ids, boxes in zip(members, cares, objects, ids, pieces, strict=True):
            labels = frames[i][0]
            frame_extras = extras[i] if extras is not None else {}
            object_extras = [{"kitti_label_line": float(line), **frame_extras} for line in frame_objects.line.tolist()]
            truncation = frame_objects.truncated.astype(np.float32)
            if tracking:
                for extra, level in zip(object_extras, frame_objects.truncated.tolist(), strict=True):
                    extra["kitti_truncation_level"] = level
                truncation = np.where(frame_objects.truncated == 0, 0.0, np.nan).astype(np.float32)
            visibility = VisibilityLabels(
                object_ids=frame_ids,
                in_fov=np.ones(len(frame_objects), dtype=bool),
                occlusion=np.clip(frame_objects.occluded, 0, 3),
                truncation=truncation,
                box2d_xyxy=frame_objects.bbox,
                alpha_rad=frame_objects.alpha,
                ignore_regions_xyxy=labels.bbox[~care],
            )
            results[i] = (ObjectLabels(boxes=boxes, source_classes=frame_objects.cls, extras=object_extras), visibility)
    return [results[i] for i in range(len(frames))]
