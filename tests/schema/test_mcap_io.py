"""The MCAP module: CRCs the stock reader checks, lazy chunks, time windows, zero-copy reads, writer checks."""

from __future__ import annotations

import hashlib
import json
import os
import zlib
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.records import Chunk, DataEnd, Footer
from mcap.stream_reader import StreamReader

from avdata.errors import InputError
from avdata.frames import Boxes3D, Transform
from avdata.schema import DatasetReader, DatasetWriter, ObjectLabels, SceneReader, SceneWriter, scene_metadata
from avdata.schema.mcap import fileio
from avdata.schema.mcap import reader as reader_module
from avdata.schema.mcap import writer as mcap_writer
from avdata.schema.mcap.reader import McapReader
from avdata.schema.mcap.writer import McapWriter
from tests.schema.conftest import T0, cloud, write_dataset


def _write_mixed(path: Path, compression: str) -> dict[int, bytes]:
    """Messages below and above the zero-copy threshold on two channels; returns time -> payload."""
    rng = np.random.default_rng(3)
    written: dict[int, bytes] = {}
    with open(path, "wb") as stream, McapWriter(stream, library="test", compression=compression,
                                                chunk_size=4096, large_message_bytes=10_000) as writer:
        schema = writer.register_schema("raw", "", b"")
        small = writer.register_channel("/small", "raw", schema)
        large = writer.register_channel("/large", "raw", schema)
        for i in range(30):
            size = int(rng.integers(1, 3000)) if i % 3 else int(rng.integers(10_000, 40_000))
            payload = rng.integers(0, 256, size, dtype=np.uint8)
            written[1000 + i] = payload.tobytes()
            parts = [b"h", memoryview(payload)[1:]] if i % 2 else [payload.tobytes()]
            written[1000 + i] = b"".join(bytes(p) for p in parts)
            writer.add_message(large if size >= 10_000 else small, 1000 + i, 1000 + i, i, parts)
        writer.add_metadata("m", {"k": "v"})
    return written


@pytest.mark.parametrize("compression", ["", "zstd", "lz4"])
def test_stock_reader_validates_every_crc_of_small_and_large_chunks(tmp_path: Path, compression: str) -> None:
    path = tmp_path / "mixed.mcap"
    written = _write_mixed(path, compression)
    with open(path, "rb") as stream:
        chunks = [r for r in StreamReader(stream, emit_chunks=True).records if isinstance(r, Chunk)]
    with open(path, "rb") as stream:
        for record in StreamReader(stream, validate_crcs=True).records:
            if isinstance(record, DataEnd):
                assert record.data_section_crc == zlib.crc32(path.read_bytes()[: stream.tell() - 13])
            elif isinstance(record, Footer):
                assert record.summary_crc != 0
    assert len(chunks) > 10 and all(chunk.uncompressed_crc != 0 for chunk in chunks)
    assert any(len(chunk.data) >= 10_000 for chunk in chunks) and any(len(chunk.data) < 5_000 for chunk in chunks)
    with open(path, "rb") as stream:
        read = {message.log_time: message.data for _, _, message in make_reader(stream, validate_crcs=True).iter_messages()}
    assert read == written
    reader = McapReader(path, verify=True)
    assert reader.verify_file() == []
    ours = {}
    for topic, table in reader.tables().items():
        channel = reader.channel_of_topic(topic)
        assert channel is not None
        ours.update({int(t): bytes(reader.read(table, i, channel.id)) for i, t in enumerate(table.log_time_ns)})
    assert ours == written


def test_unknown_compression_is_refused_with_its_name(tmp_path: Path) -> None:
    with open(tmp_path / "x.mcap", "wb") as stream, pytest.raises(InputError, match="got 'brotli'"):
        McapWriter(stream, library="test", compression="brotli")
    with pytest.raises(InputError, match="got 'gzip'"):
        DatasetWriter(tmp_path / "ds", source="t", compression="gzip").scene("s")


def test_time_windows_are_half_open_like_the_mcap_library(dataset: Path) -> None:
    scene = SceneReader(dataset / "scenes" / "scene-a.mcap")
    topic = "/ego/lidar/points"
    times = scene.times(topic).tolist()
    for start, end in [(None, None), (times[1], times[3]), (times[1] - 1, times[3] + 1), (times[3], times[3]),
                       (None, times[2]), (times[2], None)]:
        with open(scene.path, "rb") as stream:
            stock = [m.log_time for _, _, m in make_reader(stream).iter_messages(
                topics=[topic], starting_at=start, ending_before=end)]
        assert [t for t, _ in scene.messages(topic, start, end)] == stock
    assert [t for t, _ in scene.messages(topic, times[1], times[3])] == times[1:3]
    assert list(scene.messages("/no/such/topic")) == []


def test_compressed_scene_decompresses_only_the_chunks_it_reads(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "zstd.mcap"
    with SceneWriter(path, "zstd", compression="zstd") as scene:
        for i in range(5):
            scene.add_point_cloud("ego/lidar", T0 + i, cloud(i, 30_000))
    calls: list[int] = []
    real = reader_module.decompress

    def counting(compression: str, data: object, size: int) -> bytes:
        calls.append(size)
        return real(compression, data, size)  # type: ignore[arg-type]

    monkeypatch.setattr(reader_module, "decompress", counting)
    scene = SceneReader(path)
    assert len(scene._mcap.chunks) == 5
    assert calls == [] and "/ego/lidar/points" in scene.topics and calls == []
    points = scene.points("ego/lidar", T0 + 3)
    assert len(calls) == 1
    np.testing.assert_array_equal(points["x"], cloud(3, 30_000)["x"])


def test_tf_static_is_the_first_message_stamped_at_the_scene_start(dataset: Path) -> None:
    with open(dataset / "scenes" / "scene-a.mcap", "rb") as stream:
        messages = [(channel.topic, message.log_time)
                    for _, channel, message in make_reader(stream).iter_messages(log_time_order=False)]
    assert messages[0] == ("/tf_static", min(t for _, t in messages))


def test_uncompressed_points_are_read_only_zero_copy_views_that_outlive_close(dataset: Path) -> None:
    scene = SceneReader(dataset / "scenes" / "scene-a.mcap")
    points = scene.points("ego/lidar", T0 + 100_000_000)
    assert not points.flags.writeable and not points.flags.owndata
    with pytest.raises(ValueError, match="read-only"):
        points["x"][0] = 1.0
    scene.close()
    np.testing.assert_array_equal(points["x"], cloud(1)["x"])
    buffer = np.zeros(points.nbytes + 64, dtype=np.uint8)
    into = scene.points_into("ego/lidar", T0 + 100_000_000, buffer)
    assert into.flags.writeable and np.shares_memory(into, buffer)
    np.testing.assert_array_equal(into, points)
    with pytest.raises(Exception, match="at least"):
        scene.points_into("ego/lidar", T0, np.zeros(10, dtype=np.uint8))


def test_verified_reads_catch_a_flipped_payload_byte(tmp_path: Path) -> None:
    root = write_dataset(tmp_path / "ds")
    path = root / "scenes" / "scene-a.mcap"
    scene = SceneReader(path)
    table = scene.message_table("/ego/lidar/points")
    offset = scene._mcap.payload_file_offset(int(table.chunk[2]), int(table.record_offset[2]))
    assert offset is not None
    data = bytearray(path.read_bytes())
    data[offset + 1000] ^= 0x10
    path.write_bytes(bytes(data))
    time_ns = int(table.log_time_ns[2])
    SceneReader(path).points("ego/lidar", time_ns)  # unverified: the flip goes unnoticed
    with pytest.raises(InputError, match="chunk CRC mismatch"):
        SceneReader(path, verify=True).points("ego/lidar", time_ns)
    with pytest.raises(InputError, match="chunk CRC mismatch"):
        DatasetReader(root, verify=True).points("scene-a", 2, "ego/lidar")


def test_scene_metadata_round_trips_arbitrary_json_without_reading_messages(tmp_path: Path) -> None:
    fingerprint = {"inputs": {"a.bin": [123, 1.7e9], "b.txt": "sha256:ab"}, "options": {"frames": None, "x": [1, 2]},
                   "avdata_major": 1, "errors": 0}
    with SceneWriter(tmp_path / "s.mcap", "s", {"fingerprint": fingerprint, "split": "val"}) as scene:
        scene.add_frame(0, T0, ObjectLabels.empty("world"))
    meta = scene_metadata(tmp_path / "s.mcap")
    assert meta["fingerprint"] == fingerprint and meta["split"] == "val" and meta["name"] == "s"
    reader = SceneReader(tmp_path / "s.mcap")
    assert reader.metadata == meta and reader._mcap._tables is None
    with pytest.raises(InputError, match=r"keys \['name'\] are written by avdata"):
        SceneWriter(tmp_path / "t.mcap", "t", {"name": "other"})
    with pytest.raises(InputError, match="must be a JSON object"), SceneWriter(tmp_path / "u.mcap", "u", {"f": {1, 2}}):
        pass
    assert not (tmp_path / "u.mcap").exists()


def _labels(ids: list[str]) -> ObjectLabels:
    n = len(ids)
    boxes = Boxes3D.from_yaw(np.arange(3.0 * n).reshape(n, 3), np.ones((n, 3)), np.zeros(n), "world",
                             ids=ids, classes=["car"] * n)
    return ObjectLabels(boxes=boxes)


def test_writer_refuses_what_the_reader_refuses(tmp_path: Path) -> None:
    path = tmp_path / "s.mcap"
    pose = Transform.from_yaw(0.1, [1.0, 2.0, 0.0])
    with pytest.raises(InputError, match=rf"s.mcap: two different poses of 'ego' in 'world' at {T0} ns"), \
            SceneWriter(path, "s") as scene:
        scene.add_transform("world", "ego", T0, pose)
        scene.add_transform("world", "ego", T0, pose)  # the same pose twice is harmless
        scene.add_transform("world", "ego", T0, Transform.from_yaw(0.1, [1.0, 2.5, 0.0]))
    with pytest.raises(InputError, match=rf"s.mcap: /tf: expected non-decreasing times, got {T0 - 1} ns after {T0}"), \
            SceneWriter(path, "s") as scene:
        scene.add_transform("world", "ego", T0, pose)
        scene.add_transform("world", "ego", T0 - 1, pose)
    with pytest.raises(InputError, match=r"s.mcap: frame 0 at \d+ ns: expected unique object ids, got \['7'\]"), \
            SceneWriter(path, "s") as scene:
        scene.add_frame(0, T0, _labels(["7", "8", "7"]))
    with pytest.raises(InputError, match="has parent 'world'; got a pose in 'map'"), SceneWriter(path, "s") as scene:
        scene.add_transform("world", "ego", T0, pose)
        scene.add_transform("map", "ego", T0 + 1, pose)
    with pytest.raises(InputError, match="given after sensor data was written"), SceneWriter(path, "s") as scene:
        scene.add_static_transform("ego", "ego/lidar", pose)
        scene.add_point_cloud("ego/lidar", T0, cloud(0, 40_000))
        scene.add_static_transform("ego", "ego/cam", pose)
    assert not path.exists()


def test_truncated_manifest_and_index_damage_are_one_line_input_errors(dataset: Path, tmp_path: Path) -> None:
    import shutil

    root = tmp_path / "copy"
    shutil.copytree(dataset, root)
    text = (root / "avdata.json").read_text()
    manifest = json.loads(text)
    for scenes, match in [("two", "expected 'scenes' to be a list"), ([{"file": "x"}], r"scenes\[0\]"),
                          ([{"name": 3}], r"scenes\[0\]")]:
        (root / "avdata.json").write_text(json.dumps({**manifest, "scenes": scenes}))
        with pytest.raises(InputError, match=match):
            DatasetReader(root)
    (root / "avdata.json").write_text("{not json")
    with pytest.raises(InputError, match="avdata.json: unreadable manifest"):
        DatasetReader(root)
    (root / "avdata.json").write_text(text)
    objects = root / "index" / "objects.parquet"
    objects.write_bytes(objects.read_bytes()[:-30])
    with pytest.raises(InputError, match="objects.parquet") as error:
        DatasetReader(root).objects()
    assert "\n" not in str(error.value)


def test_validate_and_info_name_the_damaged_record(dataset: Path, tmp_path: Path) -> None:
    import contextlib
    import io
    import shutil

    from avdata.cli import main
    from avdata.schema.validate import validate_dataset

    root = tmp_path / "copy"
    shutil.copytree(dataset, root)
    path = root / "scenes" / "scene-a.mcap"
    original = path.read_bytes()
    scene = SceneReader(path)
    lidar = scene.message_table("/ego/lidar/points")
    payload = scene._mcap.payload_file_offset(int(lidar.chunk[1]), int(lidar.record_offset[1]))
    chunk = scene._mcap.chunks[int(scene.message_table("/ego/lidar/points").chunk[1])].offset
    summary = scene._mcap.summary_start
    scene.close()
    assert payload is not None
    damaged = bytearray(original)
    damaged[payload + 7] ^= 0x01
    path.write_bytes(bytes(damaged))
    problems = [str(p) for p in validate_dataset(root)]
    assert any(f"scene-a.mcap: byte {chunk}: chunk CRC mismatch" in p for p in problems), problems
    assert any("data-section CRC mismatch" in p for p in problems)
    damaged = bytearray(original)
    damaged[summary + 20] ^= 0x80
    path.write_bytes(bytes(damaged))
    (problem,) = validate_dataset(root)
    assert "summary CRC mismatch" in problem.message and problem.scene == "scene-a"
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        assert main(["info", str(root)]) == 1
    assert err.getvalue().count("\n") == 1 and err.getvalue().startswith("avdata: error: ")
    assert "summary CRC mismatch" in err.getvalue()
    path.write_bytes(original)
    objects = root / "index" / "objects.parquet"
    table = bytearray(objects.read_bytes())
    table[0] ^= 0x01  # the leading magic, which pyarrow never reads: only the manifest's checksum sees it
    objects.write_bytes(bytes(table))
    with pytest.raises(InputError, match=r"objects.parquet: expected \d+ bytes with CRC-32"):
        DatasetReader(root).objects()  # also without verify: the check costs nothing next to parsing
    assert any("objects.parquet" in str(p) for p in validate_dataset(root))


def _write_large(path: Path) -> dict[int, bytes]:
    """Large payloads from numpy memory (each a chunk of its own, one writev), with small ones between."""
    rng = np.random.default_rng(5)
    sizes = [(1 << 20) + 3, 300_000, 17, 2 << 20, 40, 1 << 20]
    written = {}
    with open(path, "wb") as stream, McapWriter(stream, library="test") as writer:
        channel = writer.register_channel("/raw", "raw", writer.register_schema("raw", "", b""))
        for i, size in enumerate(sizes):
            payload = rng.integers(0, 256, size, dtype=np.uint8)
            writer.add_message(channel, 10 + i, 10 + i, i, [b"head", memoryview(payload)])
            written[10 + i] = b"head" + payload.tobytes()
    return written


def test_short_writes_give_the_same_valid_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    written = _write_large(tmp_path / "whole.mcap")
    with open(tmp_path / "whole.mcap", "rb") as stream:
        read = {m.log_time: m.data for _, _, m in make_reader(stream, validate_crcs=True).iter_messages()}
    assert read == written
    assert McapReader(tmp_path / "whole.mcap").verify_file() == []
    real_writev = fileio.os.writev

    def short_writev(fd: int, buffers: list) -> int:
        # The kernel may write less than asked (signals, > 2 GiB): at most 100 kB here, from any offset.
        return real_writev(fd, [b"".join(bytes(b) for b in buffers)[:100_003]])

    monkeypatch.setattr(fileio.os, "writev", short_writev)
    _write_large(tmp_path / "short.mcap")
    assert (tmp_path / "short.mcap").read_bytes() == (tmp_path / "whole.mcap").read_bytes()


def test_written_bytes_are_pinned(tmp_path: Path) -> None:
    # Byte-identical output for the same input, across changes to how the writer produces it
    # (batching, CRC order, header packing): the digests of the two uncompressed files as the
    # writer of commit 260233d wrote them.
    _write_mixed(tmp_path / "mixed.mcap", "")
    _write_large(tmp_path / "large.mcap")
    digests = {name: hashlib.sha256((tmp_path / name).read_bytes()).hexdigest() for name in ("mixed.mcap", "large.mcap")}
    assert digests == {"mixed.mcap": "00d917a440bfb0a7c0f691a229a75e6aefc5725c9414c70012e3c1d2a0e5cf2a",
                       "large.mcap": "3445a86dda3e770b0339ea3a0bd6adcad8c20e7be192b0321fa1bd39296cdfce"}


def _write_referenced(path: Path, compression: str) -> dict[int, bytes]:
    """Mid-sized parts a chunk keeps by reference (bytes, views of bytes) or copies (writable memory, changed
    right after the call), small ones between, and a ``before_first_chunk`` hook that puts three messages ahead
    of the buffered ones; returns time -> payload as it was when added."""
    rng = np.random.default_rng(11)
    written: dict[int, bytes] = {}
    with open(path, "wb") as stream, McapWriter(stream, library="test", compression=compression, chunk_size=100_000,
                                                large_message_bytes=1 << 20) as writer:
        schema = writer.register_schema("raw", "", b"")
        channel = writer.register_channel("/raw", "raw", schema)

        def hook() -> None:
            first = writer.register_channel("/first", "raw", schema)
            for t, payload in ((1, b"x" * 50), (2, bytes(range(256)) * 100), (3, b"y" * 60)):
                writer.add_message(first, t, t, 0, [payload])
                written[t] = payload

        writer.before_first_chunk = hook
        for i in range(40):
            raw = rng.integers(0, 256, int(rng.integers(1_100, 1_900)) * 16, dtype=np.uint8).tobytes()
            kind = i % 5
            if kind == 0:
                parts: list = [b"head", raw]
            elif kind == 1:  # a 2-D float view of bytes, as a point cloud read from its file
                parts = [b"head", memoryview(np.frombuffer(raw, dtype="<f4").reshape(-1, 4))]
            elif kind == 2:
                parts = [raw[:100]]
            else:  # writable memory, changed after the call: must have been copied
                mutable = bytearray(raw) if kind == 3 else np.frombuffer(raw, dtype=np.uint8).copy()
                parts = [b"head", memoryview(mutable)]
            writer.add_message(channel, 10 + i, 10 + i, i, parts)
            written[10 + i] = b"".join(bytes(p) for p in parts)
            if kind >= 3:
                memoryview(mutable)[:] = bytes(len(raw))
    return written


@pytest.mark.parametrize("compression", ["", "zstd"])
def test_parts_kept_by_reference_give_the_bytes_a_copy_gives(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                             compression: str) -> None:
    written = _write_referenced(tmp_path / "referenced.mcap", compression)
    with open(tmp_path / "referenced.mcap", "rb") as stream:
        read = {m.log_time: m.data for _, _, m in make_reader(stream, validate_crcs=True).iter_messages()}
    assert read == written
    assert McapReader(tmp_path / "referenced.mcap").verify_file() == []
    monkeypatch.setattr(fileio, "BY_REFERENCE_BYTES", 1 << 62)  # every part copied into its chunk
    _write_referenced(tmp_path / "copied.mcap", compression)
    assert (tmp_path / "referenced.mcap").read_bytes() == (tmp_path / "copied.mcap").read_bytes()


def _write_large_kinds(path: Path) -> dict[int, bytes]:
    """Large messages in bytes, in a 2-D view of bytes and in writable memory changed right after the call,
    small ones between; returns time -> payload as it was when added."""
    rng = np.random.default_rng(12)
    written: dict[int, bytes] = {}
    with open(path, "wb") as stream, McapWriter(stream, library="test", large_message_bytes=64 << 10) as writer:
        channel = writer.register_channel("/raw", "raw", writer.register_schema("raw", "", b""))
        for i in range(30):
            raw = rng.integers(0, 256, int(rng.integers(4_100, 90_000)) * 16, dtype=np.uint8).tobytes()
            kind = i % 4
            mutable = bytearray(raw)
            parts: list = ([b"head", raw] if kind == 0 else [b"h", memoryview(np.frombuffer(raw, "<f4").reshape(-1, 4))]
                           if kind == 1 else [raw[:300]] if kind == 2 else [b"head", memoryview(mutable)])
            writer.add_message(channel, 10 + i, 10 + i, i, parts)
            written[10 + i] = b"".join(bytes(p) for p in parts)
            mutable[:] = bytes(len(raw))
    return written


def test_large_messages_nobody_can_change_wait_for_the_next_write_and_give_the_same_bytes(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []
    real_writev = fileio.os.writev

    def counted_writev(fd: int, buffers: list) -> int:
        calls.append(len(buffers))
        return real_writev(fd, buffers)

    monkeypatch.setattr(fileio.os, "writev", counted_writev)
    written = _write_large_kinds(tmp_path / "queued.mcap")
    queued_calls = len(calls)
    with open(tmp_path / "queued.mcap", "rb") as stream:
        read = {m.log_time: m.data for _, _, m in make_reader(stream, validate_crcs=True).iter_messages()}
    assert read == written
    assert McapReader(tmp_path / "queued.mcap").verify_file() == []
    calls.clear()
    monkeypatch.setattr(mcap_writer, "immutable", lambda _part: False)  # every large message written at once
    _write_large_kinds(tmp_path / "at_once.mcap")
    assert (tmp_path / "queued.mcap").read_bytes() == (tmp_path / "at_once.mcap").read_bytes()
    # Of the 16 large messages in bytes or views of bytes, those under the 1 MB a queue holds (10 here) went
    # out with the next write instead of in one of their own.
    assert len(calls) - queued_calls == 10


def test_only_memory_nobody_can_change_is_kept_by_reference() -> None:
    frozen = bytes(20_000)
    assert fileio.by_reference(frozen) is frozen
    assert fileio.by_reference(frozen[:100]) is None  # small: copied
    view = fileio.by_reference(memoryview(np.frombuffer(frozen, dtype="<f4").reshape(-1, 5)))
    assert isinstance(view, memoryview) and view.format == "B" and view.nbytes == 20_000
    assert fileio.by_reference(memoryview(frozen)[::2]) is None  # not contiguous
    for writable in (bytearray(frozen), np.zeros(20_000, dtype=np.uint8), np.frombuffer(bytearray(frozen), np.uint8)):
        assert fileio.by_reference(memoryview(writable)) is None


def test_blocks_reserved_ahead_of_the_writes_are_given_back(tmp_path: Path) -> None:
    # The writer reserves the file's blocks in steps (fallocate, size unchanged; at least 4 MiB) and frees the
    # unused tail at the end.
    path = tmp_path / "big.mcap"
    with SceneWriter(path, "big") as scene:
        scene.add_static_transform("ego", "ego/lidar", Transform.identity())
        for i in range(3):
            scene.add_point_cloud("ego/lidar", T0 + i, cloud(i, 60_000))  # 1.1 MB: a chunk of its own, written now
            during = os.stat(scene._tmp_path)
            assert during.st_blocks * 512 >= during.st_size + (512 << 10)  # reserved beyond what was written
    after = os.stat(path)
    assert after.st_size > 3_000_000
    assert after.st_blocks * 512 <= after.st_size + (64 << 10)
    np.testing.assert_array_equal(SceneReader(path).points("ego/lidar", T0 + 2)["x"], cloud(2, 60_000)["x"])


@pytest.mark.skipif(not hasattr(os, "posix_fadvise"), reason="no posix_fadvise on this platform")
def test_written_steps_are_dropped_from_the_page_cache_one_step_behind(tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    # Once a dataset's scenes written in this process pass a tenth of the machine's memory, each call asks
    # the kernel to drop the step whose write-back the previous call started and to start the new step's;
    # a file under one step (8 MiB) is never touched, nor is a dataset under the threshold.
    calls: list[tuple[int, int, int]] = []
    real_fadvise = fileio.os.posix_fadvise

    def spy(fd: int, offset: int, length: int, advice: int) -> None:
        calls.append((offset, length, advice))
        real_fadvise(fd, offset, length, advice)

    points = cloud(1, 60_000)

    def write(writer: DatasetWriter, name: str, n_clouds: int) -> None:
        with writer.scene(name) as scene:
            for i in range(n_clouds):  # 1.1 MB each, a chunk of its own
                scene.add_point_cloud("ego/lidar", T0 + i, points)
            scene.add_frame(0, T0, ObjectLabels.empty("world"))

    monkeypatch.setattr(fileio.os, "posix_fadvise", spy)
    assert fileio.DROP_WRITTEN_AFTER_BYTES >= 1 << 26  # a tenth of the machine's memory
    monkeypatch.setattr(fileio, "DROP_WRITTEN_AFTER_BYTES", 35 << 20)
    with DatasetWriter(tmp_path / "one", source="test") as writer:
        write(writer, "under_the_threshold", 30)  # 31 MiB
    with DatasetWriter(tmp_path / "two", source="test") as writer:  # another dataset: its own tally
        write(writer, "under_the_threshold", 30)
        assert calls == []
        write(writer, "small", 7)  # 38 MiB: the dataset is past the threshold, the file under one step
        assert calls == []
        write(writer, "big", 30)
    path = tmp_path / "two" / "scenes" / "big.mcap"
    ends = [offset + length for offset, length, _ in calls]
    assert {advice for _, _, advice in calls} == {os.POSIX_FADV_DONTNEED} and len(calls) == 3
    assert [offset for offset, _, _ in calls] == [0, 0, ends[0]]  # from where the previous call's new step began
    assert all(b - a >= 8 << 20 for a, b in zip([0, *ends[:-1]], ends, strict=True))
    assert ends[-1] <= path.stat().st_size
    np.testing.assert_array_equal(SceneReader(path).points("ego/lidar", T0 + 29)["x"], points["x"])


def test_a_file_system_refusing_posix_fadvise_keeps_the_pages_and_the_file(tmp_path: Path,
                                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    tries: list[int] = []

    def refuse(fd: int, offset: int, length: int, advice: int) -> None:
        tries.append(offset)
        raise OSError(22, "Invalid argument")

    monkeypatch.setattr(fileio.os, "posix_fadvise", refuse, raising=False)
    monkeypatch.setattr(fileio, "DROP_WRITTEN_AFTER_BYTES", 0)
    points = cloud(2, 60_000)
    with SceneWriter(tmp_path / "s.mcap", "s") as scene:
        for i in range(20):
            scene.add_point_cloud("ego/lidar", T0 + i, points)
    assert tries == [0]  # asked once, then not again for this file
    assert McapReader(tmp_path / "s.mcap").verify_file() == []
    np.testing.assert_array_equal(SceneReader(tmp_path / "s.mcap").points("ego/lidar", T0 + 19)["x"], points["x"])


def test_scene_tasks_of_one_dataset_writer_add_to_one_tally_per_process(tmp_path: Path) -> None:
    # Scene tasks get a ResumableWriter on the run's writer (in process) or a pickled copy of it (one
    # per task in a worker process): either way a dataset's bytes add up, so a large conversion
    # passes the page-cache threshold with any number of workers.
    import pickle

    from avdata.executors import ResumableWriter, resume_fingerprint

    parent = DatasetWriter(tmp_path / "ds", source="test")
    in_process = ResumableWriter(parent, resume_fingerprint("test", {}))
    assert in_process._written_bytes is parent._written_bytes
    copies = [pickle.loads(pickle.dumps(parent)) for _ in range(2)]
    with copies[0], copies[0].scene("a") as scene:
        scene.add_point_cloud("ego/lidar", T0, cloud(0, 60_000))
        scene.add_frame(0, T0, ObjectLabels.empty("world"))
    assert copies[1]._written_bytes is copies[0]._written_bytes is not parent._written_bytes
    assert copies[1]._written_bytes.total > 960_000
    other = pickle.loads(pickle.dumps(DatasetWriter(tmp_path / "other", source="test")))
    assert other._written_bytes.total == 0
