"""DataLoader workers, DistributedSampler and the collate functions."""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import torch
from torch.utils.data import DataLoader, DistributedSampler

from avdata.loaders import Collaboration, FrameDataset, FrameOptions, LabelFilter, SequenceDataset, collate_list, collate_padded


def unchanged(item: dict[str, Any]) -> dict[str, Any]:
    """Per-sample collate that keeps the item as is (torch's default turns tuples into lists)."""
    return item


def assert_items_equal(a: Any, b: Any) -> None:
    assert type(a) is type(b)
    if isinstance(a, dict):
        assert list(a) == list(b)
        for key in a:
            assert_items_equal(a[key], b[key])
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            assert_items_equal(x, y)
    elif isinstance(a, torch.Tensor):
        assert a.dtype == b.dtype and torch.equal(a, b)
    else:
        assert a == b


def test_two_workers_give_the_items_of_the_main_process(dataset: Path) -> None:
    options = FrameOptions(sensors=("*/lidar*", "ego/cam_front"), labels=LabelFilter(visible_to="*"), with_velocity=True,
                           collaboration=Collaboration(agents=("*",), rate_hz=5.0, noise_std_m=0.1))
    ds = FrameDataset(dataset, options, scenes=["v2i"])
    expected = [ds[i] for i in range(len(ds))]
    loader = DataLoader(ds, batch_size=None, num_workers=2, collate_fn=unchanged)
    assert len(list(loader)) == 3
    for item, want in zip(loader, expected, strict=True):
        assert_items_equal(item, want)


def test_a_batch_is_one_buffer_and_equals_its_items(dataset: Path) -> None:
    options = FrameOptions(sensors=("*/lidar*",), collaboration=Collaboration(agents=("*",), fusion="early"),
                           with_quaternions=True)
    ds = FrameDataset(dataset, options, scenes=["v2i"])
    batch = ds.__getitems__([2, 0, -2])
    assert [item["frame_index"] for item in batch] == [2, 0, 1]
    tensors = [t for item in batch for t in (item["points"]["fused"], item["boxes"], item["labels"], item["agent_poses"])]
    assert len({t.untyped_storage().data_ptr() for t in tensors}) == 1
    for item, index in zip(batch, [2, 0, 1], strict=True):
        assert_items_equal(item, ds[index])
    # through workers (the DataLoader calls __getitems__ once per batch) the batches are the same
    loader = DataLoader(ds, batch_size=2, num_workers=1, collate_fn=collate_list)
    batches = list(loader)
    assert_items_equal(batches[0], collate_list([ds[0], ds[1]]))
    assert_items_equal(batches[1], collate_list([ds[2]]))


def test_worker_batches_arrive_in_shared_memory_and_outlive_the_next_batches(dataset: Path) -> None:
    # A worker assembles each batch in scratch memory it reuses: every batch must still hold its
    # own values after the worker has produced the next ones, in one shared storage per batch.
    ds = FrameDataset(dataset, sensors="*/lidar*", frame="world", agents="*", scenes=["v2i"])
    items = list(DataLoader(ds, batch_size=None, num_workers=1, collate_fn=unchanged))
    assert len(items) == len(ds) == 3
    for index, item in enumerate(items):
        assert_items_equal(item, ds[index])
        tensors = [*item["points"].values(), item["boxes"], item["labels"], item["agent_poses"]]
        assert len({t.untyped_storage().data_ptr() for t in tensors}) == 1
        assert all(t.is_shared() for t in tensors)


def test_the_file_system_sharing_strategy_gives_the_same_items(dataset: Path) -> None:
    strategy = torch.multiprocessing.get_sharing_strategy()
    ds = FrameDataset(dataset, sensors="*/lidar*", agents="*", scenes=["v2i"])
    try:
        torch.multiprocessing.set_sharing_strategy("file_system")
        batches = list(DataLoader(ds, batch_size=2, num_workers=1, collate_fn=collate_list))
    finally:
        torch.multiprocessing.set_sharing_strategy(strategy)
    assert_items_equal(batches[0], collate_list([ds[0], ds[1]]))
    assert_items_equal(batches[1], collate_list([ds[2]]))


def test_spawned_workers_unpickle_the_dataset_and_reopen_readers(dataset: Path) -> None:
    ds = SequenceDataset(dataset, past_frames=2, sensors="ego/lidar_top")
    ds[0]  # opens readers in this process; they must not travel to the workers
    assert pickle.loads(pickle.dumps(ds)).frames._scenes_open == {}
    loader = DataLoader(ds, batch_size=2, num_workers=2, collate_fn=collate_list, multiprocessing_context="spawn")
    batches = list(loader)
    assert len(ds) == 4 and len(batches) == 2
    assert_items_equal(batches[0], collate_list([ds[0], ds[1]]))
    assert_items_equal(batches[1], collate_list([ds[2], ds[3]]))


def test_distributed_sampler_splits_the_frames_between_ranks(dataset: Path) -> None:
    ds = FrameDataset(dataset, sensors="ego/lidar_top")
    seen = []
    for rank in range(2):
        sampler = DistributedSampler(ds, num_replicas=2, rank=rank, shuffle=True, seed=1)
        sampler.set_epoch(0)
        indices = list(sampler)
        loader = DataLoader(ds, sampler=sampler, batch_size=None, num_workers=0, collate_fn=unchanged)
        for index, item in zip(indices, loader, strict=True):
            assert (item["scene"], item["frame_index"]) == ds.keys()[index]
        seen.extend(indices)
    assert sorted(seen) == list(range(len(ds)))


def test_collate_padded_pads_with_masks(dataset: Path) -> None:
    ds = FrameDataset(dataset, sensors="ego/lidar_top", agents=["*"], scenes=["v2i"])
    items = [FrameDataset(dataset, scenes=["v2i"], sensors="ego/lidar_top", agents=["*"], classes=["car"])[0], ds[2]]
    batch = collate_padded(items)
    sizes = [len(i["points"]["ego/lidar_top"]) for i in items]
    cloud, mask = batch["points"]["ego/lidar_top"], batch["points_mask"]["ego/lidar_top"]
    assert cloud.shape == (2, max(sizes), 4) and mask.shape == (2, max(sizes))
    assert mask.sum(1).tolist() == sizes
    assert torch.equal(cloud[0, : sizes[0]], items[0]["points"]["ego/lidar_top"])
    assert float(cloud[0, sizes[0]:].abs().sum()) == 0.0
    assert batch["boxes"].shape == (2, 4, 7) and batch["boxes_mask"].tolist() == [[True, False, False, False],
                                                                                     [True] * 4]
    assert batch["labels"][0].tolist() == [0, -1, -1, -1]
    assert batch["visible_by"].shape == (2, 4, 4)
    assert batch["visible_by_mask"].tolist() == batch["boxes_mask"].tolist()
    assert batch["object_ids"] == [["a"], ["a", "b", "c", "d"]]
    assert batch["frame_index"] == [0, 2] and batch["scene"] == ["v2i", "v2i"]
    assert batch["agent_poses"].shape == (2, 4, 4, 4)


def test_collate_list_keeps_variable_sizes_as_lists(dataset: Path) -> None:
    ds = FrameDataset(dataset, sensors=["ego/lidar_top", "ego/cam_front"], scenes=["v2i"])
    batch = collate_list([ds[0], ds[1]])
    assert [len(c) for c in batch["points"]["ego/lidar_top"]] == [len(ds[0]["points"]["ego/lidar_top"]),
                                                                  len(ds[1]["points"]["ego/lidar_top"])]
    assert isinstance(batch["boxes"], list) and len(batch["boxes"]) == 2
    assert batch["images"]["ego/cam_front"].shape == (2, 3, 6, 8)
    assert batch["projections"]["ego/cam_front"].shape == (2, 3, 4)
    assert batch["timestamp_ns"] == [ds[0]["timestamp_ns"], ds[1]["timestamp_ns"]]


def test_items_without_points_or_boxes_cross_workers(dataset: Path) -> None:
    ds = FrameDataset(dataset, FrameOptions(sensors=(), labels=LabelFilter(visible_to="infra_01/lidar")), scenes=["v2i"])
    batches = list(DataLoader(ds, batch_size=2, num_workers=1, collate_fn=collate_list))
    assert [[tuple(b.shape) for b in batch["boxes"]] for batch in batches] == [[(0, 7), (0, 7)], [(0, 7)]]
    assert all(batch["points"] == {} for batch in batches)


def test_a_camera_or_key_missing_from_some_items_is_none_or_zero_filled_with_presence(dataset: Path) -> None:
    with_camera = FrameDataset(dataset, sensors=["ego/lidar_top", "ego/cam_front"], scenes=["v2i"],
                               with_quaternions=True)[0]
    without = FrameDataset(dataset, sensors=["ego/lidar_top"], scenes=["v2i"])[1]
    listed = collate_list([with_camera, without])
    assert torch.equal(listed["images"]["ego/cam_front"][0], with_camera["images"]["ego/cam_front"])
    assert listed["images"]["ego/cam_front"][1] is None
    assert listed["calibrations"]["ego/cam_front"]["width"] == [8, None]
    assert listed["calibrations"]["ego/cam_front"]["K"][1] is None
    assert listed["sensor_timestamps_ns"]["ego/cam_front"] == [with_camera["sensor_timestamps_ns"]["ego/cam_front"], None]
    assert listed["boxes_quat_wxyz"][1] is None and "boxes_quat_wxyz_present" not in listed
    padded = collate_padded([with_camera, without])
    images = padded["images"]["ego/cam_front"]
    assert images.shape == (2, 3, 6, 8) and torch.equal(images[0], with_camera["images"]["ego/cam_front"])
    assert not images[1].any()
    assert padded["images_present"]["ego/cam_front"].tolist() == [True, False]
    assert padded["calibrations_present"]["ego/cam_front"].tolist() == [True, False]
    assert padded["calibrations"]["ego/cam_front"]["K"].shape == (2, 3, 3) and float(padded["calibrations"][
        "ego/cam_front"]["K"][0, 0, 0]) == 100.0
    assert padded["points_present"]["ego/lidar_top"].tolist() == [True, True]
    assert "point_fields_present" not in padded and padded["point_fields"]["ego/lidar_top"][1] == ("x", "y", "z", "intensity")
    # a top-level key only one item has (differently configured datasets)
    assert padded["boxes_quat_wxyz_present"].tolist() == [True, False]
    assert padded["boxes_quat_wxyz_mask"].sum(1).tolist() == [4, 0]
