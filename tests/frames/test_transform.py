"""Transform algebra: identities, conversions against scipy, interpolation, reflections."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation, Slerp

from avdata.errors import AvdataError
from avdata.frames import RH_T_CARLA, XFWD_T_OPTICAL, Transform, rotations

finite = st.floats(-100.0, 100.0, allow_nan=False, allow_infinity=False)
quats = arrays(np.float64, 4, elements=st.floats(-1.0, 1.0, allow_nan=False)).filter(lambda q: np.linalg.norm(q) > 0.1)
vectors = arrays(np.float64, 3, elements=finite)


def transforms() -> st.SearchStrategy[Transform]:
    return st.builds(lambda q, t: Transform.from_quat_wxyz(q, t), quats, vectors)


@settings(max_examples=60, deadline=None)
@given(transforms())
def test_inverse_composes_to_identity(a_T_b: Transform) -> None:
    assert (a_T_b.inverse() @ a_T_b).allclose(Transform.identity(), atol=1e-9)
    assert (a_T_b @ a_T_b.inverse()).allclose(Transform.identity(), atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(transforms(), transforms(), transforms())
def test_composition_is_associative_and_matches_4x4(a: Transform, b: Transform, c: Transform) -> None:
    assert ((a @ b) @ c).allclose(a @ (b @ c), atol=1e-9)
    np.testing.assert_allclose((a @ b @ c).as_matrix(), a.as_matrix() @ b.as_matrix() @ c.as_matrix(), atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(transforms(), arrays(np.float64, (5, 3), elements=finite))
def test_apply_equals_homogeneous_product(a_T_b: Transform, points_b: np.ndarray) -> None:
    homogeneous = np.hstack([points_b, np.ones((5, 1))])
    expected = (a_T_b.as_matrix() @ homogeneous.T).T[:, :3]
    np.testing.assert_allclose(a_T_b.apply(points_b), expected, atol=1e-9)
    np.testing.assert_allclose(a_T_b.apply_vector(points_b), points_b @ a_T_b.rotation.T, atol=1e-9)


EULER_SEQUENCES = ["".join(p) for p in itertools.product("xyz", repeat=3) if p[0] != p[1] and p[1] != p[2]]


@pytest.mark.parametrize("seq", EULER_SEQUENCES + [s.upper() for s in EULER_SEQUENCES])
def test_every_euler_sequence_agrees_with_scipy(seq: str) -> None:
    rng = np.random.default_rng(3)
    angles = rng.uniform(-np.pi, np.pi, size=(50, 3))
    angles[:, 1] = rng.uniform(0.1, np.pi - 0.1, size=50) if seq[0].lower() == seq[2].lower() else rng.uniform(
        -np.pi / 2 + 0.1, np.pi / 2 - 0.1, size=50)
    ours = Transform.from_euler(seq, angles)
    np.testing.assert_allclose(ours.rotation, Rotation.from_euler(seq, angles).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(ours.euler(seq), Rotation.from_matrix(ours.rotation).as_euler(seq), atol=1e-9)
    np.testing.assert_allclose(Transform.from_euler(seq, ours.euler(seq)).rotation, ours.rotation, atol=1e-9)


def test_quaternion_is_scalar_first_with_nonnegative_w() -> None:
    # 90 degrees about z: (w, x, y, z) = (cos 45, 0, 0, sin 45).
    t = Transform.from_quat_wxyz(np.array([np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)]))
    np.testing.assert_allclose(t.rotation, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    negated = Transform.from_quat_wxyz(-t.quat_wxyz())
    np.testing.assert_allclose(negated.quat_wxyz(), [np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)], atol=1e-12)


def test_batched_transforms_broadcast_and_index() -> None:
    yaws = np.linspace(0.0, np.pi, 7)
    batch = Transform.from_yaw(yaws, np.stack([yaws, -yaws, np.zeros(7)], axis=1))
    assert batch.shape == (7,)
    points = np.tile([1.0, 0.0, 0.0], (7, 1))
    moved = batch.apply(points)
    np.testing.assert_allclose(moved[:, 0], np.cos(yaws) + yaws, atol=1e-12)
    np.testing.assert_allclose(moved[:, 1], np.sin(yaws) - yaws, atol=1e-12)
    assert batch[3].allclose(Transform.from_yaw(yaws[3], [yaws[3], -yaws[3], 0.0]))
    np.testing.assert_allclose((batch.inverse() @ batch).rotation, np.broadcast_to(np.eye(3), (7, 3, 3)), atol=1e-12)


def test_interpolation_matches_scipy_slerp_and_lerp() -> None:
    rng = np.random.default_rng(0)
    start = Transform.from_quat_wxyz(rng.normal(size=4), rng.normal(size=3))
    end = Transform.from_quat_wxyz(rng.normal(size=4), rng.normal(size=3))
    fractions = np.linspace(0.0, 1.0, 11)
    ours = Transform(rotation=np.broadcast_to(start.rotation, (11, 3, 3)),
                     translation=np.broadcast_to(start.translation, (11, 3))).interpolate(end, fractions)
    slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([start.rotation, end.rotation])))
    np.testing.assert_allclose(ours.rotation, slerp(fractions).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(
        ours.translation, start.translation + fractions[:, None] * (end.translation - start.translation), atol=1e-12)


def test_reflection_is_improper_and_has_no_quaternion() -> None:
    assert RH_T_CARLA.is_proper is False
    assert (RH_T_CARLA @ RH_T_CARLA).allclose(Transform.identity())
    np.testing.assert_allclose(RH_T_CARLA.apply(np.array([1.0, 2.0, 3.0])), [1.0, -2.0, 3.0])
    with pytest.raises(AvdataError, match="improper"):
        RH_T_CARLA.quat_wxyz()


def test_optical_axes_map_onto_x_forward_axes() -> None:
    # Optical z (forward) is x-forward's +x; optical x (right) is -y; optical y (down) is -z.
    np.testing.assert_allclose(XFWD_T_OPTICAL.apply(np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0]], float)),
                               [[1, 0, 0], [0, -1, 0], [0, 0, -1]], atol=1e-15)
    assert XFWD_T_OPTICAL.is_proper is True


def test_orthonormalization_moves_nearly_orthonormal_matrix_least() -> None:
    rotation = Rotation.from_euler("ZYX", [0.3, -0.2, 0.1]).as_matrix()
    noisy = rotation + 1e-7 * np.random.default_rng(1).normal(size=(3, 3))
    fixed = Transform(rotation=noisy, translation=np.zeros(3)).orthonormalize()
    np.testing.assert_allclose(fixed.rotation @ fixed.rotation.T, np.eye(3), atol=1e-14)
    assert np.abs(fixed.rotation - rotation).max() < 3e-7
    # beyond float noise the repair is no longer silent, and a matrix that is no rotation is refused
    lines: list[str] = []
    Transform(rotation=rotation + 1e-4, translation=np.zeros(3)).orthonormalize(where="calib.txt Tr", warn=lines.append)
    assert len(lines) == 1 and lines[0].startswith("calib.txt Tr: rotation off orthonormality by ")
    with pytest.raises(AvdataError, match=r"calib.txt Tr: expected a rotation \(max \|R\^T R - I\| <= 0.01\), got deviation 3"):
        Transform(rotation=2.0 * rotation, translation=np.zeros(3)).orthonormalize(where="calib.txt Tr")


def test_bad_shapes_raise_clear_errors() -> None:
    with pytest.raises(AvdataError, match=r"expected a \(\.\.\., 4, 4\)"):
        Transform.from_matrix(np.eye(3))
    with pytest.raises(AvdataError, match="last row"):
        Transform.from_matrix(np.ones((4, 4)))
    with pytest.raises(AvdataError, match="non-zero"):
        Transform.from_quat_wxyz(np.zeros(4))


def test_quaternion_from_matrix_agrees_with_scipy_for_every_branch() -> None:
    rotations = Rotation.random(2000, random_state=12).as_matrix()
    # Rotations by ~180 degrees about each axis exercise the x, y and z branches of Shepperd's method.
    near_pi = Rotation.from_rotvec(np.eye(3) * (np.pi - 1e-9)).as_matrix()
    matrices = np.concatenate([rotations, near_pi, np.eye(3)[None]])
    ours = Transform(rotation=matrices, translation=np.zeros((len(matrices), 3))).quat_wxyz()
    theirs = Rotation.from_matrix(matrices).as_quat(scalar_first=True)
    theirs = np.where(theirs[:, :1] < 0, -theirs, theirs)
    np.testing.assert_allclose(np.abs(np.sum(ours * theirs, axis=1)), 1.0, atol=1e-12)
    np.testing.assert_allclose(Transform.from_quat_wxyz(ours).rotation, matrices, atol=1e-12)
    assert np.all(ours[:, 0] >= 0.0)


def test_single_matrix_quaternion_path_equals_the_batched_path() -> None:
    # Exact 90 degree turns tie two of Shepperd's candidates (the first must win in both paths); exact and near
    # half turns have w = 0 or nearly so.
    matrices = np.concatenate([Rotation.random(200, random_state=5).as_matrix(),
                               Rotation.from_rotvec(np.eye(3) * (np.pi - 1e-9)).as_matrix(),
                               np.round(Rotation.from_rotvec(np.eye(3) * np.pi / 2).as_matrix()),
                               np.round(Rotation.from_rotvec(np.eye(3) * np.pi).as_matrix())])
    batched = Transform(rotation=matrices, translation=np.zeros((len(matrices), 3))).quat_wxyz()
    singles = np.stack([Transform(rotation=m, translation=np.zeros(3)).quat_wxyz() for m in matrices])
    np.testing.assert_allclose(singles, batched, atol=1e-15)


def test_matrix_from_quaternion_agrees_with_scipy() -> None:
    quats = np.random.default_rng(4).normal(size=(500, 4)) * 3.0
    ours = Transform.from_quat_wxyz(quats).rotation
    np.testing.assert_allclose(ours, Rotation.from_quat(quats, scalar_first=True).as_matrix(), atol=1e-12)


def test_matrix_from_quaternion_has_the_bits_of_the_textbook_formula() -> None:
    # Written datasets are pinned by digests: the vectorised entries must do the very same arithmetic.
    quats = np.random.default_rng(8).normal(size=(1000, 4))
    w, x, y, z = np.moveaxis(quats / np.linalg.norm(quats, axis=-1)[..., None], -1, 0)
    textbook = np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=-2)
    np.testing.assert_array_equal(rotations.matrix_from_quat_wxyz(quats), textbook)
    np.testing.assert_array_equal(rotations.matrix_from_quat_wxyz(quats[7]), textbook[7])


def test_determinant_agrees_with_lapack_and_sets_properness() -> None:
    matrices = np.random.default_rng(9).normal(size=(5, 7, 3, 3))
    np.testing.assert_allclose(rotations.determinant(matrices), np.linalg.det(matrices), rtol=1e-12, atol=1e-12)
    assert rotations.determinant(np.eye(3)).shape == ()
    reflection = np.diag([1.0, -1.0, 1.0])
    flags = Transform(rotation=np.stack([np.eye(3), reflection]), translation=np.zeros((2, 3))).is_proper
    np.testing.assert_array_equal(flags, [True, False])


def test_indexing_a_batch_gives_read_only_transforms_of_its_values() -> None:
    rng = np.random.default_rng(8)
    batch = Transform.from_quat_wxyz(rng.normal(size=(6, 4)), rng.normal(size=(6, 3)))
    for index in (0, -1, slice(1, 4), np.array([5, 0, 5]), np.array([True, False] * 3)):
        picked = batch[index]
        np.testing.assert_array_equal(picked.rotation, batch.rotation[index])
        np.testing.assert_array_equal(picked.translation, batch.translation[index])
        for array in (picked.rotation, picked.translation):
            with pytest.raises(ValueError, match="read-only"):
                array[...] = 0.0
    np.testing.assert_array_equal(batch[2].apply(np.ones(3)), batch.apply(np.ones(3))[2])
    with pytest.raises(AvdataError, match=r"expected rotation of shape \(\.\.\., 3, 3\), got \(3,\)"):
        batch[2][0]
