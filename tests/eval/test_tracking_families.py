"""The registry of tracking metric families: every registered name finds its one declaration."""

import importlib

import numpy as np
import pytest

from avdata.eval.tracking import COMBINED, Similarity, TrackingMetric, TrackingSequence, evaluate_tracking, family_of
from avdata.eval.tracking import results as results_module


def test_every_registered_family_is_declared_by_its_module_and_computes_its_fields():
    box = np.array([[0.0, 0.0, 10.0, 10.0], [20.0, 0.0, 30.0, 10.0]])
    seq = TrackingSequence.from_boxes(
        num_frames=2, gt_frame=np.array([0, 1]), gt_id=np.array([1, 1]), gt_boxes=box,
        tracker_frame=np.array([0, 1]), tracker_id=np.array([7, 7]), tracker_boxes=box + 1.0,
        similarity=Similarity.IOU_2D,
    )
    out = evaluate_tracking({"a": seq}, list(TrackingMetric))
    for metric in TrackingMetric:
        declared = family_of(metric)
        assert declared.metric is metric
        assert declared.compute.__module__ == f"avdata.eval.tracking.{metric.name.lower()}"
        for name in ("a", COMBINED):
            assert list(out[name][metric]) and set(out[name][metric]) == {f.value for f in declared.fields}


def test_a_module_without_its_declaration_is_named(monkeypatch):
    # The package exports the function ``vace``, which hides the module of the same name as an attribute.
    vace_module = importlib.import_module("avdata.eval.tracking.vace")
    monkeypatch.setattr(vace_module, "FAMILY", None)
    monkeypatch.setattr(results_module, "_LOADED", {})
    with pytest.raises(TypeError, match=r"avdata\.eval\.tracking\.vace: expected FAMILY, a MetricFamily of VACE"):
        family_of(TrackingMetric.VACE)
