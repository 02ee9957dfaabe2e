"""Studies with each kind of component: a model detector (by factory and checkpoint), a user's tracker and predictor."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
import yaml

from avdata.errors import InputError
from avdata.perception.bev import BevCenterNet, BevDetector, save_checkpoint
from avdata.studies import run_study
from avdata.studies.config import study_from_dict

SMALL = Path(__file__).with_name("small_study.yaml")


def _study(tmp_path: Path, cases: list[dict], trials: int = 1) -> object:
    data = yaml.safe_load(SMALL.read_text())
    data.update(cases=cases, trials=trials, plots=[])
    return study_from_dict(data, str(tmp_path / "study.yaml"))


@pytest.fixture(scope="module")
def components_out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("components")
    torch.manual_seed(0)
    save_checkpoint(BevDetector(BevCenterNet(2), ("car", "pedestrian")), tmp / "bev.pt")
    study = _study(tmp, [
        {"name": "sim", "detector": {"kind": "simulated", "noise": "none"}},
        {"name": "truth", "detector": {"kind": "model", "callable": "tests.studies.components:truth_detector"},
         "tracker": "tests.studies.components:still_tracker", "predictor": "tests.studies.components:stand_still"},
        {"name": "bev", "detector": {"kind": "model", "callable": "avdata.perception.bev:load_checkpoint",
                                     "checkpoint": "bev.pt"}},
    ])
    run_study(study, tmp / "out", progress=False)
    return tmp / "out"


def _result(out: Path, case: str) -> dict:
    return json.loads((out / "runs" / f"{case}__trial-0.json").read_text())["result"]


def test_model_detector_of_ground_truth_is_perfect(components_out: Path) -> None:
    """The items' own boxes, moved ego -> world by the pipeline, land on the evaluated ground truth."""
    truth = _result(components_out, "truth")
    assert truth["precision"] == 1.0 and truth["recall"] == 1.0
    assert truth["detector"] == "model:tests.studies.components:truth_detector"
    assert truth["predictor"] == "tests.studies.components:stand_still"
    assert truth["MOTA"] > 0.9


def test_simulated_noise_sets_the_ego_noise(components_out: Path) -> None:
    sim = _result(components_out, "sim")
    assert sim["axis_ego_noise"] == "none" and sim["detector"] == "simulated"


def test_checkpoint_model_runs_and_a_new_checkpoint_redoes_it(components_out: Path, tmp_path: Path) -> None:
    bev = _result(components_out, "bev")
    assert bev["detector"] == "model:bev.pt" and 0.0 <= bev["precision"] <= 1.0
    # An untrained network: low precision (its boxes are its prior's peaks, not objects).
    assert bev["precision"] < 0.2
    checkpoint = components_out.parent / "bev.pt"
    stamp = (components_out / "runs" / "bev__trial-0.json").stat().st_mtime_ns
    torch.manual_seed(1)
    save_checkpoint(BevDetector(BevCenterNet(2), ("car", "pedestrian")), checkpoint)
    study = _study(components_out.parent, [{"name": "bev", "detector": {
        "kind": "model", "callable": "avdata.perception.bev:load_checkpoint", "checkpoint": "bev.pt"}}])
    run_study(study, components_out, progress=False)
    assert (components_out / "runs" / "bev__trial-0.json").stat().st_mtime_ns != stamp


@pytest.mark.parametrize(("case", "message"), [
    ({"name": "a", "detector": {"kind": "camera"}}, "kind in"),
    ({"name": "a", "detector": {"kind": "files", "path": "x"}}, r"required \['format', 'path'\]"),
    ({"name": "a", "detector": {"kind": "model", "callable": "nocolon"}}, "pkg.mod:factory"),
    ({"name": "a", "detector": {"kind": "simulated", "noise": "loud"}}, "ego_noise"),
    ({"name": "a", "tracker": "sort"}, "expected tracker to be 'kalman'"),
    ({"name": "a", "comm_range_m": 50, "detector": {"kind": "model", "callable": "m:f"}}, "comm_range_m null"),
    ({"name": "a", "detector": {"kind": "model", "callable": "m:f", "checkpoint": "$NO_SUCH_VARIABLE_H6/x.pt"}},
     "NO_SUCH_VARIABLE_H6.*is not set"),
    ({"name": "a", "detector": {"kind": "model", "callable": "m:f", "min_score": "high"}}, "min_score to be float"),
    ({"name": "a", "datasets": ["kitti"]}, "a case's 'datasets' needs the study's 'datasets'"),
    ({"name": "a", "detector": {"kind": "files", "path": "x", "format": "csv"}}, r"expected detector.format in \['ab3dmot'"),
])
def test_bad_components_are_one_line(tmp_path: Path, case: dict, message: str) -> None:
    with pytest.raises(InputError, match=message):
        _study(tmp_path, [case])


def test_bad_dataset_lists_are_one_line(tmp_path: Path) -> None:
    data = yaml.safe_load(SMALL.read_text())
    data.update(datasets=[{"name": "x", "path": str(tmp_path)}], cases=[{"name": "a"}])
    with pytest.raises(InputError, match="expected datasets\\[0\\].path to be a unified dataset folder"):
        study_from_dict(data, str(tmp_path / "study.yaml"))



def test_model_detects_on_one_thread(components_out: Path) -> None:
    """A torch model detects on one thread whatever the executor (the thread count changes a convolution's last
    bits, so local processes and Ray workers wrote different bytes); the caller's setting is restored."""
    from avdata.schema import DatasetReader
    from avdata.studies.runner import run_pipeline, trial_dataset
    from tests.studies import components

    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        case = _study(components_out.parent, [{"name": "probe", "detector": {
            "kind": "model", "callable": "tests.studies.components:thread_probe"}}]).cases[0]
        components.SEEN_THREADS.clear()
        root = trial_dataset(components_out, 0)
        run_pipeline(root, DatasetReader(root).scenes[0], case)
        assert components.SEEN_THREADS == {1} and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(threads)
