"""``avdata.sources.jpeg.jpeg_problem`` on the real JPEGs in ../shared/realdata, OpenCV encodings and damaged copies."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from avdata.sources.jpeg import jpeg_problem
from tests.realdata import REALDATA


def nuscenes_jpegs() -> list[Path]:
    """The real nuScenes JPEGs (listed when a test runs, never at import)."""
    return sorted((REALDATA / "nuscenes" / "samples").glob("CAM_*/*.jpg"))


def test_every_real_nuscenes_jpeg_is_whole_and_a_cut_anywhere_is_found() -> None:
    jpegs = nuscenes_jpegs()
    assert len(jpegs) == 18
    for path in jpegs:
        assert jpeg_problem(path.read_bytes()) == (None, (1600, 900)), path
    data = jpegs[0].read_bytes()
    # Cut inside the headers, inside the scan, and just before the end marker.
    for size in (2, 300, 600, len(data) // 2, len(data) - 1):
        problem, _ = jpeg_problem(data[:size])
        assert problem is not None and problem.endswith("(truncated file?)"), (size, problem)


@pytest.mark.parametrize("params", [[], [cv2.IMWRITE_JPEG_PROGRESSIVE, 1], [cv2.IMWRITE_JPEG_RST_INTERVAL, 4],
                                    [cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444]])
def test_jpeg_check_accepts_opencv_encodings_and_reads_their_size(params: list[int]) -> None:
    image = np.random.default_rng(0).integers(0, 255, (37, 53, 3), dtype=np.uint8)
    ok, jpeg = cv2.imencode(".jpg", image, params)
    assert ok and jpeg_problem(jpeg.tobytes()) == (None, (53, 37))
    ok, grey = cv2.imencode(".jpg", image[:, :, 0], params)
    assert ok and jpeg_problem(grey.tobytes()) == (None, (53, 37))


def test_jpeg_check_names_what_is_wrong() -> None:
    ok, encoded = cv2.imencode(".jpg", np.zeros((8, 16, 3), np.uint8))
    jpeg = encoded.tobytes()
    assert jpeg_problem(b"") == ("expected a JPEG file (bytes ff d8), got an empty file", (0, 0))
    assert jpeg_problem(jpeg + b"\x00") == (
        "expected the file to end with the EOI marker ff d9, got d9 00 (truncated file?)", (16, 8))
    assert jpeg_problem(b"\xff\xd8\xff\xd9") == ("end marker ff d9 at byte 2 before any scan (no image data)", (0, 0))
    assert jpeg_problem(b"\xff\xd8\x00\xe0\x00\x10" + bytes(20))[0] == (
        "expected a marker (ff xx) at byte 2, got 00 (damaged bytes)")
