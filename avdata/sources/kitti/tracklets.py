"""KITTI raw ``tracklet_labels.xml`` (the devkit's boost serialisation), one row per (tracklet, frame) pose."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from avdata.errors import InputError
from avdata.inputs import read_regular_file
from avdata.storage import Location


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


def read_tracklets(path: Path | Location) -> Tracklets:
    """Reads a raw drive's ``tracklet_labels.xml`` (boost serialisation format of the KITTI devkit)."""
    try:
        root = ET.fromstring(read_regular_file(path))  # a FIFO is refused, not waited on
    except OSError as error:
        raise InputError(f"{path}: cannot read ({error.strerror or error})") from None
    except ET.ParseError as error:
        raise InputError(f"{path}: unreadable tracklet XML ({error})") from None
    tracklets = root.find("tracklets")
    if tracklets is None:
        raise InputError(f"{path}: expected a <tracklets> element, got none")
    rows: list[tuple[int, int, str, list[float], list[float], list[float], int, int]] = []
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


