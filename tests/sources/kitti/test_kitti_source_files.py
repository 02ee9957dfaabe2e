"""``avdata.sources.kitti`` readers and formulas against the real KITTI files and the devkit's formulas."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from avdata.errors import InputError
from avdata.frames import rotations
from avdata.sources.kitti import compute_box_3d, read_calib, read_labels
from tests.realdata import REALDATA

REAL = REALDATA / "kitti"
#: The three real samples (named, not listed: nothing is read at import)
LABELS = [REAL / "object" / "training" / "label_2" / f"{name}.txt" for name in ("000000", "000001", "000002")]


def devkit_compute_box_3d(hwl: np.ndarray, location: np.ndarray, ry: np.ndarray) -> np.ndarray:
    """The devkit's ``compute_box_3d`` (MATLAB ``computeBox3D.m``), written out: (N, 8, 3)."""
    h, w, l = hwl.T
    x = np.stack([l / 2, l / 2, -l / 2, -l / 2, l / 2, l / 2, -l / 2, -l / 2], axis=1)
    y = np.stack([0 * h, 0 * h, 0 * h, 0 * h, -h, -h, -h, -h], axis=1)
    z = np.stack([w / 2, -w / 2, -w / 2, w / 2, w / 2, -w / 2, -w / 2, w / 2], axis=1)
    c, s = np.cos(ry)[:, None], np.sin(ry)[:, None]
    return np.stack([c * x + s * z, y, -s * x + c * z], axis=2) + location[:, None, :]


def plain_rows(path: Path) -> list[list[str]]:
    return [line.split() for line in path.read_text().splitlines() if line.strip()]


@pytest.mark.parametrize("path", LABELS, ids=[p.name for p in LABELS])
def test_read_labels_equals_the_plain_parse_of_real_files(path):
    labels, problems = read_labels(path)
    rows = plain_rows(path)
    assert not problems and len(labels) == len(rows)
    values = np.array([r[1:] for r in rows], dtype=float)
    assert labels.cls.tolist() == [r[0] for r in rows]
    np.testing.assert_array_equal(labels.hwl, values[:, 7:10])
    np.testing.assert_array_equal(labels.location, values[:, 10:13])
    np.testing.assert_array_equal(labels.rotation_y, values[:, 13])
    np.testing.assert_array_equal(labels.bbox, values[:, 3:7])
    assert np.all(np.isnan(labels.score))


def test_results_file_scores_are_read_and_required_with_with_score(tmp_path):
    rows = plain_rows(LABELS[0])
    results = tmp_path / "000000.txt"
    results.write_text("".join(" ".join(r) + f" {0.5 + k / 10:.2f}\n" for k, r in enumerate(rows)))
    labels, problems = read_labels(results, with_score=True)
    assert not problems
    np.testing.assert_allclose(labels.score, [0.5 + k / 10 for k in range(len(rows))])
    labels, problems = read_labels(LABELS[0], with_score=True)
    assert len(labels) == 0
    assert [p.message for p in problems] == [f"line {k + 1}: expected 16 fields (with the score), got 15"
                                            for k in range(len(rows))]
    bad = tmp_path / "bad.txt"
    bad.write_text(" ".join(rows[0]) + " inf\n")
    _, problems = read_labels(bad, with_score=True)
    assert problems[0].message == "line 1: score: expected a finite number, got 'inf'"


def test_compute_box_3d_is_the_devkit_formula_on_real_labels():
    worst = 0.0
    for path in LABELS:
        labels, _ = read_labels(path)
        care = labels.cls != "DontCare"
        got = compute_box_3d(labels.hwl[care], labels.location[care], labels.rotation_y[care])
        expected = devkit_compute_box_3d(labels.hwl[care], labels.location[care], labels.rotation_y[care])
        worst = max(worst, float(np.abs(got - expected).max()))
    assert worst < 1e-12


def test_calib_of_real_files_needs_no_repair_beyond_noise():
    for path in sorted((REAL / "object" / "training" / "calib").glob("*.txt")) + [
            REAL / "tracking" / "training" / "calib" / "0001.txt"]:
        assert read_calib(path).warnings == ()


def _rotation(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize(("scale", "outcome"), [(1 + 1e-8, "silent"), (1 + 3e-7, "silent"), (1 + 1e-4, "warn"),
                                                (1 + 4e-3, "warn"), (1 + 1e-2, "reject"), (0.0, "reject")])
def test_rotation_tolerances(scale, outcome):
    matrix = _rotation(0.3) * scale
    if outcome == "reject":
        with pytest.raises(InputError, match=r"^R: expected a rotation \(max \|R\^T R - I\| <= 0.01\)"):
            rotations.repaired_rotation(matrix, "R")
        return
    repaired, warning = rotations.repaired_rotation(matrix, "R")
    np.testing.assert_allclose(repaired, _rotation(0.3), atol=1e-12)
    assert (warning is None) == (outcome == "silent")


def test_reflection_and_nan_are_not_rotations():
    with pytest.raises(InputError, match="finite values with det > 0"):
        rotations.repaired_rotation(np.diag([1.0, 1.0, -1.0]), "R")
    with pytest.raises(InputError, match="finite values with det > 0"):
        rotations.repaired_rotation(np.full((3, 3), np.nan), "R")


def test_quaternion_tolerances():
    q = np.array([[1.0, 0, 0, 0], [1 + 5e-7, 0, 0, 0], [1 + 1e-3, 0, 0, 0], [1.02, 0, 0, 0], [np.nan, 0, 0, 0],
                  [0.0, 0, 0, 0]])
    unit, warn, reject = rotations.repaired_quaternions(q)
    assert warn.tolist() == [False, False, True, False, False, False]
    assert reject.tolist() == [False, False, False, True, True, True]
    np.testing.assert_allclose(np.linalg.norm(unit, axis=1), 1.0)


@pytest.mark.parametrize("token", ["1_000", "\u0663"])
def test_calib_and_oxts_numbers_are_what_a_c_reader_takes(tmp_path, token):
    # float() reads '1_000' as 1000 and '٣' as 3; KITTI's own (C/C++) readers stop there, so it is damage.
    from avdata.sources.kitti.oxts import oxts_packet_problem

    text = (REAL / "object" / "training" / "calib" / "000000.txt").read_text().splitlines()
    fields = text[5].split()  # Tr_velo_to_cam
    fields[4] = token
    text[5] = " ".join(fields)
    (tmp_path / "calib.txt").write_text("\n".join(text) + "\n")
    with pytest.raises(InputError, match=rf"calib.txt: line 6: Tr_velo_to_cam: expected numbers, got .*{token}"):
        read_calib(tmp_path / "calib.txt")
    packet = (REAL / "tracking" / "training" / "oxts" / "0001.txt").read_text().splitlines()[0].split()
    packet[3] = token
    assert oxts_packet_problem(" ".join(packet)) == f"expected numbers, got {' '.join(packet)!r}"
