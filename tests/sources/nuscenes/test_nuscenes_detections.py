"""nuScenes detection submissions: one built from the real Lyft annotations (nuScenes schema), and hostile copies."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from avdata.errors import InputError
from avdata.perception.detection_files import read_detections
from avdata.sources.nuscenes.detections import read_nuscenes_submission
from tests.realdata import REALDATA

_ANNOTATIONS = REALDATA / "nuscenes_schema" / "lyft" / "v1.01-train" / "v1.01-train" / "sample_annotation.json"


def _submission() -> dict:
    """The real annotations as a detector's results: global boxes, sizes w, l, h, quaternions w, x, y, z."""
    results: dict[str, list] = {}
    for k, ann in enumerate(json.loads(_ANNOTATIONS.read_text())):
        results.setdefault(ann["sample_token"], []).append({
            "sample_token": ann["sample_token"], "translation": ann["translation"], "size": ann["size"],
            "rotation": ann["rotation"], "velocity": [float("nan"), 0.5], "detection_name": "car",
            "detection_score": 0.5 + 0.1 * k, "attribute_name": "vehicle.parked"})
    return {"meta": {"use_lidar": True}, "results": results}


def test_real_annotations_as_a_submission(tmp_path):
    path = tmp_path / "results.json"
    path.write_text(json.dumps(_submission()))
    annotations = json.loads(_ANNOTATIONS.read_text())
    rows, problems = read_nuscenes_submission(path)
    assert problems == [] and len(rows) == len(annotations) == 4
    first = annotations[0]
    np.testing.assert_array_equal(rows.center_world_m[0], first["translation"])
    w, l, h = first["size"]
    np.testing.assert_array_equal(rows.size_lwh_m[0], [l, w, h])
    # the stored quaternion is unit within float noise, so it is kept as given (w first)
    np.testing.assert_allclose(rows.quat_wxyz[0], first["rotation"], atol=1e-15)
    assert np.isnan(rows.velocity_world_mps[0, 0]) and rows.velocity_world_mps[0, 1] == 0.5
    found = read_detections(path, "nuscenes")
    dets = found.scenes[first["sample_token"]][0]
    assert dets.boxes.frame == "world" and dets.boxes.classes.tolist()[0] == "car"
    assert dets.scores[0] == pytest.approx(0.5) and dets.extras["attribute_name"][0] == "vehicle.parked"


@pytest.mark.parametrize(("field", "value", "message"), [
    ("size", [1.0, -2.0, 1.5], "field size: expected positive sizes, got [1.0, -2.0, 1.5]"),
    ("translation", [1.0, "x", 2.0], "field translation: expected 3 finite numbers, got [1.0, 'x', 2.0]"),
    ("rotation", [2.0, 0.0, 0.0, 0.0], "field rotation: expected a unit quaternion"),
    ("detection_score", 3.2, "field detection_score: expected a number in [0, 1], got 3.2"),
    ("detection_name", "Car", "field detection_name: expected one of car, truck"),
    ("attribute_name", "parked", "field attribute_name: expected a nuScenes attribute or '', got 'parked'"),
    ("velocity", None, "field velocity: expected 2 numbers, got none"),
])
def test_a_bad_box_costs_itself(tmp_path, field, value, message):
    data = _submission()
    token = next(iter(data["results"]))
    bad = copy.deepcopy(data)
    if value is None:
        del bad["results"][token][0][field]
    else:
        bad["results"][token][0][field] = value
    path = tmp_path / "results.json"
    path.write_text(json.dumps(bad))
    rows, problems = read_nuscenes_submission(path)
    assert len(rows) == 3 and len(problems) == 1
    assert problems[0].startswith(f"{path}: results[{token!r}][0]: {message}"), problems[0]
    assert "\n" not in problems[0]


def test_a_file_that_is_no_submission_is_one_error(tmp_path):
    path = tmp_path / "results.json"
    path.write_text('{"meta": {}}')
    with pytest.raises(InputError, match=r"results.json: expected a 'results' object"):
        read_nuscenes_submission(path)
    path.write_text('{"results": {')
    with pytest.raises(InputError, match=r"results.json: cannot read a nuScenes submission"):
        read_nuscenes_submission(path)


def test_a_quaternion_off_by_more_than_float_noise_is_kept_normalised_with_a_warning(tmp_path):
    data = _submission()
    token = next(iter(data["results"]))
    data["results"][token][0]["rotation"] = [1.001, 0.0, 0.0, 0.0]
    data["results"]["not-a-list"] = {"translation": [0, 0, 0]}
    path = tmp_path / "results.json"
    path.write_text(json.dumps(data))
    rows, problems = read_nuscenes_submission(path)
    assert problems == [f"{path}: results['not-a-list']: expected a list of boxes, got dict"]
    assert len(rows) == 4 and rows.quat_wxyz[0].tolist() == [1.0, 0.0, 0.0, 0.0]
    assert len(rows.repaired) == 1 and rows.repaired[0].startswith(f"{path}: results[{token!r}][0]: field rotation: ")
    assert "normalised" in rows.repaired[0]
    assert read_detections(path, "nuscenes").warnings == list(rows.repaired)
