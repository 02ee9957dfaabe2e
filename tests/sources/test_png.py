"""png_problem: a real KITTI PNG passes; any single flipped byte, a cut or trailing bytes are named."""

from __future__ import annotations

import random

import cv2
import numpy as np
import pytest

from avdata.sources.png import png_problem
from tests.realdata import REALDATA

IMAGE = REALDATA / "kitti" / "object" / "training" / "image_2" / "000001.png"


def test_a_real_png_is_whole_and_its_size_is_the_decoded_one():
    data = IMAGE.read_bytes()
    decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert png_problem(data) == (None, (decoded.shape[1], decoded.shape[0]))
    assert png_problem(memoryview(data)) == (None, (1242, 375))


def test_every_flipped_byte_is_found():
    data = IMAGE.read_bytes()
    rng = random.Random(7)
    # The signature, IHDR and the first chunk heads, the IEND trailer, and random bytes in between.
    offsets = list(range(0, 120)) + list(range(len(data) - 40, len(data))) + rng.sample(range(len(data)), 400)
    undecodable = 0
    for offset in offsets:
        damaged = bytearray(data)
        damaged[offset] ^= 1 << rng.randrange(8)
        problem, _ = png_problem(bytes(damaged))
        assert problem is not None, offset
        undecodable += cv2.imdecode(np.frombuffer(bytes(damaged), np.uint8), cv2.IMREAD_UNCHANGED) is None
    # libpng refuses most of them too (it checks critical chunks' CRCs) but decodes a few: flips in
    # ancillary chunks (only a warning to libpng) or in IEND's CRC.
    assert undecodable < len(offsets)


@pytest.mark.parametrize(("cut", "expected"), [
    (lambda d: d[: len(d) // 2], "run past the end (truncated file?)"),
    (lambda d: d[:-12], "the file ends inside it (truncated file?)"),
    (lambda d: d + b"\0" * 5, "5 bytes after the IEND chunk"),
    (lambda d: b"GIF89a" + d[6:], "expected a PNG file (signature and IHDR chunk)"),
])
def test_cuts_and_extras_are_named(cut, expected):
    problem, _ = png_problem(cut(IMAGE.read_bytes()))
    assert problem is not None and expected in problem
