"""Damaged files: every changed byte of a real converted KITTI scene is reported, nothing but AvdataError escapes.

The scene is the real KITTI object sample in ../shared/realdata converted with the KITTI
converter, uncompressed and with zstd chunks. Hypothesis flips one byte (any bit pattern) or
truncates the file; ``avdata validate`` must exit 1, and validate, info and the DatasetReader API
must raise nothing but :class:`~avdata.errors.AvdataError` subclasses. Index tables and the
manifest get the same treatment.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from avdata.cli import main
from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.kitti import KittiObjectConverter
from avdata.errors import AvdataError
from avdata.schema import DatasetReader
from avdata.schema.info import describe_dataset
from avdata.schema.validate import validate_dataset
from tests.realdata import REALDATA

OBJECT = REALDATA / "kitti" / "object"
#: Examples per test and compression; AVDATA_BYTE_FLIPS=500 for a longer run (the figure in README).
EXAMPLES = int(os.environ.get("AVDATA_BYTE_FLIPS", "30"))


def _settings(share: float) -> settings:
    return settings(max_examples=max(1, int(EXAMPLES * share)), deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@pytest.fixture(scope="module", params=["none", "zstd"])
def converted(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    dst = tmp_path_factory.mktemp(f"kitti-{request.param}") / "ds"
    run_conversion(KittiObjectConverter(ConvertConfig(src=OBJECT, dst=dst, quiet=True,
                                                               compression=request.param)))
    assert validate_dataset(dst) == []
    yield dst


def _cli(*argv: str) -> int:
    """Runs the CLI; an error must be one ``avdata: error:`` line."""
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        status = main(list(argv))
    # stderr: one "avdata: error:" line, or validate's "N problems" count.
    lines = err.getvalue().splitlines()
    assert len(lines) <= 1 and all(re.fullmatch(r"avdata: error: .+|\d+ problems", line) for line in lines), lines
    return status


def _exercise_api(root: Path) -> None:
    """Reads everything through the public API; only AvdataError may come out."""
    try:
        describe_dataset(root)
    except AvdataError as error:
        assert "\n" not in str(error)
    try:
        reader = DatasetReader(root)
        frames = list(reader.iter_frames())
    except AvdataError:
        return
    for scene, frame_index, time_ns in frames:
        try:
            scene_reader = reader.scene(scene)
            scene_reader.graph.lookup("world", "ego", time_ns)
            info, labels = scene_reader.labels(frame_index)
            len(labels)
            for sensor in sorted(info.sensor_timestamps_ns):
                topic_kind = scene_reader.sensors().get(sensor, {}).get("kind")
                if topic_kind == "lidar":
                    reader.points(scene, frame_index, sensor)
                elif topic_kind == "camera":
                    reader.image(scene, frame_index, sensor)
                    scene_reader.camera_calibration(sensor, time_ns)
                scene_reader.visibility(sensor, frame_index)
        except AvdataError as error:
            assert "\n" not in str(error)


@contextlib.contextmanager
def _damaged(converted: Path, relative: str, change: bytes | int) -> Iterator[Path]:
    """The dataset with ``relative`` changed (bytes: new content; int: truncated there), restored afterwards."""
    path = converted / relative
    original = path.read_bytes()
    path.write_bytes(original[:change] if isinstance(change, int) else change)
    try:
        yield converted
    finally:
        path.write_bytes(original)


def _scene_file(converted: Path) -> str:
    (path,) = (converted / "scenes").glob("*.mcap")
    return str(path.relative_to(converted))


@_settings(1.0)
@given(data=st.data())
def test_every_flipped_byte_of_a_scene_is_reported(converted: Path, data: st.DataObject) -> None:
    relative = _scene_file(converted)
    original = (converted / relative).read_bytes()
    size = len(original)
    # Half the flips land in the first or last 4 KiB (records, indexes, summary, footer), half anywhere.
    region = data.draw(st.sampled_from(["head", "tail", "anywhere"]))
    low, high = {"head": (0, 4096), "tail": (size - 4096, size), "anywhere": (0, size)}[region]
    position = data.draw(st.integers(low, high - 1))
    mask = data.draw(st.integers(1, 255))
    changed = bytearray(original)
    changed[position] ^= mask
    with _damaged(converted, relative, bytes(changed)) as root:
        assert _cli("validate", str(root)) == 1, f"byte {position} ^ {mask:#x} not reported"
        _cli("info", str(root))
        _exercise_api(root)


@_settings(0.3)
@given(data=st.data())
def test_every_truncation_of_a_scene_is_reported(converted: Path, data: st.DataObject) -> None:
    relative = _scene_file(converted)
    size = (converted / relative).stat().st_size
    length = data.draw(st.integers(0, size - 1))
    with _damaged(converted, relative, length) as root:
        assert _cli("validate", str(root)) == 1, f"truncation to {length} bytes not reported"
        _cli("info", str(root))
        _exercise_api(root)


@_settings(0.5)
@given(data=st.data())
def test_every_flipped_or_cut_byte_of_the_index_is_reported(converted: Path,
                                                            data: st.DataObject) -> None:
    relative = data.draw(st.sampled_from(["index/frames.parquet", "index/objects.parquet",
                                          "index/visibility.parquet"]))
    with _damaged(converted, relative, _change(converted / relative, data)) as root:
        assert _cli("validate", str(root)) == 1, f"{relative}: change not reported"
        _cli("info", str(root))
        _exercise_api(root)


@_settings(0.5)
@given(data=st.data())
def test_every_flipped_or_cut_byte_of_the_manifest_is_reported(converted: Path,
                                                                data: st.DataObject) -> None:
    # The manifest carries a CRC-32 of its canonical text: a flip inside a free-text value (licence,
    # description) that is still valid JSON is reported too, and nothing but avdata's errors escapes.
    with _damaged(converted, "avdata.json", _change(converted / "avdata.json", data)) as root:
        assert _cli("validate", str(root)) == 1, "manifest change not reported"
        _cli("info", str(root))
        _exercise_api(root)


def _change(path: Path, data: st.DataObject) -> bytes | int:
    original = path.read_bytes()
    position = data.draw(st.integers(0, len(original) - 1))
    if data.draw(st.booleans()):
        changed = bytearray(original)
        changed[position] ^= data.draw(st.integers(1, 255))
        return bytes(changed)
    return position
