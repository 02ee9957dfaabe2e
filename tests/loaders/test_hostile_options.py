"""Hostile loader options: wrong types, non-finite values and names that match nothing are refused when the
options or the dataset are made, with the option and the value named; never a TypeError, a ZeroDivisionError
or an OverflowError at the first item, and never items silently emptied or filled with NaN."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from avdata.errors import AvdataError
from avdata.loaders import Collaboration, FrameDataset, FrameOptions, LabelFilter, SequenceDataset


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"max_range_m": "50"}, "expected max_range_m as a number or None, got '50'"),
        ({"min_points": "5", "visible_to": "*"}, "expected min_points as a number or None, got '5'"),
        ({"max_occlusion": "1", "visible_to": "*"}, "expected max_occlusion as a number or None, got '1'"),
        # NaN compared false with every count: each object was dropped without a word
        ({"min_points": math.nan, "visible_to": "*"}, "expected min_points >= 0, got nan"),
        ({"visible_to": 5}, "expected visible_to as a string or a sequence of strings, got 5"),
        ({"classes": 5}, "expected classes as a string or a sequence of strings, got 5"),
    ],
)
def test_label_filter_names_the_bad_value(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(AvdataError) as raised:
        LabelFilter(**kwargs)
    assert str(raised.value) == message


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"comm_range_m": "50"}, "expected comm_range_m as a number or None, got '50'"),
        # infinite rate: a slot of 0 s (ZeroDivisionError at the first item)
        ({"rate_hz": math.inf}, "expected a finite positive rate for agents '*', got inf Hz"),
        # infinite latency: OverflowError at the first item
        ({"latency_ms": {"infra_*": math.inf}}, "expected a finite non-negative latency for agents 'infra_*', got inf ms"),
        # infinite noise: every received cloud NaN / inf, items served without a word
        ({"noise_std_m": math.inf}, "expected a finite non-negative noise for agents '*', got inf m"),
        ({"pose_noise": (0.1, 0.1, 0.0, math.inf)},
         "expected pose_noise as four finite non-negative sigmas (x_m, y_m, z_m, yaw_deg), got (0.1, 0.1, 0.0, inf)"),
        ({"pose_noise": "abcd"},
         "expected pose_noise as four finite non-negative sigmas (x_m, y_m, z_m, yaw_deg), got 'abcd'"),
        ({"rate_hz": {"*": "fast"}}, "expected rate_hz as a number or a mapping agent pattern -> number, got {'*': 'fast'}"),
        ({"noise_std_m": (("*", "x"),)},
         "expected noise_std_m as a number or a mapping agent pattern -> number, got (('*', 'x'),)"),
        # numpy's generators refuse these, at the first noised item
        ({"seed": -1}, "expected seed as an integer >= 0, got -1"),
        ({"seed": 1.5}, "expected seed as an integer >= 0, got 1.5"),
        ({"seed": "7"}, "expected seed as an integer >= 0, got '7'"),
        ({"max_agents": True}, "expected max_agents >= 1, got True"),
    ],
)
def test_collaboration_names_the_bad_value(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(AvdataError) as raised:
        Collaboration(agents=("*",), **kwargs)
    assert str(raised.value) == message


def test_collaboration_keeps_good_numbers_of_every_kind() -> None:
    import numpy as np

    link = Collaboration(agents="*", rate_hz={"infra_*": np.float32(5.0)}, latency_ms=100, seed=np.int64(3),
                         pose_noise=[0.5, 0.5, 0.0, 1])
    assert link.rate_of("infra_02") == 5.0 and link.rate_of("ego") is None
    assert link.latency_ns_of("cav_1") == 100_000_000
    assert link.pose_noise == (0.5, 0.5, 0.0, 1.0)


def test_unknown_split_is_refused_with_the_splits_present(dataset: Path) -> None:
    with pytest.raises(AvdataError, match=r"expected a split of the dataset \[.*\], got split='tarin'"):
        FrameDataset(dataset, split="tarin")


def test_one_scene_name_is_one_scene(dataset: Path) -> None:
    by_name = FrameDataset(dataset, scenes="v2i")
    assert by_name.keys() == FrameDataset(dataset, scenes=["v2i"]).keys()
    assert {scene for scene, _ in by_name.keys()} == {"v2i"}
    with pytest.raises(AvdataError, match=r"expected scenes as a string or a sequence of strings, got 3"):
        FrameDataset(dataset, scenes=3)  # type: ignore[arg-type]  # the wrong type is the point


def test_visible_to_matching_no_sensor_is_refused(dataset: Path) -> None:
    # a typo'd sensor used to drop every object of every item
    with pytest.raises(AvdataError, match=r"expected a sensor matching visible_to 'ego/lidar_tpo', got \[.*'ego/lidar_top'"):
        FrameDataset(dataset, FrameOptions(labels=LabelFilter(visible_to="ego/lidar_tpo")), scenes=["v2i"])


def test_fractional_indices_are_refused_not_truncated(dataset: Path) -> None:
    frames = FrameDataset(dataset, scenes=["v2i"])
    assert frames[1]["frame_index"] == 1
    with pytest.raises(TypeError):
        frames[1.5]  # type: ignore[index]  # used to return item 1
    windows = SequenceDataset(dataset, past_frames=1, scenes=["v2i"])
    with pytest.raises(TypeError):
        windows[0.5]  # type: ignore[index]  # used to return window 0


@pytest.mark.parametrize("counts", [{"past_frames": 1.5}, {"past_frames": "2"}, {"past_frames": 1, "stride": True}])
def test_sequence_counts_must_be_integers(dataset: Path, counts: dict[str, Any]) -> None:
    with pytest.raises(AvdataError, match="expected past_frames >= 1, future_frames >= 0, stride >= 1"):
        SequenceDataset(dataset, scenes=["v2i"], **counts)
