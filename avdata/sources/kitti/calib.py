"""KITTI calibration files, read and checked.

Object (``calib/000000.txt``), tracking (``calib/0001.txt``, other key names) and raw
(``calib_cam_to_cam.txt``, ``calib_velo_to_cam.txt``, ``calib_imu_to_velo.txt``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from avdata.errors import InputError
from avdata.frames.rotations import repaired_rotation
from avdata.inputs import c_floats, read_text_bytes, require_file
from avdata.schema.limits import MAX_CAMERA_VALUE_PX, MAX_COORDINATE_M
from avdata.storage import Location

_CALIB_ALIASES = {"R_rect": "R0_rect", "Tr_velo_cam": "Tr_velo_to_cam", "Tr_imu_velo": "Tr_imu_to_velo"}
_CALIB_SIZES = {"P0": 12, "P1": 12, "P2": 12, "P3": 12, "R0_rect": 9, "Tr_velo_to_cam": 12, "Tr_imu_to_velo": 12}
#: Largest |entry| per key: P in pixels, a transform's translation in metres (its rotation is checked as one).
_CALIB_LIMITS = {"P0": MAX_CAMERA_VALUE_PX, "P1": MAX_CAMERA_VALUE_PX, "P2": MAX_CAMERA_VALUE_PX,
                 "P3": MAX_CAMERA_VALUE_PX, "Tr_velo_to_cam": MAX_COORDINATE_M, "Tr_imu_to_velo": MAX_COORDINATE_M}


@dataclass(frozen=True, slots=True, kw_only=True)
class KittiCalib:
    """One calibration set, as KITTI prints it (matrices not yet orthonormalized, but checked).

    Every value is finite, every P's left 3x3 block (K) is invertible, and ``R0_rect`` and the rotation
    blocks of ``Tr_*`` are rotations within the tolerance of :mod:`avdata.frames.rotations` (repairs beyond
    float noise are listed in ``warnings``).

    Attributes:
        P: (4, 3, 4) projection matrices P0..P3 of the rectified cameras, for points in rectified camera 0.
        R0_rect: (3, 3) rectifying rotation: rectified cam 0 <- unrectified cam 0.
        velo_to_cam: (3, 4) unrectified cam 0 <- velodyne (``Tr_velo_to_cam``).
        imu_to_velo: (3, 4) velodyne <- IMU (``Tr_imu_to_velo``), or None if the file has none.
        image_size: (4, 2) rectified width, height per camera from raw ``S_rect_0i``, or None.
        warnings: (file, message) per matrix repaired beyond float noise; the message names the key.
    """

    P: np.ndarray
    R0_rect: np.ndarray
    velo_to_cam: np.ndarray
    imu_to_velo: np.ndarray | None
    image_size: np.ndarray | None = None
    warnings: tuple[tuple[str, str], ...] = ()


def _read_text(path: Path | Location) -> str:
    data = read_text_bytes(path)  # a FIFO or a 10 GB file is refused before reading
    try:
        return data.decode()
    except UnicodeDecodeError as error:
        raise InputError(f"{path}: unreadable ({error})") from error


def _parse_key_values(path: Path | Location) -> dict[str, tuple[int, list[str]]]:
    """Key -> (line number, values) of a ``key: v v v`` or ``key v v v`` file."""
    return _key_values(path, _read_text(path))


def _key_values(path: Path | Location, text: str, aliases: dict[str, str] | None = None) -> dict[str, tuple[int, list[str]]]:
    """Key -> (line number, values); ``aliases`` maps other spellings to one key first.

    Raises:
        InputError: a key given twice with different values (KITTI's readers would keep one of them
            silently; which one is a guess). The same line twice is harmless.
    """
    entries: dict[str, tuple[int, list[str]]] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        parts = line.replace(":", ": ", 1).split()
        if not parts:
            continue
        spelled = parts[0].rstrip(":")
        key = (aliases or {}).get(spelled, spelled)
        previous = entries.get(key)
        if previous is not None and previous[1] != parts[1:]:
            raise InputError(f"{path}: line {number}: {spelled}: given again with different values (first on line "
                             f"{previous[0]}); expected each key once")
        entries.setdefault(key, (number, parts[1:]))
    return entries


def _floats(path: Path | Location, key: str, entry: tuple[int, list[str]], count: int,
            limit: float | None = None) -> np.ndarray:
    """The ``count`` numbers of ``key``'s line, finite and (``limit``) of magnitude <= ``limit``."""
    number, values = entry
    if len(values) != count:
        raise InputError(f"{path}: line {number}: expected {count} values for {key}, got {len(values)}")
    try:
        out = np.array(c_floats(values), dtype=np.float64)
    except ValueError as error:
        raise InputError(f"{path}: line {number}: {key}: expected numbers, got {' '.join(values)!r}") from error
    if not np.all(np.isfinite(out)):
        raise InputError(f"{path}: line {number}: {key}: expected finite numbers, got {' '.join(values)!r}")
    if limit is not None and np.max(np.abs(out)) > limit:
        # The scene writer refuses such a transform or camera too, but for the whole scene and without the file.
        big = values[int(np.argmax(np.abs(out)))]
        raise InputError(f"{path}: line {number}: {key}: expected values within {limit:g}, got {big}")
    return out


def _checked(P: np.ndarray, rotations: dict[tuple[Path | Location, str], np.ndarray],
             P_where: list[str]) -> tuple[tuple[str, str], ...]:
    """Checks each P's intrinsics and each named rotation; returns the repair warnings.

    Args:
        P: (4, 3, 4) projection matrices.
        rotations: (file, key) -> (3, 3) matrix that must be a rotation.
        P_where: "file: key" of each P.

    Raises:
        InputError: a K that is not invertible, or a matrix that is not a rotation (the rule of
            :func:`avdata.frames.rotations.repaired_rotation`).
    """
    for where, matrix in zip(P_where, P, strict=True):
        K = matrix[:, :3]
        if not (K[0, 0] > 0.0 and K[1, 1] > 0.0 and abs(np.linalg.det(K)) > 1e-9):
            raise InputError(f"{where}: expected a projection whose left 3x3 block (intrinsics K, fx > 0, fy > 0) "
                             f"is invertible, got {' '.join(f'{v:.6g}' for v in matrix.ravel())}")
    warnings = []
    for (path, key), matrix in rotations.items():
        try:
            _, warning = repaired_rotation(matrix, key)
        except InputError as error:
            raise InputError(f"{path}: {error}") from None
        if warning is not None:
            warnings.append((str(path), warning))
    return tuple(warnings)


#: Parsed and checked calibrations by file text: the object samples of one recording day have the
#: same calibration file (byte for byte), so each text is parsed and checked once per process.
_CALIB_BY_TEXT: dict[str, KittiCalib] = {}
_CALIB_CACHE_SIZE = 256


def read_calib(path: Path | Location) -> KittiCalib:
    """Reads an object (``calib/000000.txt``) or tracking (``calib/0001.txt``) calibration file.

    Raises:
        InputError: the file is missing or unreadable, a key is missing, or a value is malformed.
    """
    require_file(path, "calibration file")
    text = _read_text(path)
    calib = _CALIB_BY_TEXT.get(text)
    if calib is None:
        calib = _parse_calib(path, text)
        for matrix in (calib.P, calib.R0_rect, calib.velo_to_cam, calib.imu_to_velo):
            if matrix is not None:
                matrix.flags.writeable = False  # shared by every file with this text
        if len(_CALIB_BY_TEXT) >= _CALIB_CACHE_SIZE:
            _CALIB_BY_TEXT.clear()
        _CALIB_BY_TEXT[text] = calib
    if calib.warnings and calib.warnings[0][0] != str(path):
        calib = replace(calib, warnings=tuple((str(path), message) for _, message in calib.warnings))
    return calib


def _parse_calib(path: Path | Location, text: str) -> KittiCalib:
    """:func:`read_calib` of ``text``, the contents of ``path`` (named in errors and warnings)."""
    key_values = _key_values(path, text)
    entries = _key_values(path, text, _CALIB_ALIASES)
    missing = [key for key in _CALIB_SIZES if key != "Tr_imu_to_velo" and key not in entries]
    if missing:
        raise InputError(f"{path}: expected keys P0..P3, R0_rect (R_rect), Tr_velo_to_cam (Tr_velo_cam); "
                         f"missing {missing}")
    values = {key: _floats(path, key, entries[key], size, _CALIB_LIMITS.get(key)) for key, size in _CALIB_SIZES.items()
              if key in entries}
    spelled = {_CALIB_ALIASES.get(key, key): key for key in key_values}
    P = np.stack([values[f"P{i}"].reshape(3, 4) for i in range(4)])
    R0_rect = values["R0_rect"].reshape(3, 3)
    velo_to_cam = values["Tr_velo_to_cam"].reshape(3, 4)
    imu_to_velo = values["Tr_imu_to_velo"].reshape(3, 4) if "Tr_imu_to_velo" in values else None
    rotations = {(path, spelled["R0_rect"]): R0_rect, (path, spelled["Tr_velo_to_cam"]): velo_to_cam[:, :3]}
    if imu_to_velo is not None:
        rotations[(path, spelled["Tr_imu_to_velo"])] = imu_to_velo[:, :3]
    warnings = _checked(P, rotations, [f"{path}: P{i}" for i in range(4)])
    return KittiCalib(P=P, R0_rect=R0_rect, velo_to_cam=velo_to_cam, imu_to_velo=imu_to_velo, warnings=warnings)


def read_raw_calib(date_dir: Path | Location) -> KittiCalib:
    """Reads a raw recording day's ``calib_cam_to_cam.txt``, ``calib_velo_to_cam.txt``, ``calib_imu_to_velo.txt``."""
    cam_path = date_dir / "calib_cam_to_cam.txt"
    velo_path = date_dir / "calib_velo_to_cam.txt"
    imu_path = date_dir / "calib_imu_to_velo.txt"
    for path in (cam_path, velo_path, imu_path):
        require_file(path, "calibration file")
    cam = _parse_key_values(cam_path)
    needed = [f"{k}_0{i}" for i in range(4) for k in ("P_rect", "S_rect")] + ["R_rect_00"]
    missing = [key for key in needed if key not in cam]
    if missing:
        raise InputError(f"{cam_path}: expected keys P_rect_0i, S_rect_0i, R_rect_00; missing {missing}")

    def rigid(path: Path | Location) -> np.ndarray:
        entries = _parse_key_values(path)
        for key in ("R", "T"):
            if key not in entries:
                raise InputError(f"{path}: expected keys R and T, missing {key}")
        return np.hstack([_floats(path, "R", entries["R"], 9).reshape(3, 3),
                          _floats(path, "T", entries["T"], 3, MAX_COORDINATE_M)[:, None]])

    P = np.stack([_floats(cam_path, f"P_rect_0{i}", cam[f"P_rect_0{i}"], 12, MAX_CAMERA_VALUE_PX).reshape(3, 4)
                  for i in range(4)])
    R0_rect = _floats(cam_path, "R_rect_00", cam["R_rect_00"], 9).reshape(3, 3)
    velo_to_cam = rigid(velo_path)
    imu_to_velo = rigid(imu_path)
    image_size = np.stack([_floats(cam_path, f"S_rect_0{i}", cam[f"S_rect_0{i}"], 2, MAX_CAMERA_VALUE_PX)
                           for i in range(4)])
    if np.any(image_size < 1) or np.any(image_size != np.round(image_size)):
        raise InputError(f"{cam_path}: S_rect_0i: expected whole positive image sizes, got {image_size.tolist()}")
    warnings = _checked(P, {(cam_path, "R_rect_00"): R0_rect, (velo_path, "R"): velo_to_cam[:, :3],
                            (imu_path, "R"): imu_to_velo[:, :3]}, [f"{cam_path}: P_rect_0{i}" for i in range(4)])
    return KittiCalib(P=P, R0_rect=R0_rect, velo_to_cam=velo_to_cam, imu_to_velo=imu_to_velo,
                      image_size=image_size.astype(int), warnings=warnings)


#: The keys of an object calibration file, in the order KITTI writes them.
CALIB_KEYS = ("P0", "P1", "P2", "P3", "R0_rect", "Tr_velo_to_cam", "Tr_imu_to_velo")


def format_calib(matrices: dict[str, np.ndarray]) -> str:
    """The text of an object calibration file (``calib/000000.txt``), the inverse of :func:`read_calib`.

    Args:
        matrices: each of :data:`CALIB_KEYS` -> its matrix ((3, 4), or (3, 3) for ``R0_rect``), written
            row-major with 12 significant digits (KITTI's own files have 7).
    """
    return "".join(f"{key}: " + " ".join(f"{v:.12e}" for v in matrices[key].ravel()) + "\n" for key in CALIB_KEYS)
