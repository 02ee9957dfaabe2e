"""The camera detector and the 2D metrics of studies: projection, 2D IoU and counts worked by hand, then a study."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from avdata.errors import InputError
from avdata.eval.detection.image import frame_counts_2d
from avdata.eval.geometry import box2d_iou
from avdata.frames import Boxes3D
from avdata.studies import run_study, write_report
from avdata.studies.config import study_from_dict

SMALL = Path(__file__).with_name("small_study.yaml")

# A pinhole camera: f = 100 px, principal point (50, 40), a 100 x 80 image, points in its optical frame.
_P = np.array([[100.0, 0.0, 50.0, 0.0], [0.0, 100.0, 40.0, 0.0], [0.0, 0.0, 1.0, 0.0]])


def _cube(x: float, z: float) -> Boxes3D:
    """A 2 m cube centred at (x, 0, z) of the optical frame, axis-aligned."""
    return Boxes3D(center=[[x, 0.0, z]], size_lwh=[[2.0, 2.0, 2.0]], quat_wxyz=[[1.0, 0.0, 0.0, 0.0]], frame="cam")


def test_a_hand_placed_box_projects_to_its_exact_rectangle() -> None:
    # Corners at x, y = +-1 and z = 9 or 11: the nearest face bounds the image, u = 50 +- 100 / 9, v = 40 +- 100 / 9.
    xyxy, truncation, in_image = _cube(0.0, 10.0).image_boxes(_P, (100, 80))
    assert xyxy[0] == pytest.approx([50 - 100 / 9, 40 - 100 / 9, 50 + 100 / 9, 40 + 100 / 9], abs=1e-12)
    assert truncation[0] == pytest.approx(0.0) and in_image[0]
    # Moved 4 m right: u spans 50 + 100 * 3 / 11 .. 50 + 100 * 5 / 9 = 77.27 .. 105.56, clipped at the last pixel (99).
    xyxy, truncation, in_image = _cube(4.0, 10.0).image_boxes(_P, (100, 80))
    assert xyxy[0] == pytest.approx([50 + 300 / 11, 40 - 100 / 9, 99.0, 40 + 100 / 9], abs=1e-12)
    assert truncation[0] == pytest.approx(1 - (99 - 50 - 300 / 11) / (500 / 9 - 300 / 11))
    # Behind the camera: no rectangle.
    xyxy, _, in_image = _cube(0.0, -10.0).image_boxes(_P, (100, 80))
    assert np.all(np.isnan(xyxy)) and not in_image[0]


def test_2d_iou_worked_by_hand() -> None:
    # Two 4 x 4 squares overlapping in a 2 x 2 square: 4 / (16 + 16 - 4) = 1 / 7.
    assert box2d_iou([[0, 0, 4, 4]], [[2, 2, 6, 6]])[0, 0] == pytest.approx(1 / 7)
    assert box2d_iou([[0, 0, 4, 4]], [[0, 0, 4, 2]])[0, 0] == pytest.approx(0.5)
    assert box2d_iou([[0, 0, 4, 4]], [[5, 5, 6, 6]])[0, 0] == 0.0


def test_2d_counts_worked_by_hand() -> None:
    evaluated = [[0, 0, 10, 10], [20, 0, 30, 10]]
    ignored = [[40, 0, 50, 10]]
    detections = [[0, 0, 10, 8],    # IoU 0.8 with the first, but the next is better: a false positive
                  [1, 0, 10, 10],   # IoU 0.9 with the first: the match
                  [41, 0, 50, 10],  # IoU 0.9 with the ignored box: neither hit nor false positive
                  [20, 0, 24, 10]]  # IoU 0.4 with the second: below 0.5, a false positive
    assert frame_counts_2d(detections, evaluated, ignored) == (1, 2, 1)  # precision 1/3, recall 1/2
    assert frame_counts_2d(np.zeros((0, 4)), evaluated, ignored) == (0, 0, 2)
    assert frame_counts_2d(detections, np.zeros((0, 4)), np.zeros((0, 4))) == (0, 4, 0)


def _camera_study(tmp_path: Path, cases: list[dict]) -> object:
    data = yaml.safe_load(SMALL.read_text())
    data["overrides"]["egos"][0]["sensors"].append(
        {"name": "cam_front", "kind": "camera", "mount_xyz_m": [2.0, 0.0, 1.65],
         "camera": {"width": 1242, "height": 375, "horizontal_fov_deg": 81}})
    data.update(cases=cases, trials=1, frames=6, plots=[])
    return study_from_dict(data, str(tmp_path / "study.yaml"))


@pytest.fixture(scope="module")
def camera_out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("camera")
    study = _camera_study(tmp, [
        {"name": "cam-none", "detector": {"kind": "simulated", "noise": "none", "camera": "ego/cam_front"}},
        {"name": "cam-high", "detector": {"kind": "simulated", "noise": "high",
                                          "camera": ["ego/cam2", "ego/cam_front"]}},
        {"name": "lidar", "detector": {"kind": "simulated", "noise": "none"}},
    ])
    run_study(study, tmp / "out", progress=False)
    return tmp / "out"


def _run(out: Path, case: str) -> dict:
    return json.loads((out / "runs" / f"{case}__trial-0.json").read_text())


def test_a_perfect_camera_detector_scores_2d_precision_one(camera_out: Path) -> None:
    run = _run(camera_out, "cam-none")
    result, frames = run["result"], run["frames"]
    assert result["detector"] == "simulated:camera"
    # Exact boxes projected as the ground truth is: every 2D detection lands on its object (IoU 1).
    assert result["precision_2d"] == 1.0
    assert sum(frames["tp_2d"]) > 10 and result["recall_2d"] > 0.9
    assert result["recall_2d"] == sum(frames["tp_2d"]) / (sum(frames["tp_2d"]) + sum(frames["fn_2d"]))
    # The camera sees its 81 degrees only: fewer of the evaluated objects (all around the ego) in 3D.
    assert result["recall"] < _run(camera_out, "lidar")["result"]["recall"]


def test_noise_costs_2d_precision_and_recall(camera_out: Path) -> None:
    high, none = _run(camera_out, "cam-high")["result"], _run(camera_out, "cam-none")["result"]
    assert high["precision_2d"] < none["precision_2d"] and high["recall_2d"] < none["recall_2d"]
    assert 0.0 < high["precision_2d"] < 1.0


def test_a_lidar_detector_has_no_2d_scores(camera_out: Path) -> None:
    run = _run(camera_out, "lidar")
    assert run["result"]["precision_2d"] is None and run["result"]["recall_2d"] is None
    assert "tp_2d" not in run["frames"]


def test_report_csv_and_page_hold_the_2d_columns(camera_out: Path) -> None:
    write_report(camera_out)
    md = (camera_out / "report.md").read_text()
    assert "| precision | recall | precision_2d | recall_2d |" in md
    lidar_row = next(line for line in md.splitlines() if line.startswith("| lidar |"))
    assert "| N/A | N/A |" in lidar_row
    csv = (camera_out / "report.csv").read_text().splitlines()
    header = csv[0].split(",")
    assert {"precision_2d_mean", "precision_2d_std", "recall_2d_mean", "recall_2d_std"} <= set(header)
    cam = dict(zip(header, next(line for line in csv if line.startswith("cam-none,")).split(","), strict=True))
    assert float(cam["precision_2d_mean"]) == 1.0
    assert "precision_2d" in (camera_out / "report.html").read_text()


def test_a_study_without_a_camera_has_no_2d_columns(camera_out: Path, tmp_path: Path) -> None:
    import shutil

    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    out = tmp_path / "lidar-only"
    shutil.copytree(camera_out, out)
    results = pq.read_table(out / "results.parquet")
    pq.write_table(results.filter(pc.equal(results["case"], "lidar")), out / "results.parquet")
    write_report(out)
    assert "precision_2d" not in (out / "report.md").read_text()


@pytest.mark.parametrize(("detector", "message"), [
    ({"kind": "simulated", "camera": 3}, "expected detector.camera to be a camera name or a list of them, got 3"),
    ({"kind": "simulated", "camera": []}, "expected detector.camera to be a camera name or a list of them, got []"),
    ({"kind": "model", "callable": "a.b:c", "camera": "ego/cam2"}, "expected keys"),
])
def test_camera_settings_are_checked(tmp_path: Path, detector: dict, message: str) -> None:
    with pytest.raises(InputError, match=r"cases\[0\]") as error:
        _camera_study(tmp_path, [{"name": "c", "detector": detector}])
    assert message in str(error.value) and "\n" not in str(error.value)


def test_a_camera_detector_does_not_collaborate(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="expected comm_range_m null with a simulated:camera detector"):
        _camera_study(tmp_path, [{"name": "c", "comm_range_m": 50,
                                  "detector": {"kind": "simulated", "camera": "ego/cam_front"}}])


def test_a_scene_without_the_camera_is_one_line(tmp_path: Path) -> None:
    from avdata.errors import AvdataError

    study = _camera_study(tmp_path, [{"name": "c", "detector": {"kind": "simulated", "camera": ["ego/cam2"]}}])
    with pytest.raises(AvdataError) as error:
        run_study(study, tmp_path / "out", progress=False)
    text = str(error.value)
    assert "has none of ['ego/cam2']; its cameras are ['ego/cam_front']" in text and "\n" not in text


def test_files_without_2d_boxes_cannot_name_a_camera(camera_out: Path, tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """A format whose detections carry no 2D boxes (e.g. a nuScenes submission) with ``camera`` is one line."""
    from avdata.perception import detection_files
    from avdata.perception.detections import Detections
    from avdata.schema import DatasetReader
    from avdata.studies.config import CaseConfig, DetectorConfig
    from avdata.studies.runner import run_pipeline

    root = camera_out / "trials" / "trial-0"
    scene = DatasetReader(root).scenes[0]
    boxes = Boxes3D(center=[[5.0, 0.0, 1.0]], size_lwh=[[4.0, 2.0, 1.5]], quat_wxyz=[[1.0, 0.0, 0.0, 0.0]],
                    frame="world", classes=["car"])
    found = detection_files.DetectionFiles(scenes={scene: {0: Detections(
        boxes=boxes, scores=np.ones(1), sensors=np.array(["x"]), timestamp_ns=0)}})
    monkeypatch.setattr(detection_files, "read_detections", lambda *_args, **_kwargs: found)
    case = CaseConfig(name="f", detector=DetectorConfig(kind="files", path=str(tmp_path), format="nuscenes",
                                                        cameras=("ego/cam_front",)))
    with pytest.raises(InputError, match=r"^case f: detector.camera: the nuscenes detections of .* carry no 2D boxes$"):
        run_pipeline(root, scene, case)
