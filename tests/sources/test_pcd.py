"""``avdata.sources.pcd.read_pcd`` against the real PCD files' headers and payloads, and damaged copies.

Real files (read in place): DAIR-V2X vehicle side ``017314.pcd`` (binary_compressed, x y z F4,
intensity U1, timestamp F8) and infrastructure side ``001366.pcd`` (binary_compressed, four F4). The
OPV2V/V2XSet ASCII layout (``x y z rgb`` with the colour packed into a float) is written here with the
real file's exact header.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pypcd4 import Encoding
from pypcd4 import PointCloud as PypcdCloud

from avdata.errors import InputError
from avdata.sources.pcd import read_pcd
from tests.realdata import REALDATA

REPO = Path(__file__).resolve().parents[2]
DAIR = REALDATA / "dair_v2x"
VEHICLE_PCD = DAIR / "vehicle-side" / "velodyne" / "017314.pcd"
INFRA_PCD = DAIR / "infrastructure-side" / "velodyne" / "001366.pcd"

OPV2V_HEADER = (
    "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\n"
    "COUNT 1 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA ascii\n"
)


def test_real_vehicle_side_binary_compressed_mixed_types() -> None:
    points = read_pcd(VEHICLE_PCD)
    assert points.dtype.names == ("x", "y", "z", "intensity", "timestamp")
    assert [points.dtype[n] for n in points.dtype.names] == [np.dtype("<f4")] * 3 + [np.dtype("u1"), np.dtype("<f8")]
    assert len(points) == 62199
    # first point as decoded by PCL's layout (column-wise after LZF): checked once by hand with pypcd4
    assert points[0]["x"] == np.float32(-93.25332) and points[0]["intensity"] == 21
    assert 1.626e9 < points["timestamp"].min() <= points["timestamp"].max() < 1.627e9  # 2021-07 epoch seconds
    assert np.all(np.isfinite(points["x"]))


def test_real_infrastructure_side_binary_compressed() -> None:
    points = read_pcd(INFRA_PCD)
    assert points.dtype.names == ("x", "y", "z", "intensity")
    assert len(points) == 53653
    assert points[0]["x"] == np.float32(23.684158)
    assert 0.0 <= points["intensity"].min() and points["intensity"].max() <= 1.0


def test_ascii_opv2v_layout_and_binary_round_trip(tmp_path: Path) -> None:
    xyz = np.array([[-68.34235382, -1.954882282e-05, 2.386561155], [1.5, -2.25, 0.125]], dtype=np.float32)
    rgb = np.array([1.781608625e-38, 1.790792175e-38], dtype=np.float32)
    ascii_path = tmp_path / "a.pcd"
    body = "".join(f"{x:.10g} {y:.10g} {z:.10g} {c:.10g}\n" for (x, y, z), c in zip(xyz, rgb, strict=True))
    ascii_path.write_text(OPV2V_HEADER.format(n=2) + body)
    points = read_pcd(ascii_path)
    assert points.dtype.names == ("x", "y", "z", "rgb")
    np.testing.assert_array_equal(points["x"], xyz[:, 0])
    np.testing.assert_array_equal(points["rgb"].view(np.uint32), rgb.view(np.uint32))
    for encoding in (Encoding.BINARY, Encoding.BINARY_COMPRESSED):
        path = tmp_path / f"{encoding.value}.pcd"
        PypcdCloud(PypcdCloud.from_fileobj(open(ascii_path, "rb")).metadata, points).save(path, encoding=encoding)
        again = read_pcd(path)
        np.testing.assert_array_equal(again.view(np.uint8), points.view(np.uint8))


def test_damaged_files_fail_with_one_line_naming_the_file(tmp_path: Path) -> None:
    raw = VEHICLE_PCD.read_bytes()
    cut = tmp_path / "cut.pcd"
    cut.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(InputError, match="cut.pcd"):
        read_pcd(cut)
    bad_header = tmp_path / "header.pcd"
    bad_header.write_bytes(raw.replace(b"TYPE F F F U F", b"TYPE F F F Q F", 1))
    with pytest.raises(InputError, match="header.pcd: malformed PCD header"):
        read_pcd(bad_header)
    short_ascii = tmp_path / "short.pcd"
    short_ascii.write_text(OPV2V_HEADER.format(n=3) + "1 2 3 0\n4 5 6 0\n")
    with pytest.raises(InputError, match="short.pcd: data: expected POINTS 3 points, got 2"):
        read_pcd(short_ascii)
    long_ascii = tmp_path / "long.pcd"
    long_ascii.write_text(OPV2V_HEADER.format(n=1) + "1 2 3 0\n4 5 6 0\n")
    with pytest.raises(InputError, match="long.pcd: data: expected POINTS 1 points, got 2"):
        read_pcd(long_ascii)
    zero = tmp_path / "zero.pcd"  # the real cloud's header saying 0 points read as an empty cloud
    zero.write_bytes(raw.replace(b"WIDTH 62199", b"WIDTH 0").replace(b"POINTS 62199", b"POINTS 0"))
    with pytest.raises(InputError, match=r"zero.pcd: binary_compressed data: header POINTS 0 x 21 bytes = 0 bytes, "
                                         r"but the compressed block holds 1306179"):
        read_pcd(zero)
    binary = tmp_path / "binary.pcd"
    binary.write_bytes(OPV2V_HEADER.format(n=4).replace("ascii", "binary").encode() + bytes(40))
    with pytest.raises(InputError, match="binary.pcd: binary data: expected 4 points x 16 bytes = 64 bytes, got 40"):
        read_pcd(binary)
    with pytest.raises(InputError, match="missing.pcd: cannot read"):
        read_pcd(tmp_path / "missing.pcd")
    no_data = tmp_path / "nodata.pcd"
    no_data.write_text("VERSION 0.7\nFIELDS x\n")
    with pytest.raises(InputError, match="nodata.pcd: PCD header: expected a DATA line"):
        read_pcd(no_data)


@pytest.mark.parametrize(("field", "value"), [("x", np.nan), ("z", -np.inf), ("y", 3e30)])
def test_a_coordinate_no_lidar_measures_is_refused(tmp_path: Path, field: str, value: float) -> None:
    # LZF- or uncompressed PCD data has no checksum: a damaged float was a point at infinity, stored as is.
    cloud = read_pcd(INFRA_PCD)
    cloud[field][17] = value
    path = tmp_path / "damaged.pcd"
    with open(INFRA_PCD, "rb") as real:
        PypcdCloud(PypcdCloud.from_fileobj(real).metadata, cloud).save(path, encoding=Encoding.BINARY_COMPRESSED)
    with pytest.raises(InputError, match=rf"damaged.pcd: point 17, {field}: expected a finite value within"):
        read_pcd(path)


@pytest.mark.parametrize(("find", "put", "why"), [
    (b"SIZE 4 4 4 1 8", b"SIZE 4 4 4 1", "counts differ"),  # fewer sizes than fields: an IndexError traceback
    (b"SIZE 4 4 4 1 8", b"SIZE 4 4 4 3 8", "('U', 3)"),  # a 3-byte unsigned integer
    (b"TYPE F F F U F", b"TYPE F F F F F", "('F', 1)"),  # a 1-byte float
    (b"FIELDS x y z intensity timestamp", b"FIELDS x x z intensity timestamp", "field 'x' occurs more than once"),
])
def test_a_header_whose_fields_sizes_and_types_disagree_is_one_line(tmp_path: Path, find: bytes, put: bytes,
                                                                    why: str) -> None:
    # Each was a KeyError / IndexError / ValueError traceback from pypcd4's dtype.
    path = tmp_path / "lying.pcd"
    raw = VEHICLE_PCD.read_bytes()
    assert find in raw
    path.write_bytes(raw.replace(find, put, 1))
    with pytest.raises(InputError) as info:
        read_pcd(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"{path}: PCD header FIELDS ")
    assert "expected one size, type and count per field, a known type and unique names" in message and why in message


def test_binary_points_of_fewer_fields_than_sizes_are_refused(tmp_path: Path) -> None:
    # FIELDS x y z over four sizes read the 16-byte points as 12-byte ones: 4 points of garbage, without a word.
    path = tmp_path / "three.pcd"
    header = OPV2V_HEADER.format(n=3).replace("ascii", "binary").replace("FIELDS x y z rgb", "FIELDS x y z")
    path.write_bytes(header.encode() + np.arange(12, dtype=np.float32).tobytes())
    with pytest.raises(InputError, match=r"three.pcd: PCD header FIELDS x y z SIZE 4 4 4 4 TYPE F F F F COUNT 1 1 1 1: "
                                         r"expected one size, type and count per field"):
        read_pcd(path)


@pytest.mark.parametrize("extra", [1, 10**6, 2**31])
def test_a_compressed_size_beyond_the_file_is_refused(tmp_path: Path, extra: int) -> None:
    # The block was read as far as the file went and decoded without a word.
    cloud = read_pcd(INFRA_PCD)[:3000]
    path = tmp_path / "sized.pcd"
    with open(INFRA_PCD, "rb") as real:
        metadata = PypcdCloud.from_fileobj(real).metadata.model_copy(update={"width": 3000, "points": 3000})
    PypcdCloud(metadata, cloud).save(path, encoding=Encoding.BINARY_COMPRESSED)
    raw = bytearray(path.read_bytes())
    start = raw.find(b"\n", raw.find(b"\nDATA") + 1) + 1
    compressed = int.from_bytes(raw[start:start + 4], "little")
    assert compressed == len(raw) - start - 8  # pypcd4 writes the block to the end of the file
    raw[start:start + 4] = (compressed + extra).to_bytes(4, "little")
    path.write_bytes(bytes(raw))
    with pytest.raises(InputError, match=rf"sized.pcd: binary_compressed data: expected the compressed block of "
                                         rf"{compressed + extra} bytes within the file, got {compressed} bytes"):
        read_pcd(path)
