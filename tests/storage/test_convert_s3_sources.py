"""``avdata convert`` of Waymo v2, Argoverse 2 and nuScenes-schema (Lyft) sources read from S3 (moto's server on 127.0.0.1).

Each converter's real sample files are uploaded to the bucket at test time, with a local twin of the same files
and modification times; the conversion from the bucket must write the same bytes as the local one. A counting
relay in front of the server measures what was fetched: Parquet and feather objects are read by ranges of the
columns used, and files a converter does not use are never fetched.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from tests.realdata import REALDATA
from tests.storage.conftest import SECRET, S3Server
from tests.storage.kitti_s3 import avdata, objects
from tests.storage.sources_s3 import (
    Traffic,
    convert,
    convert_locally_and_from_s3,
    counting_proxy,
    rewrite_object,
    same_dataset,
    upload_files,
    upload_tree,
)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "oracles"))

AV2 = REALDATA / "argoverse2" / "sensor"
AV2_LOG = "val/7fab2350-7eaf-3b7e-a39d-6937a4c1bede"
#: A real Waymo v2 component the converter does not use (camera keypoints): in a bucket, it must never be fetched.
WAYMO_UNUSED = REALDATA / "waymo_v2" / "camera_hkp" / "10023947602400723454_1120_000_1140_000.parquet"
#: pyarrow's first read of a Parquet footer: the object's last 64 KiB.
FOOTER_READ = 64 << 10


def _sizes(server: S3Server, prefix: str) -> dict[str, int]:
    listed = server.client().list_objects_v2(Bucket=server.bucket, Prefix=f"{prefix}/").get("Contents", [])
    return {f"/{server.bucket}/{item['Key']}": int(item["Size"]) for item in listed}


def _print(name: str, traffic: Traffic, fetched: dict[str, int], sizes: dict[str, int]) -> None:
    """The measured numbers (``pytest -s`` shows them; docs/cluster.md quotes them)."""
    listings = sum("?" in path for path, _, _ in traffic.gets)
    print(f"{name} from S3: {traffic.requests} requests ({listings} GETs are listings), {sum(fetched.values())} of "
          f"{sum(sizes.values())} bytes")


def _fetched(traffic: Traffic) -> dict[str, int]:
    """Object path -> bytes of its GETs (listings left out)."""
    out: dict[str, int] = {}
    for path, _, size in traffic.gets:
        if "?" not in path:
            out[path] = out.get(path, 0) + size
    return out


@pytest.fixture
def waymo_src(s3_server: S3Server, tmp_path: Path) -> tuple[str, Path]:
    """The Waymo v2 fixture (Waymo's compat_v1 on the real v1 frame) and a real unused component, in the bucket."""
    from waymo_fixture import waymo_v2_fixture

    fixture, _ = waymo_v2_fixture()
    src = upload_tree(s3_server, fixture, tmp_path / "waymo", "waymo",
                      [p.relative_to(fixture).as_posix() for p in fixture.glob("*/*.parquet")])
    upload_tree(s3_server, WAYMO_UNUSED.parents[1], tmp_path / "waymo", "waymo",
                [WAYMO_UNUSED.relative_to(WAYMO_UNUSED.parents[1]).as_posix()])
    return src, tmp_path / "waymo"


@pytest.mark.oracle
def test_waymo_from_s3_is_byte_identical_and_fetches_each_object_once(
        s3_server: S3Server, waymo_src: tuple[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    src, twin = waymo_src
    local, remote, traffic = convert_locally_and_from_s3("waymo", s3_server, twin, src, tmp_path, monkeypatch)
    assert remote == local == []
    assert same_dataset(tmp_path / "remote", src, tmp_path / "local", twin)  # every file, every byte
    sizes, fetched = _sizes(s3_server, "waymo"), _fetched(traffic)
    unused = f"/{s3_server.bucket}/waymo/camera_hkp/{WAYMO_UNUSED.name}"
    assert unused in sizes and unused not in fetched
    assert all(fetched.get(path, 0) >= size for path, size in sizes.items() if path != unused)  # each one read
    # Small objects are fetched whole twice (the resume fingerprint hashes them, the reader parses them); a large
    # one's data once, plus its footer read per opening and the few columns two passes share (camera_image is
    # opened for its poses, then its images): never a large object twice.
    for path, size in sizes.items():
        assert fetched.get(path, 0) <= (2 * size if size <= FOOTER_READ else size + 3 * FOOTER_READ), path
    _print("waymo", traffic, fetched, sizes)


@pytest.mark.oracle
def test_waymo_reads_only_the_selected_columns_of_an_object(
        s3_server: S3Server, waymo_src: tuple[str, Path], monkeypatch: pytest.MonkeyPatch) -> None:
    from avdata.sources.waymo import find_component_files
    from avdata.sources.waymo.components import TIME_KEY, iter_component
    from avdata.storage import location

    src, _ = waymo_src
    with counting_proxy(s3_server, monkeypatch) as traffic:  # the store's filesystem is made for the relay's endpoint
        (context, by_component), = find_component_files(location(src)).items()
        lidar = by_component["lidar"]
        times = [t for batch in iter_component(lidar, [TIME_KEY, "key.laser_name"]) for t in batch.column(TIME_KEY).to_pylist()]
    assert lidar.path.uri == f"{src}/lidar/{context}.parquet" and lidar.path.size() > 10 << 20
    assert len(times) == 5  # one range image row per laser
    # A listing, the footer read and the key columns' chunks, of a 17 MB object holding range images.
    assert [path for path, _, _ in traffic.gets].count(f"/{s3_server.bucket}/waymo/lidar/{context}.parquet") >= 2
    assert traffic.get_bytes < lidar.path.size() / 100, traffic
    print(f"waymo lidar, 2 key columns: {traffic.requests} requests, {traffic.get_bytes} of {lidar.path.size()} bytes")


@pytest.mark.oracle
def test_a_truncated_waymo_object_is_one_line_naming_its_uri(s3_server: S3Server, waymo_src: tuple[str, Path],
                                                              tmp_path: Path) -> None:
    src, _ = waymo_src
    key = next(k for k in _sizes(s3_server, "waymo") if "/lidar_calibration/" in k)
    rewrite_object(s3_server, key.split("/", 2)[2], lambda data: data[: len(data) // 2])
    result = avdata("convert", "waymo", src, str(tmp_path / "out"), "--quiet")
    errors = [line for line in result.stderr.splitlines() if "error" in line]
    assert result.returncode == 1 and len(errors) == 1, result.stderr
    assert f"s3:/{key}: expected a Parquet file, got an unreadable one" in errors[0]
    assert "Traceback" not in result.stderr and SECRET not in result.stdout + result.stderr


@pytest.fixture
def av2_src(s3_server: S3Server, tmp_path: Path) -> tuple[str, Path]:
    """One real Argoverse 2 log (val split), in the bucket and in a local twin."""
    names = [p.relative_to(AV2).as_posix() for p in (AV2 / AV2_LOG).rglob("*") if p.is_file()]
    return upload_tree(s3_server, AV2, tmp_path / "av2", "av2", names), tmp_path / "av2"


def test_argoverse2_from_s3_is_byte_identical_to_s3_and_locally(
        s3_server: S3Server, av2_src: tuple[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    src, twin = av2_src
    local = convert("argoverse2", twin, tmp_path / "local")
    # The sample has 2 sweeps: 154 annotated times lack theirs.
    assert len(local) == 1 and "missing sweep of an annotated time" in local[0]
    with counting_proxy(s3_server, monkeypatch) as traffic:
        assert convert("argoverse2", src, tmp_path / "remote") == local
    assert same_dataset(tmp_path / "remote", src, tmp_path / "local", twin)
    assert convert("argoverse2", src, f"{s3_server.uri}/out") == local
    assert same_dataset(objects(s3_server, "out"), src, tmp_path / "local", twin)
    sizes, fetched = _sizes(s3_server, "av2"), _fetched(traffic)
    # Scene flow labels, the map's ground heights and vector map are not read; the rest once (small ones twice).
    unused = ("flow_labels.feather", ".npy", "____PIT_city_47896.json")
    assert [path for path in sizes if path.endswith(unused)] and not [path for path in fetched if path.endswith(unused)]
    assert [path for path in fetched if path.endswith("annotations.feather")]
    assert sum(fetched.values()) < sum(sizes.values()) / 1.5
    _print("argoverse2", traffic, fetched, sizes)


def test_argoverse2_reads_only_the_selected_columns_of_a_feather_object(
        s3_server: S3Server, av2_src: tuple[str, Path], monkeypatch: pytest.MonkeyPatch) -> None:
    from avdata.sources.argoverse2 import read_table
    from avdata.storage import location

    src, twin = av2_src
    with counting_proxy(s3_server, monkeypatch) as traffic:  # the store's filesystem is made for the relay's endpoint
        annotations = location(f"{src}/{AV2_LOG}/annotations.feather")
        table = read_table(annotations, ["timestamp_ns", "qw"])
    assert traffic.requests["GET"] >= 3  # the tail (the footer), the record batch's header, the columns' buffers
    assert table.column_names == ["timestamp_ns", "qw"]
    assert table.to_pydict() == read_table(twin / AV2_LOG / "annotations.feather").select(["timestamp_ns", "qw"]).to_pydict()
    # Two float64/int64 columns of 14 (two UUID strings among the others): the footer and those two buffers.
    assert traffic.get_bytes < annotations.size() / 4, traffic
    print(f"av2 annotations, 2 columns: {traffic.requests} requests, {traffic.get_bytes} of {annotations.size()} bytes")


def test_a_feather_object_whose_footer_outgrows_the_first_read_is_read_the_same(
        s3_server: S3Server, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import pyarrow as pa
    import pyarrow.ipc as ipc

    from avdata.sources.argoverse2 import read_table
    from avdata.storage import location

    # 600 columns: a footer (the schema) of ~50 kB, past the 16 kB read first, so its reader asks for the rest.
    columns = {"timestamp_ns": pa.array(range(10), pa.int64()), "qw": pa.array([1.0] * 10)}
    columns |= {f"a_column_this_reader_does_not_need_{k:04d}": pa.array([float(k)] * 10) for k in range(600)}
    batch = pa.record_batch(columns)
    with ipc.new_file(tmp_path / "many.feather", batch.schema) as writer:
        writer.write_batch(batch)
    s3_server.client().put_object(Bucket=s3_server.bucket, Key="many.feather", Body=(tmp_path / "many.feather").read_bytes())
    with counting_proxy(s3_server, monkeypatch) as traffic:
        found = read_table(location(f"{s3_server.uri}/many.feather"), ["timestamp_ns", "qw"])
    assert found.equals(read_table(tmp_path / "many.feather", ["timestamp_ns", "qw"])) and found.num_rows == 10
    assert traffic.requests["GET"] > 3, traffic  # the tail, the rest of the footer, the batch's header, 2 buffers


def test_a_truncated_sweep_and_a_bad_cuboid_cost_their_own_records_in_one_line_naming_the_uri(
        s3_server: S3Server, av2_src: tuple[str, Path], tmp_path: Path) -> None:
    import pyarrow as pa
    import pyarrow.ipc as ipc

    src, twin = av2_src
    sweep = f"av2/{AV2_LOG}/sensors/lidar/315966265259836000.feather"
    rewrite_object(s3_server, sweep, lambda data: data[: len(data) - 100])
    cuboids = f"av2/{AV2_LOG}/annotations.feather"
    table = ipc.open_file(pa.memory_map(str(twin / AV2_LOG / "annotations.feather"))).read_all()
    lengths = table.column("length_m").to_pylist()
    lengths[7] = -2.5
    table = table.set_column(table.schema.get_field_index("length_m"), "length_m", pa.array(lengths, pa.float64()))
    sink = pa.BufferOutputStream()
    with ipc.new_file(sink, table.schema) as writer:
        writer.write_table(table)
    s3_server.client().put_object(Bucket=s3_server.bucket, Key=cuboids, Body=sink.getvalue().to_pybytes())
    result = avdata("convert", "argoverse2", src, str(tmp_path / "out"), "--quiet")
    assert result.returncode == 1 and "1 scenes written" in result.stdout, result.stdout + result.stderr
    sweep_errors = [line for line in result.stderr.splitlines() if f"{s3_server.uri}/{sweep}: " in line]
    assert len(sweep_errors) == 1 and "unreadable feather file" in sweep_errors[0] and "without points" in sweep_errors[0]
    cuboid_errors = [line for line in result.stderr.splitlines() if f"{s3_server.uri}/{cuboids}: " in line]
    assert cuboid_errors == [f"error: 7fab2350-7eaf-3b7e-a39d-6937a4c1bede: {s3_server.uri}/{cuboids}: row 7: column "
                             "'length_m': expected a finite positive size <= 1000 m, got -2.5; row dropped"], result.stderr
    assert "Traceback" not in result.stderr and SECRET not in result.stdout + result.stderr


LYFT = REALDATA / "nuscenes_schema" / "lyft"


@pytest.fixture
def lyft_src(s3_server: S3Server, tmp_path: Path) -> tuple[str, Path]:
    """The real Lyft tables (nuScenes schema) and map; each sample_data file a real file of its kind.

    The excerpt ships 3 real Lyft lidar sweeps (under other names) and no camera image: the sweeps and real
    nuScenes camera images stand in for the files sample_data.json names.
    """
    tables = LYFT / "v1.01-train"
    named = {p.relative_to(tables).as_posix(): p for p in tables.rglob("*") if p.is_file()}
    sweeps = sorted((LYFT / "lidar").glob("*.bin"))
    images = sorted((REALDATA / "nuscenes" / "samples").glob("CAM_*/*.jpg"))
    rows = json.loads((tables / "v1.01-train" / "sample_data.json").read_text())
    for k, row in enumerate(rows):
        named[row["filename"]] = (sweeps if row["fileformat"] == "bin" else images)[k % 3]
    return upload_files(s3_server, named, tmp_path / "lyft", "lyft"), tmp_path / "lyft"


def test_nuscenes_schema_from_s3_is_byte_identical(s3_server: S3Server, lyft_src: tuple[str, Path], tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    src, twin = lyft_src
    local = convert("nuscenes", twin, tmp_path / "local", version="v1.01-train")
    assert not [p for p in local if "missing" in p], local  # every sensor file is there and read
    with counting_proxy(s3_server, monkeypatch) as traffic:
        assert convert("nuscenes", src, tmp_path / "remote", version="v1.01-train") == local
    assert same_dataset(tmp_path / "remote", src, tmp_path / "local", twin)
    sizes, fetched = _sizes(s3_server, "lyft"), _fetched(traffic)
    assert f"/{s3_server.bucket}/lyft/maps/map_raster_palo_alto.png" not in fetched  # named in metadata, not read
    assert all(fetched.get(path, 0) >= size for path, size in sizes.items() if not path.endswith(".png"))
    _print("nuscenes (Lyft)", traffic, fetched, sizes)


def test_a_truncated_table_object_is_one_line_naming_its_uri(s3_server: S3Server, lyft_src: tuple[str, Path],
                                                             tmp_path: Path) -> None:
    src, _ = lyft_src
    key = "lyft/v1.01-train/ego_pose.json"
    rewrite_object(s3_server, key, lambda data: data[: len(data) // 2])
    result = avdata("convert", "nuscenes", src, str(tmp_path / "out"), "--version", "v1.01-train", "--quiet")
    assert result.returncode != 0 and len(result.stderr.splitlines()) == 1, result.stderr
    assert f"{s3_server.uri}/{key}: " in result.stderr and "Traceback" not in result.stderr
    assert SECRET not in result.stdout + result.stderr
