"""Record encodings: the JSON text of per-object attributes and extras."""

from __future__ import annotations

import json
from typing import Any

import pytest

from avdata.schema.records import canonical_jsons


def reader_text(value: dict[str, Any]) -> str:
    """What a reader gets back: the stored text decoded and encoded again with sorted keys."""
    return json.dumps(json.loads(json.dumps(value)), sort_keys=True)


@pytest.mark.parametrize("values", [
    [],
    [{"b": 1, "a": "x"}],
    [{"visibility": "v1", "annotation_token": "t" * 32, "vehicle.moving": "true"}, {}, {"num_lidar_pts": 3.0}, {}],
    [{"note": "a}, {b"}, {"c": 1}],  # the boundary text inside a string: split refused, each encoded alone
    [{"note": "}, {"}, {"note": "}, {"}, {"z": None, "y": True, "x": -0.0, "w": 1e300}],
    [{"ünï": "cödé\n\"quoted\""}, {"a": float("nan")}],
    [{"nested": {"b": 1, "a": 2}}, {"flat": 1}],  # nested: decoded and encoded again
    [{10: 1, 9: 1}, {"flat": 2}],  # non-string keys: "10" sorts before "9" only once they are strings
])
def test_each_object_is_the_text_a_reader_re_encodes(values: list[dict[str, Any]]) -> None:
    assert canonical_jsons(values) == [reader_text(value) for value in values]
