"""Readers of KITTI's published text and binary files (object, tracking and raw layouts).

Every reader either returns arrays or raises :class:`InputError` naming the file, the line and the
value; nothing is guessed. Per-frame problems (a bad label line) are reported by the converters,
which decide whether a frame or a scene is skipped.
"""

from __future__ import annotations

import datetime as dt
import os
import struct
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from avdata.errors import InputError

#: KITTI velodyne scans: little-endian float32 x, y, z, reflectance; 16 bytes per point.
VELODYNE_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])

#: Tracking calib files name three matrices differently and drop the colons.
_CALIB_ALIASES = {"R_rect": "R0_rect", "Tr_velo_cam": "Tr_velo_to_cam", "Tr_imu_velo": "Tr_imu_to_velo"}
_CALIB_SIZES = {"P0": 12, "P1": 12, "P2": 12, "P3": 12, "R0_rect": 9, "Tr_velo_to_cam": 12, "Tr_imu_to_velo": 12}

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_IEND = b"\x00\x00\x00\x00IEND\xaeB`\x82"

#: Label columns after the class (object) or frame, track id and class (tracking).
_BOX_FIELDS = 14


@dataclass(frozen=True, slots=True, kw_only=True)
class KittiCalib:
    """One calibration set, as KITTI prints it (matrices not yet orthonormalised).

    Attributes:
        P: (4, 3, 4) projection matrices P0..P3 of the rectified cameras, for points in rectified camera 0.
        R0_rect: (3, 3) rectifying rotation: rectified cam 0 <- unrectified cam 0.
        velo_to_cam: (3, 4) unrectified cam 0 <- velodyne (``Tr_velo_to_cam``).
        imu_to_velo: (3, 4) velodyne <- IMU (``Tr_imu_to_velo``), or None if the file has none.
        image_size: (4, 2) rectified width, height per camera from raw ``S_rect_0i``, or None.
    """

    P: np.ndarray
    R0_rect: np.ndarray
    velo_to_cam: np.ndarray
    imu_to_velo: np.ndarray | None
    image_size: np.ndarray | None = None


def _parse_key_values(path: Path) -> dict[str, tuple[int, list[str]]]:
    """key -> (line number, values) of a ``key: v v v`` or ``key v v v`` file."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(f"{path}: unreadable ({error})") from error
    entries: dict[str, tuple[int, list[str]]] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        parts = line.replace(":", ": ", 1).split()
        if not parts:
            continue
        entries[parts[0].rstrip(":")] = (number, parts[1:])
    return entries


def _floats(path: Path, key: str, entry: tuple[int, list[str]], count: int) -> np.ndarray:
    number, values = entry
    if len(values) != count:
        raise InputError(f"{path}: line {number}: expected {count} values for {key}, got {len(values)}")
    try:
        return np.array([float(v) for v in values], dtype=np.float64)
    except ValueError as error:
        raise InputError(f"{path}: line {number}: {key}: expected numbers, got {' '.join(values)!r}") from error


def read_calib(path: Path) -> KittiCalib:
    """Reads an object (``calib/000000.txt``) or tracking (``calib/0001.txt``) calibration file.

    Raises:
        InputError: the file is missing or unreadable, a key is missing, or a value is malformed.
    """
    if not path.is_file():
        raise InputError(f"{path}: calibration file missing")
    entries = {_CALIB_ALIASES.get(key, key): entry for key, entry in _parse_key_values(path).items()}
    missing = [key for key in _CALIB_SIZES if key != "Tr_imu_to_velo" and key not in entries]
    if missing:
        raise InputError(f"{path}: expected keys P0..P3, R0_rect (R_rect), Tr_velo_to_cam (Tr_velo_cam); "
                         f"missing {missing}")
    values = {key: _floats(path, key, entries[key], size) for key, size in _CALIB_SIZES.items() if key in entries}
    return KittiCalib(
        P=np.stack([values[f"P{i}"].reshape(3, 4) for i in range(4)]),
        R0_rect=values["R0_rect"].reshape(3, 3),
        velo_to_cam=values["Tr_velo_to_cam"].reshape(3, 4),
        imu_to_velo=values["Tr_imu_to_velo"].reshape(3, 4) if "Tr_imu_to_velo" in values else None,
    )


def read_raw_calib(date_dir: Path) -> KittiCalib:
    """Reads a raw recording day's ``calib_cam_to_cam.txt``, ``calib_velo_to_cam.txt``, ``calib_imu_to_velo.txt``."""
    cam_path = date_dir / "calib_cam_to_cam.txt"
    velo_path = date_dir / "calib_velo_to_cam.txt"
    imu_path = date_dir / "calib_imu_to_velo.txt"
    for path in (cam_path, velo_path, imu_path):
        if not path.is_file():
            raise InputError(f"{path}: calibration file missing")
    cam = _parse_key_values(cam_path)
    needed = [f"{k}_0{i}" for i in range(4) for k in ("P_rect", "S_rect")] + ["R_rect_00"]
    missing = [key for key in needed if key not in cam]
    if missing:
        raise InputError(f"{cam_path}: expected keys P_rect_0i, S_rect_0i, R_rect_00; missing {missing}")

    def rigid(path: Path) -> np.ndarray:
        entries = _parse_key_values(path)
        for key in ("R", "T"):
            if key not in entries:
                raise InputError(f"{path}: expected keys R and T, missing {key}")
        return np.hstack([_floats(path, "R", entries["R"], 9).reshape(3, 3), _floats(path, "T", entries["T"], 3)[:, None]])

    return KittiCalib(
        P=np.stack([_floats(cam_path, f"P_rect_0{i}", cam[f"P_rect_0{i}"], 12).reshape(3, 4) for i in range(4)]),
        R0_rect=_floats(cam_path, "R_rect_00", cam["R_rect_00"], 9).reshape(3, 3),
        velo_to_cam=rigid(velo_path),
        imu_to_velo=rigid(imu_path),
        image_size=np.stack([_floats(cam_path, f"S_rect_0{i}", cam[f"S_rect_0{i}"], 2) for i in range(4)]).astype(int),
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class KittiLabels:
    """Label lines as columns (N rows, DontCare included).

    Attributes:
        line: (N,) 1-based line numbers in the file.
        frame: (N,) frame numbers (tracking), or all -1 (object).
        track_id: (N,) track ids (tracking; -1 for DontCare), or all -1 (object).
        cls: (N,) KITTI class strings, verbatim.
        truncated: (N,) object: fraction 0..1; tracking: level 0, 1, 2.
        occluded: (N,) 0 visible, 1 partly, 2 largely occluded, 3 unknown (-1 for DontCare).
        alpha: (N,) observation angle, radians.
        bbox: (N, 4) left, top, right, bottom in pixels.
        hwl: (N, 3) height, width, length in metres.
        location: (N, 3) bottom centre in rectified camera 0, metres.
        rotation_y: (N,) rotation about camera y, radians.
    """

    line: np.ndarray
    frame: np.ndarray
    track_id: np.ndarray
    cls: np.ndarray
    truncated: np.ndarray
    occluded: np.ndarray
    alpha: np.ndarray
    bbox: np.ndarray
    hwl: np.ndarray
    location: np.ndarray
    rotation_y: np.ndarray

    def __len__(self) -> int:
        return int(self.line.shape[0])

    def select(self, mask: np.ndarray) -> KittiLabels:
        """The rows where ``mask`` (N,) is true."""
        return KittiLabels(**{name: getattr(self, name)[mask] for name in self.__slots__})


@dataclass(frozen=True, slots=True, kw_only=True)
class LabelProblem:
    """A label line that cannot be read: its line number, frame (tracking, -1 unknown) and why."""

    line: int
    frame: int
    message: str


def read_labels(path: Path, tracking: bool) -> tuple[KittiLabels, list[LabelProblem]]:
    """Reads ``label_2/000000.txt`` (object, 15 fields; 16 with a score) or ``label_02/0001.txt``
    (tracking, 17 fields; 18 with a score).

    Returns:
        The readable lines as columns, and one problem per unreadable line.
    """
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(f"{path}: unreadable ({error})") from error
    lead = 3 if tracking else 1
    expected = lead + _BOX_FIELDS
    rows: list[tuple[int, int, int, str, list[float]]] = []
    problems: list[LabelProblem] = []
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        if not fields:
            continue
        frame = -1
        if tracking:
            try:
                frame = int(fields[0])
            except ValueError:
                frame = -1
        if len(fields) not in (expected, expected + 1):
            problems.append(LabelProblem(line=number, frame=frame, message=(
                f"line {number}: expected {expected} fields ({expected + 1} with a score), got {len(fields)}")))
            continue
        try:
            numbers = [float(v) for v in fields[lead : lead + _BOX_FIELDS]]
            track = int(fields[1]) if tracking else -1
        except ValueError:
            problems.append(LabelProblem(line=number, frame=frame, message=(
                f"line {number}: expected numbers after the class, got {' '.join(fields[lead:])!r}")))
            continue
        if tracking and frame < 0:
            problems.append(LabelProblem(line=number, frame=frame, message=(
                f"line {number}: expected a non-negative frame number, got {fields[0]!r}")))
            continue
        rows.append((number, frame, track, fields[lead - 1], numbers))
    values = np.array([r[4] for r in rows], dtype=np.float64).reshape(-1, _BOX_FIELDS)
    labels = KittiLabels(
        line=np.array([r[0] for r in rows], dtype=np.int64),
        frame=np.array([r[1] for r in rows], dtype=np.int64),
        track_id=np.array([r[2] for r in rows], dtype=np.int64),
        cls=np.array([r[3] for r in rows], dtype=str),
        truncated=values[:, 0],
        occluded=values[:, 1].astype(np.int64),
        alpha=values[:, 2],
        bbox=values[:, 3:7],
        hwl=values[:, 7:10],
        location=values[:, 10:13],
        rotation_y=values[:, 13],
    )
    return labels, problems


def read_oxts_lines(path: Path, lines: list[str]) -> np.ndarray:
    """(T, 30) oxts packets from text lines (lat, lon, alt, roll, pitch, yaw, vn, ve, vf, ...)."""
    out = np.empty((len(lines), 30), dtype=np.float64)
    for i, line in enumerate(lines):
        fields = line.split()
        if len(fields) != 30:
            raise InputError(f"{path}: line {i + 1}: expected 30 oxts values, got {len(fields)}")
        try:
            out[i] = [float(v) for v in fields]
        except ValueError as error:
            raise InputError(f"{path}: line {i + 1}: expected numbers, got {line.strip()!r}") from error
    return out


def read_timestamps(path: Path) -> np.ndarray:
    """(T,) int64 ns from a raw ``timestamps.txt`` ("2011-09-26 13:02:25.967790592"), read exactly.

    The files carry no time zone; they are read as UTC.
    """
    try:
        lines = [line.strip() for line in path.read_text().splitlines() if line.strip()]
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(f"{path}: unreadable ({error})") from error
    out = np.empty(len(lines), dtype=np.int64)
    for i, line in enumerate(lines):
        try:
            whole, _, fraction = line.partition(".")
            seconds = dt.datetime.strptime(whole, "%Y-%m-%d %H:%M:%S").replace(tzinfo=dt.timezone.utc).timestamp()
            if not fraction.isdigit() or len(fraction) > 9:
                raise ValueError(fraction)
        except ValueError as error:
            raise InputError(f"{path}: line {i + 1}: expected 'YYYY-MM-DD HH:MM:SS.fffffffff', got {line!r}") from error
        out[i] = int(seconds) * 1_000_000_000 + int(fraction.ljust(9, "0"))
    return out


def velodyne_problem(path: Path) -> str | None:
    """Why a velodyne ``.bin`` cannot be read (None if its size is a whole number of points)."""
    size = os.stat(path).st_size
    if size % VELODYNE_DTYPE.itemsize:
        return f"expected a size that is a multiple of 16 bytes (x, y, z, reflectance float32), got {size} bytes"
    return None


def read_velodyne(path: Path) -> np.ndarray:
    """(N,) structured float32 x, y, z, intensity, the file's bytes unchanged."""
    return np.fromfile(path, dtype=VELODYNE_DTYPE)


def png_size(path: Path, decode: bool = False) -> tuple[int, int]:
    """(width, height) of a PNG after checking it is whole.

    Without ``decode`` the check reads 33 bytes and the last 12: the signature, the IHDR chunk and
    the IEND trailer (a truncated or non-PNG file fails); with ``decode`` the image is decoded.

    Raises:
        InputError: the file is not a complete PNG.
    """
    with open(path, "rb") as stream:
        head = stream.read(33)
        stream.seek(0, os.SEEK_END)
        size = stream.tell()
        stream.seek(max(size - 12, 0))
        tail = stream.read(12)
    if len(head) < 33 or head[:8] != _PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise InputError(f"{path}: expected a PNG file (signature and IHDR chunk), got {head[:16]!r}")
    if tail != _PNG_IEND:
        raise InputError(f"{path}: expected a PNG ending in an IEND chunk, got {tail!r} (truncated file?)")
    width, height = struct.unpack(">II", head[16:24])
    if decode and _imdecode(np.fromfile(path, dtype=np.uint8)) is None:
        raise InputError(f"{path}: PNG does not decode")
    return int(width), int(height)


@dataclass(frozen=True, slots=True, kw_only=True)
class Tracklets:
    """Raw ``tracklet_labels.xml``, one row per (tracklet, frame) pose.

    Attributes:
        frame: (M,) frame numbers.
        tracklet: (M,) tracklet index in the file (the object id).
        cls: (M,) objectType, verbatim.
        hwl: (M, 3) height, width, length in metres.
        translation: (M, 3) box bottom centre in the velodyne frame, metres.
        rotation: (M, 3) rx, ry, rz in radians (rz is the yaw about velodyne z).
        occlusion: (M,) -1 unset, 0 visible, 1 partly, 2 fully occluded.
        truncation: (M,) -1 unset, 0 in image, 1 truncated, 2 out of image, 99 behind image.
    """

    frame: np.ndarray
    tracklet: np.ndarray
    cls: np.ndarray
    hwl: np.ndarray
    translation: np.ndarray
    rotation: np.ndarray
    occlusion: np.ndarray
    truncation: np.ndarray

    def select(self, mask: np.ndarray) -> Tracklets:
        """The rows where ``mask`` (M,) is true."""
        return Tracklets(**{name: getattr(self, name)[mask] for name in self.__slots__})


def read_tracklets(path: Path) -> Tracklets:
    """Reads a raw drive's ``tracklet_labels.xml`` (boost serialisation format of the KITTI devkit)."""
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as error:
        raise InputError(f"{path}: unreadable tracklet XML ({error})") from error
    tracklets = root.find("tracklets")
    if tracklets is None:
        raise InputError(f"{path}: expected a <tracklets> element, got none")
    rows: list[tuple] = []
    for index, item in enumerate(tracklets.findall("item")):
        try:
            cls = item.findtext("objectType", "")
            hwl = [float(item.findtext(key, "nan")) for key in ("h", "w", "l")]
            first = int(item.findtext("first_frame", "0"))
            poses = item.find("poses")
            for k, pose in enumerate([] if poses is None else poses.findall("item")):
                rows.append((
                    first + k, index, cls, hwl,
                    [float(pose.findtext(key, "nan")) for key in ("tx", "ty", "tz")],
                    [float(pose.findtext(key, "nan")) for key in ("rx", "ry", "rz")],
                    int(pose.findtext("occlusion", "-1")),
                    int(pose.findtext("truncation", "-1")),
                ))
        except ValueError as error:
            raise InputError(f"{path}: tracklet {index}: expected numbers ({error})") from error
    return Tracklets(
        frame=np.array([r[0] for r in rows], dtype=np.int64),
        tracklet=np.array([r[1] for r in rows], dtype=np.int64),
        cls=np.array([r[2] for r in rows], dtype=str),
        hwl=np.array([r[3] for r in rows], dtype=np.float64).reshape(-1, 3),
        translation=np.array([r[4] for r in rows], dtype=np.float64).reshape(-1, 3),
        rotation=np.array([r[5] for r in rows], dtype=np.float64).reshape(-1, 3),
        occlusion=np.array([r[6] for r in rows], dtype=np.int64),
        truncation=np.array([r[7] for r in rows], dtype=np.int64),
    )


def _imdecode(data: np.ndarray) -> np.ndarray | None:
    # OpenCV is imported only when images are fully decoded (--decode-images): ~16 MB otherwise unused.
    import cv2

    return cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
