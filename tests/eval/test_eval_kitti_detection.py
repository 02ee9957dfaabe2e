"""KITTI detection AP: hand-worked examples following the devkit's (Python port's) rules."""

import numpy as np
import pytest

from avdata.cli import main
from avdata.errors import InputError
from avdata.eval.detection.kitti import KittiObjects, evaluate_kitti_detection, load_kitti_objects
from tests.realdata import REALDATA


def _objects(rows):
    """rows: (image, name, occluded, bbox, location, rotation_y, score); truncation 0, hwl (1.5, 1.6, 4)."""
    n = len(rows)
    return KittiObjects(
        image=np.array([r[0] for r in rows], dtype=object),
        name=np.array([r[1] for r in rows], dtype=object),
        truncated=np.zeros(n),
        occluded=np.array([r[2] for r in rows], dtype=np.int64),
        alpha_rad=np.zeros(n),
        bbox_px=np.array([r[3] for r in rows], dtype=float).reshape(n, 4),
        dimensions_hwl_m=np.tile([1.5, 1.6, 4.0], (n, 1)),
        location_m=np.array([r[4] for r in rows], dtype=float).reshape(n, 3),
        rotation_y_rad=np.array([r[5] for r in rows], dtype=float),
        score=np.array([r[6] for r in rows], dtype=float),
    )


def _scene(image):
    gt = [
        (image, "Car", 0, [100, 100, 200, 200], [0, 1.5, 10], 0.0, 0),
        (image, "Van", 0, [300, 100, 400, 200], [5, 1.5, 10], 0.0, 0),
        (image, "DontCare", -1, [500, 100, 700, 200], [-1000, -1000, -1000], -10, 0),
        (image, "Car", 2, [800, 100, 900, 200], [10, 1.5, 10], 0.0, 0),  # heavily occluded: Hard only
    ]
    dt = [
        (image, "Car", 0, [302, 100, 402, 200], [5.1, 1.5, 10], 0.0, 0.8),  # on the Van: ignored match
        (image, "Car", 0, [550, 110, 650, 190], [20, 1.5, 30], 0.0, 0.7),  # inside DontCare, nowhere in 3D
        (image, "Car", 0, [104, 100, 204, 200], [0.1, 1.5, 10], 0.0, 0.6),  # on the Car
    ]
    return gt, dt


def test_dontcare_neighbour_class_and_difficulty():
    gt_rows, dt_rows = [], []
    for k in range(40):
        g, d = _scene(f"{k:06d}")
        gt_rows += g
        dt_rows += d
    res = evaluate_kitti_detection(_objects(gt_rows), _objects(dt_rows), classes=["Car"])
    ap11, ap40 = res.ap11["Car"], res.ap40["Car"]
    # 40 valid cars, each matched at score 0.6: the 40 thresholds are all 0.6 and fill precision points
    # 0..39 (point 40 stays 0). 2D: the Van match is ignored and the DontCare detection is absorbed, so
    # precision is 1: AP_11 = 10 / 11 (points 0, 4, ..., 36), AP_40 = 39 / 40.
    assert ap11["bbox"]["easy"] == pytest.approx(100 * 10 / 11)
    assert ap40["bbox"]["moderate"] == pytest.approx(100 * 39 / 40)
    # BEV / 3D have no DontCare: the detection there is a false positive, precision 1/2.
    assert ap11["bev"]["moderate"] == pytest.approx(50 * 10 / 11)
    assert ap40["3d"]["easy"] == pytest.approx(50 * 39 / 40)
    # Hard admits the occluded car, which nothing detects: 80 valid cars, 40 matched. Recall reaches only
    # 1/2: thresholds fill points 0..20 (one per score until recall 1/2, then the last score) with
    # precision 1 in 2D.
    assert ap40["bbox"]["hard"] == pytest.approx(100 * 20 / 40)
    assert ap11["bbox"]["hard"] == pytest.approx(100 * 6 / 11)
    # AOS: alphas all equal, so orientation similarity equals precision.
    assert res.ap40["Car"]["aos"]["easy"] == pytest.approx(ap40["bbox"]["easy"])


def test_single_object_devkit_quirk():
    # One ground truth found perfectly gives a single threshold, stored at precision point 0:
    # AP_11 = 100 / 11 and AP_40 = 0, exactly as the devkit reports it.
    gt = _objects([("a", "Pedestrian", 0, [0, 0, 50, 100], [0, 1.7, 8], 0.0, 0)])
    dt = _objects([("a", "Pedestrian", 0, [0, 0, 50, 100], [0, 1.7, 8], 0.0, 0.9)])
    res = evaluate_kitti_detection(gt, dt, classes=["Pedestrian"])
    assert res.ap11["Pedestrian"]["3d"]["easy"] == pytest.approx(100 / 11)
    assert res.ap40["Pedestrian"]["3d"]["easy"] == 0.0


def test_rotated_3d_overlap_below_threshold():
    # Same centre, rotation_y differs by 90 degrees: BEV overlap 1.6 x 1.6 of two 4 x 1.6 rectangles,
    # IoU 2.56 / (6.4 + 6.4 - 2.56) = 0.25 < 0.5, so the 3D match fails while 2D matches.
    rows_gt = [(f"{k}", "Cyclist", 0, [0, 0, 50, 100], [0, 1.5, 8], 0.0, 0) for k in range(40)]
    rows_dt = [(f"{k}", "Cyclist", 0, [0, 0, 50, 100], [0, 1.5, 8], np.pi / 2, 0.9) for k in range(40)]
    res = evaluate_kitti_detection(_objects(rows_gt), _objects(rows_dt), classes=["Cyclist"])
    assert res.ap40["Cyclist"]["bbox"]["easy"] == pytest.approx(97.5)
    assert res.ap40["Cyclist"]["bev"]["easy"] == 0.0
    # AOS: alpha equal (0) although rotation_y differs, so AOS follows the 2D precision.
    assert res.ap40["Cyclist"]["aos"]["easy"] == pytest.approx(97.5)


def test_read_label_files(tmp_path):
    label = tmp_path / "label_2"
    label.mkdir()
    (label / "000001.txt").write_text(
        "Car 0.00 0 -1.57 100.0 100.0 200.0 200.0 1.50 1.60 4.00 0.00 1.50 10.00 -1.57\n"
        "DontCare -1 -1 -10 500.0 100.0 700.0 200.0 -1 -1 -1 -1000 -1000 -1000 -10\n"
    )
    objs = load_kitti_objects(label)
    assert list(objs.name) == ["Car", "DontCare"]
    np.testing.assert_allclose(objs.dimensions_hwl_m[0], [1.5, 1.6, 4.0])
    (label / "000002.txt").write_text("Car 0 0\n")
    with pytest.raises(InputError, match=r"000002.txt: line 1: expected 15 fields \(16 with a score\), got 3"):
        load_kitti_objects(label)


def test_no_detections_gives_zero_ap():
    gt = _objects([("a", "Car", 0, [0, 0, 100, 100], [0, 1.5, 10], 0.0, 0)])
    res = evaluate_kitti_detection(gt, _objects([]), classes=["Car"])
    assert res.ap11["Car"]["bbox"]["easy"] == 0.0 and res.ap40["Car"]["3d"]["hard"] == 0.0
    assert "aos" not in res.ap11["Car"]


@pytest.mark.parametrize(("change", "message"), [
    # The score left out: the line was read as a label, score 0, and ranked last without a word.
    (lambda fields: fields[:15], "line 1: expected 16 fields (with the score), got 15"),
    # A type that is no KITTI type matched no class: the detection was dropped without a word.
    (lambda fields: ["Cra", *fields[1:]], "line 1: type: expected a KITTI type (car, van, truck, pedestrian, "
     "person_sitting, cyclist, tram, misc, dontcare, any case), got 'Cra'"),
])
def test_real_kitti_result_line_without_score_or_type_is_refused(tmp_path, capsys, change, message):
    labels = REALDATA / "kitti" / "object" / "training" / "label_2"
    results = tmp_path / "results"
    results.mkdir()
    for path in sorted(labels.glob("*.txt")):
        lines = [line.split()[:15] + ["0.9"] for line in path.read_text().splitlines() if line.split()]
        (results / path.name).write_text("\n".join(" ".join(fields) for fields in lines) + "\n")
    argv = ["eval", "detection", str(labels), str(results), "--protocol", "kitti"]
    assert main(argv) == 0
    capsys.readouterr()
    first = sorted(results.glob("*.txt"))[0]
    lines = first.read_text().splitlines()
    first.write_text("\n".join([" ".join(change(lines[0].split())), *lines[1:]]) + "\n")
    assert (main(argv), capsys.readouterr().err.splitlines()) == (1, [f"avdata: error: {first}: {message}"])
    # the devkit compares types with strcasecmp: "car" is a Car
    first.write_text("\n".join(line.replace("Car ", "car ") for line in lines) + "\n")
    assert main(argv) == 0
