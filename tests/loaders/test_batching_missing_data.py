"""Batches of items that hold different sensors and agents, through DataLoader workers and both collate functions.

Items of one dataset legitimately differ: a rate-limited infrastructure agent sends only in some frames, and the
converters keep frames whose scans are missing (the real KITTI tracking sample ships sweeps for frames 0-1 only;
the Argoverse 2 log for 2 of its annotated times). Each real sample the suite converts is converted here the way
its converter test does it (the same builders around the same real files) and batched with ``num_workers=2``.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import torch
from torch.utils.data import DataLoader, Subset

from avdata.converters import ConvertConfig, converter_class, run_conversion
from avdata.loaders import Collaboration, FrameDataset, FrameOptions, collate_list, collate_padded
from tests.realdata import REALDATA

COLLATES = {"list": collate_list, "padded": collate_padded}


def check_list_batch(batch: dict[str, Any], items: list[dict[str, Any]]) -> None:
    """Every item's value is at its place in the batch; what an item lacks is None there."""
    assert set(batch) == {key for item in items for key in item}
    for b, item in enumerate(items):
        for key, value in batch.items():
            same(pick(value, b), item.get(key), f"[{b}][{key!r}]")


def check_padded_batch(batch: dict[str, Any], items: list[dict[str, Any]]) -> None:
    """Clouds and boxes padded with masks; ``points_present`` says which items held each cloud."""
    names = list(dict.fromkeys(name for item in items for name in item["points"]))
    assert list(batch["points"]) == names and list(batch["points_present"]) == names
    for name in names:
        present = [name in item["points"] for item in items]
        assert batch["points_present"][name].tolist() == present
        sizes = [len(item["points"][name]) if p else 0 for item, p in zip(items, present, strict=True)]
        assert batch["points_mask"][name].sum(1).tolist() == sizes
        for b, (item, size) in enumerate(zip(items, sizes, strict=True)):
            if present[b]:
                assert equal(batch["points"][name][b, :size], item["points"][name])
            assert not batch["points"][name][b, size:].any()
    assert batch["boxes_mask"].sum(1).tolist() == [len(item["boxes"]) for item in items]
    for b, item in enumerate(items):
        assert equal(batch["boxes"][b, : len(item["boxes"])], item["boxes"])
        assert equal(batch["labels"][b, : len(item["labels"])], item["labels"])
        assert batch["sensor_timestamps_ns"] == {
            name: [other["sensor_timestamps_ns"].get(name) for other in items] for name in batch["sensor_timestamps_ns"]}


def equal(a: torch.Tensor, b: torch.Tensor) -> bool:
    """Same dtype, shape and values, NaN equal to NaN (velocities that were not labelled)."""
    return a.dtype == b.dtype and a.shape == b.shape and bool(((a == b) | (a != a) & (b != b)).all())


def pick(value: Any, b: int) -> Any:
    if isinstance(value, dict):
        return {name: pick(inner, b) for name, inner in value.items()}
    return value[b]


def same(got: Any, want: Any, where: str) -> None:
    if isinstance(got, dict):
        # a name this item lacks reaches every leaf as None
        assert want is None or (isinstance(want, dict) and set(want) <= set(got)), where
        for name in got:
            same(got[name], None if want is None else want.get(name), f"{where}[{name!r}]")
    elif isinstance(want, torch.Tensor):
        assert isinstance(got, torch.Tensor) and equal(got, want), where
    else:
        assert got == want, where


def batch_all_ways(dataset: Any, batch_size: int) -> dict[str, list[dict[str, Any]]]:
    """Each collate function's batches through two workers, checked against the items read here."""
    items = [dataset[i] for i in range(len(dataset))]
    batches = {}
    for name, collate in COLLATES.items():
        loader = DataLoader(dataset, batch_size=batch_size, num_workers=2, collate_fn=collate)
        batches[name] = list(loader)
        assert len(batches[name]) == -(-len(items) // batch_size)
        for k, batch in enumerate(batches[name]):
            part = items[k * batch_size : (k + 1) * batch_size]
            (check_list_batch if name == "list" else check_padded_batch)(batch, part)
    return batches


def test_rate_limited_infrastructure_is_none_or_absent_in_its_silent_frames(generated_v2i: Path) -> None:
    # the README's collaborative example: infrastructure at 5 Hz in a 10 Hz scene sends in frames 0 and 2
    options = FrameOptions(sensors=("*/lidar*",), collaboration=Collaboration(agents=("ego", "infra_*"),
                                                                               rate_hz={"infra_*": 5.0}))
    ds = FrameDataset(generated_v2i, options)
    assert len(ds) == 3
    batches = batch_all_ways(ds, batch_size=3)
    listed, padded = batches["list"][0], batches["padded"][0]
    assert list(listed["points"]) == ["ego/lidar_top", "infra_00/lidar", "infra_01/lidar"]
    assert [c is None for c in listed["points"]["infra_01/lidar"]] == [False, True, False]
    assert listed["sensor_timestamps_ns"]["infra_00/lidar"][1] is None
    assert padded["points_present"]["infra_00/lidar"].tolist() == [True, False, True]
    assert padded["points_present"]["ego/lidar_top"].tolist() == [True, True, True]
    assert padded["agent_received"].tolist() == [[True, True, True], [True, False, False], [True, True, True]]
    fused = FrameDataset(generated_v2i, FrameOptions(collaboration=Collaboration(
        agents=("ego", "infra_*"), fusion="early", rate_hz={"infra_*": 5.0})))
    batches = batch_all_ways(fused, batch_size=2)
    assert batches["padded"][0]["points_present"]["fused"].tolist() == [True, True]


# ----------------------------------------------------------------------------- every converted real sample
def _kitti(name: str, sub: str) -> Callable[[Path], Path]:
    def build(root: Path) -> Path:
        convert(name, REALDATA / "kitti" / sub, root / "dst")
        return root / "dst"
    return build


def _kitti_raw(root: Path) -> Path:
    from tests.converters.test_kitti_raw import assemble_drive

    assemble_drive(root / "src", n_frames=6)
    return convert("kitti-raw", root / "src", root / "dst")


def _lyft(root: Path) -> Path:
    from tests.converters.test_nuscenes import LYFT_ROOT

    return convert("nuscenes", LYFT_ROOT, root / "dst", version="v1.01-train")


def _nuscenes(root: Path) -> Path:
    from tests.converters.test_nuscenes import build_synthetic_nuscenes

    build_synthetic_nuscenes(root / "src")
    return convert("nuscenes", root / "src", root / "dst", version="v1.0-mini")


def _argoverse2(root: Path) -> Path:
    from tests.converters.test_argoverse2 import LOG, REAL_LOG, link_log

    link_log(REAL_LOG, root / "src" / "val" / LOG)
    return convert("argoverse2", root / "src", root / "dst")


def _waymo(root: Path) -> Path:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "oracles"))
    from waymo_fixture import waymo_v2_fixture

    return convert("waymo", waymo_v2_fixture()[0], root / "dst")


def _dair(root: Path) -> Path:
    from tests.converters.test_dair_v2x import build_dair

    build_dair(root / "src", skew=0.0)
    return convert("dair-v2x", root / "src", root / "dst")


def _v2xset(root: Path) -> Path:
    from tests.converters.opv2v_fixtures import build_opv2v

    build_opv2v(root / "src")
    return convert("opv2v", root / "src", root / "dst")


def convert(source: str, src: Path, dst: Path, **options: Any) -> Path:
    result = run_conversion(converter_class(source)(ConvertConfig(src=src, dst=dst, quiet=True, options=options)))
    assert result.written and not result.failed, result.problems
    return dst


#: source -> (builder of the converted sample, collaborative agents or None)
REAL_SAMPLES: dict[str, tuple[Callable[[Path], Path], tuple[str, ...] | None]] = {
    "kitti-object": (_kitti("kitti-object", "object"), None),
    "kitti-tracking": (_kitti("kitti-tracking", "tracking"), None),
    "kitti-raw": (_kitti_raw, None),
    "lyft": (_lyft, None),
    "nuscenes": (_nuscenes, None),
    "argoverse2": (_argoverse2, None),
    "waymo-v1-frame": (_waymo, None),
    "dair-v2x": (_dair, ("*",)),
    "v2xset": (_v2xset, ("*",)),
}


@pytest.mark.parametrize("source", [
    pytest.param(name, marks=pytest.mark.oracle) if name == "waymo-v1-frame" else name for name in REAL_SAMPLES])
def test_every_converted_real_sample_batches_through_workers(source: str, realdata: Path,
                                                            tmp_path: Path) -> None:
    build, agents = REAL_SAMPLES[source]
    # every frame (KITTI raw without tracklets has no annotated one)
    ds = FrameDataset(build(tmp_path), agents=agents, with_velocity=True, annotated_only=False)
    # At most 8 items, those with clouds and those without interleaved, so that batches of 4 mix them.
    with_points = [i for i in range(len(ds)) if ds[i]["points"]]
    without = [i for i in range(len(ds)) if i not in with_points]
    chosen = [i for pair in zip(with_points, without, strict=False) for i in pair][:8] or (with_points or without)[:8]
    # the Lyft sample's lidar files are cut to a few points (README): its frames have no cloud
    assert bool(with_points) == (source != "lyft"), with_points
    batches = batch_all_ways(Subset(ds, chosen), batch_size=4)
    if source == "kitti-tracking":
        # frames 0 and 1 ship sweeps, 2 and 3 do not: the README's crash (KeyError 'ego/velodyne')
        assert chosen[:4] == [0, 2, 1, 3]
        assert [c is None for c in batches["list"][0]["points"]["ego/velodyne"]] == [False, True, False, True]
        assert batches["padded"][0]["points_present"]["ego/velodyne"].tolist() == [True, False, True, False]
