"""Argoverse 2 detection tables: one built from the real annotations.feather, and hostile copies."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather
import pytest

from avdata.errors import InputError
from avdata.perception.detection_files import read_detections
from avdata.sources.argoverse2.detections import read_av2_detections
from tests.realdata import REALDATA

_LOG = "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"
_ANNOTATIONS = REALDATA / "argoverse2" / "sensor" / "val" / _LOG / "annotations.feather"


def _table() -> pa.Table:
    """The real cuboids as a detector's table: av2's columns plus log_id and score, without track_uuid."""
    table = feather.read_table(_ANNOTATIONS).drop_columns(["track_uuid", "num_interior_pts"])
    n = table.num_rows
    table = table.append_column("log_id", pa.array([_LOG] * n))
    return table.append_column("score", pa.array(np.linspace(0.05, 0.95, n)))


def test_real_annotations_as_a_detection_table(tmp_path):
    path = tmp_path / "detections.feather"
    feather.write_feather(_table(), path)
    truth = feather.read_table(_ANNOTATIONS).to_pydict()
    rows, problems = read_av2_detections(path)
    assert problems == [] and len(rows.columns["score"]) == len(truth["tx_m"])
    np.testing.assert_array_equal(rows.columns["tx_m"], truth["tx_m"])
    found = read_detections(path, "argoverse2")
    times = np.unique(truth["timestamp_ns"])
    frames = found.scenes[_LOG]
    assert sorted(frames) == list(range(len(times)))
    first = frames[0]
    in_first = np.asarray(truth["timestamp_ns"]) == times[0]
    assert first.timestamp_ns == times[0] and len(first) == int(in_first.sum())
    assert first.boxes.frame == "ego"
    np.testing.assert_array_equal(first.boxes.size_lwh[:, 0], np.asarray(truth["length_m"])[in_first])
    assert set(first.extras["category"].tolist()) <= set(truth["category"])


@pytest.mark.parametrize(("column", "value", "message"), [
    ("score", 1.5, "column 'score': expected a probability in [0, 1], got 1.5"),
    ("length_m", -1.0, "column 'length_m': expected a finite positive size"),
    ("qw", 3.0, "columns qw..qz: expected a unit quaternion"),
    ("tx_m", float("nan"), "column 'tx_m': expected a finite number"),
])
def test_a_bad_row_costs_itself(tmp_path, column, value, message):
    table = _table()
    values = table.column(column).to_pylist()
    values[7] = value
    table = table.set_column(table.column_names.index(column), column, pa.array(values))
    path = tmp_path / "detections.feather"
    feather.write_feather(table, path)
    rows, problems = read_av2_detections(path)
    assert len(rows.columns["score"]) == table.num_rows - 1 and len(problems) == 1
    assert problems[0].startswith(f"{path}: row 7: {message}"), problems[0]


def test_a_null_costs_its_row_and_a_missing_column_the_file(tmp_path):
    table = _table()
    values = table.column("category").to_pylist()
    values[3] = None
    path = tmp_path / "detections.feather"
    feather.write_feather(table.set_column(table.column_names.index("category"), "category", pa.array(values)), path)
    rows, problems = read_av2_detections(path)
    assert problems == [f"{path}: row 3: column 'category': expected a value, got null"]
    feather.write_feather(table.drop_columns(["score"]), path)
    with pytest.raises(InputError, match=r"missing \['score'\]"):
        read_av2_detections(path)
