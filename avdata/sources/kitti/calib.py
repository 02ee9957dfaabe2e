"""KITTI calibration files: object (``calib/000000.txt``), tracking (``calib/0001.txt``, other key names) and raw
(``calib_cam_to_cam.txt``, ``calib_velo_to_cam.txt``, ``calib_imu_to_velo.txt``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from avdata.errors import InputError

_CALIB_ALIASES = {"R_rect": "R0_rect", "Tr_velo_cam": "Tr_velo_to_cam", "Tr_imu_velo": "Tr_imu_to_velo"}
_CALIB_SIZES = {"P0": 12, "P1": 12, "P2": 12, "P3": 12, "R0_rect": 9, "Tr_velo_to_cam": 12, "Tr_imu_to_velo": 12}


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




#: The keys of an object calibration file, in the order KITTI writes them.
CALIB_KEYS = ("P0", "P1", "P2", "P3", "R0_rect", "Tr_velo_to_cam", "Tr_imu_to_velo")


def format_calib(matrices: dict[str, np.ndarray]) -> str:
    """The text of an object calibration file (``calib/000000.txt``), the inverse of :func:`read_calib`.

    Args:
        matrices: each of :data:`CALIB_KEYS` -> its matrix ((3, 4), or (3, 3) for ``R0_rect``), written
            row-major with 12 significant digits (KITTI's own files have 7).
    """
    return "".join(f"{key}: " + " ".join(f"{v:.12e}" for v in matrices[key].ravel()) + "\n" for key in CALIB_KEYS)
