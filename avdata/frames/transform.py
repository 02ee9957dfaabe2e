"""Rigid (and reflecting) transforms, vectorised over any leading batch shape.

A ``Transform`` named ``a_T_b`` maps coordinates of a point in frame ``b`` into frame ``a``:
``p_a = a_T_b.rotation @ p_b + a_T_b.translation``. Composition reads right to left, so
``world_T_lidar = world_T_ego @ ego_T_lidar``.

The rotation is stored as a matrix, not a quaternion, because a transform between a left-handed
source frame (CARLA/Unreal) and a right-handed one is a reflection (det -1), which no quaternion can
hold. Everything written to disk is proper; :meth:`Transform.quat_wxyz` refuses an improper one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from avdata.errors import AvdataError
from avdata.frames import rotations


@dataclass(frozen=True, slots=True, kw_only=True)
class Transform:
    """A batch of rigid transforms, ``p_target = rotation @ p_source + translation``.

    Attributes:
        rotation: (..., 3, 3) rotation matrices, proper (det +1) or improper (det -1).
        translation: (..., 3) translations in metres, in the target frame.
    """

    rotation: np.ndarray
    translation: np.ndarray

    def __post_init__(self) -> None:
        rotation = np.asarray(self.rotation, dtype=np.float64)
        translation = np.asarray(self.translation, dtype=np.float64)
        if rotation.shape[-2:] != (3, 3):
            raise AvdataError(f"expected rotation of shape (..., 3, 3), got {rotation.shape}")
        if translation.shape[-1:] != (3,):
            raise AvdataError(f"expected translation of shape (..., 3), got {translation.shape}")
        if rotation.shape[:-2] != translation.shape[:-1]:
            batch = np.broadcast_shapes(rotation.shape[:-2], translation.shape[:-1])
            rotation = np.broadcast_to(rotation, batch + (3, 3))
            translation = np.broadcast_to(translation, batch + (3,))
        rotation = np.array(rotation)
        translation = np.array(translation)
        rotation.flags.writeable = False
        translation.flags.writeable = False
        object.__setattr__(self, "rotation", rotation)
        object.__setattr__(self, "translation", translation)

    # ----------------------------------------------------------------- constructors
    @classmethod
    def identity(cls, shape: tuple[int, ...] = ()) -> Transform:
        """The identity transform, broadcast to a batch ``shape``."""
        rotation = np.broadcast_to(np.eye(3), shape + (3, 3))
        return cls(rotation=rotation, translation=np.zeros(shape + (3,)))

    @classmethod
    def from_matrix(cls, matrix: np.ndarray) -> Transform:
        """From homogeneous matrices.

        Args:
            matrix: (..., 4, 4) or (..., 3, 4) matrices; a 4x4's last row must be (0, 0, 0, 1).
        """
        matrix = np.asarray(matrix, dtype=np.float64)
        if matrix.shape[-2:] not in ((4, 4), (3, 4)):
            raise AvdataError(f"expected a (..., 4, 4) or (..., 3, 4) matrix, got {matrix.shape}")
        if matrix.shape[-2:] == (4, 4) and not np.allclose(matrix[..., 3, :], [0.0, 0.0, 0.0, 1.0]):
            raise AvdataError(f"expected last row (0, 0, 0, 1), got {matrix[..., 3, :].tolist()}")
        return cls(rotation=matrix[..., :3, :3], translation=matrix[..., :3, 3])

    @classmethod
    def from_quat_wxyz(cls, quat_wxyz: np.ndarray, translation: np.ndarray | None = None) -> Transform:
        """From scalar-first quaternions (..., 4) and translations (..., 3)."""
        rotation = rotations.matrix_from_quat_wxyz(quat_wxyz)
        if translation is None:
            translation = np.zeros(rotation.shape[:-2] + (3,))
        return cls(rotation=rotation, translation=translation)

    @classmethod
    def from_euler(
        cls,
        seq: str,
        angles: np.ndarray,
        translation: np.ndarray | None = None,
        degrees: bool = False,
    ) -> Transform:
        """From Euler angles in an explicit scipy axis sequence ("ZYX" intrinsic, "xyz" extrinsic)."""
        rotation = rotations.matrix_from_euler(seq, angles, degrees=degrees)
        if translation is None:
            translation = np.zeros(rotation.shape[:-2] + (3,))
        return cls(rotation=rotation, translation=translation)

    @classmethod
    def from_yaw(cls, yaw_rad: np.ndarray, translation: np.ndarray | None = None) -> Transform:
        """Rotations about +z by ``yaw_rad`` (counter-clockwise seen from above), any batch shape."""
        yaw_rad = np.asarray(yaw_rad, dtype=np.float64)
        cos, sin = np.cos(yaw_rad), np.sin(yaw_rad)
        zeros, ones = np.zeros_like(yaw_rad), np.ones_like(yaw_rad)
        rotation = np.stack(
            [
                np.stack([cos, -sin, zeros], axis=-1),
                np.stack([sin, cos, zeros], axis=-1),
                np.stack([zeros, zeros, ones], axis=-1),
            ],
            axis=-2,
        )
        if translation is None:
            translation = np.zeros(yaw_rad.shape + (3,))
        return cls(rotation=rotation, translation=translation)

    @classmethod
    def stack(cls, transforms: list[Transform]) -> Transform:
        """Stacks equally shaped transforms along a new leading axis."""
        if not transforms:
            raise AvdataError("expected at least one transform to stack, got none")
        return cls(
            rotation=np.stack([t.rotation for t in transforms]),
            translation=np.stack([t.translation for t in transforms]),
        )

    # ----------------------------------------------------------------- views
    @property
    def shape(self) -> tuple[int, ...]:
        """The batch shape (``()`` for a single transform)."""
        return self.translation.shape[:-1]

    def __len__(self) -> int:
        if not self.shape:
            raise TypeError("a single Transform has no len()")
        return self.shape[0]

    def __getitem__(self, index: int | slice | np.ndarray) -> Transform:
        rotation, translation = self.rotation[index], self.translation[index]
        if rotation.shape[-2:] != (3, 3) or rotation.shape[:-2] != translation.shape[:-1]:
            return Transform(rotation=rotation, translation=translation)  # indexed past the batch: refused there
        # Views of this transform's read-only arrays (or, for an index array, copies made read-only here): nothing
        # to check or copy. Loaders pick one pose of a batch per message, where __post_init__'s checks would
        # cost several times the indexing itself.
        rotation.flags.writeable = False
        translation.flags.writeable = False
        picked = object.__new__(Transform)
        object.__setattr__(picked, "rotation", rotation)
        object.__setattr__(picked, "translation", translation)
        return picked

    @property
    def is_proper(self) -> np.ndarray | bool:
        """Whether each rotation is proper (det +1) rather than a reflection (det -1)."""
        det = rotations.determinant(self.rotation)
        return bool(det > 0) if det.ndim == 0 else det > 0

    def as_matrix(self) -> np.ndarray:
        """Homogeneous matrices (..., 4, 4)."""
        matrix = np.zeros(self.shape + (4, 4))
        matrix[..., :3, :3] = self.rotation
        matrix[..., :3, 3] = self.translation
        matrix[..., 3, 3] = 1.0
        return matrix

    def quat_wxyz(self) -> np.ndarray:
        """Scalar-first unit quaternions (..., 4) with w >= 0; proper rotations only."""
        return rotations.quat_wxyz_from_matrix(self.rotation)

    def euler(self, seq: str, degrees: bool = False) -> np.ndarray:
        """Euler angles (..., 3) in the given scipy axis sequence; proper rotations only."""
        return rotations.euler_from_matrix(self.rotation, seq, degrees=degrees)

    # ----------------------------------------------------------------- algebra
    def __matmul__(self, other: Transform) -> Transform:
        """``a_T_b @ b_T_c = a_T_c`` (broadcasting batch shapes)."""
        if not isinstance(other, Transform):
            return NotImplemented
        rotation = self.rotation @ other.rotation
        translation = np.einsum("...ij,...j->...i", self.rotation, other.translation) + self.translation
        return Transform(rotation=rotation, translation=translation)

    def inverse(self) -> Transform:
        """``b_T_a`` from ``a_T_b``. Uses R^-1 = R^T, valid for proper and improper rotations alike."""
        rotation_inv = np.swapaxes(self.rotation, -1, -2)
        translation = -np.einsum("...ij,...j->...i", rotation_inv, self.translation)
        return Transform(rotation=rotation_inv, translation=translation)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Maps points into the target frame.

        Args:
            points: (..., 3) points in the source frame. A single transform applies to any number
                of points; a batch of transforms of shape (N,) applies element-wise to (N, 3).

        Returns:
            (..., 3) points in the target frame, float64 (float32 input stays float32).
        """
        points = np.asarray(points)
        out_dtype = np.float32 if points.dtype == np.float32 else np.float64
        if not self.shape:
            return _rotate(self.rotation, points, out_dtype) + self.translation.astype(out_dtype)
        result = np.einsum("...ij,...j->...i", self.rotation, points) + self.translation
        moved: np.ndarray = result.astype(out_dtype, copy=False)
        return moved

    def apply_vector(self, vectors: np.ndarray) -> np.ndarray:
        """Rotates direction vectors (velocities, normals) into the target frame; no translation."""
        vectors = np.asarray(vectors)
        out_dtype = np.float32 if vectors.dtype == np.float32 else np.float64
        if not self.shape:
            return _rotate(self.rotation, vectors, out_dtype)
        rotated: np.ndarray = np.einsum("...ij,...j->...i", self.rotation, vectors).astype(out_dtype, copy=False)
        return rotated

    def interpolate(self, other: Transform, fraction: np.ndarray | float) -> Transform:
        """Slerp of the rotation and lerp of the translation, from ``self`` (0) to ``other`` (1).

        Both ends must be proper rotations (a reflection cannot be interpolated continuously).

        Args:
            other: the end transforms, same batch shape as ``self`` (or broadcastable).
            fraction: (...,) interpolation fractions, 0 gives ``self``, 1 gives ``other``.
        """
        fraction = np.asarray(fraction, dtype=np.float64)
        relative = np.swapaxes(self.rotation, -1, -2) @ other.rotation
        rotvec = rotations.rotvec_from_matrix(relative)
        step = rotations.matrix_from_rotvec(rotvec * fraction[..., None])
        rotation = self.rotation @ step
        translation = self.translation + (other.translation - self.translation) * fraction[..., None]
        return Transform(rotation=rotation, translation=translation)

    def orthonormalize(self, *, where: str = "transform", warn: Callable[[str], None] | None = None) -> Transform:
        """The same transform with each rotation replaced by its nearest rotation.

        The repair is checked by the one rule, :func:`~avdata.frames.rotations.orthonormalize_checked`:
        silent up to float noise (max |R^T R - I| <= 1e-6), a warning up to 1e-2, an InputError beyond.

        Args:
            where: what the transform is (file and field), for the warning or error.
            warn: receives a warning line; None issues a :class:`~avdata.frames.RepairWarning`.
        """
        rotation, _ = rotations.orthonormalize_checked(self.rotation, where=where, warn=warn)
        return Transform(rotation=rotation, translation=self.translation)

    def allclose(self, other: Transform, atol: float = 1e-9) -> bool:
        """Whether rotations and translations agree element-wise within ``atol``."""
        return bool(
            np.allclose(self.rotation, other.rotation, atol=atol, rtol=0.0)
            and np.allclose(self.translation, other.translation, atol=atol, rtol=0.0)
        )


def _rotate(rotation: np.ndarray, vectors: np.ndarray, dtype: type) -> np.ndarray:
    """``vectors @ rotation.T`` as three multiply-adds.

    A matrix product with a 3-wide inner dimension goes through BLAS, whose threads spin badly when
    the cores are shared (a lidar sweep then takes many times longer than element-wise arithmetic) and whose
    summation order may vary between runs; element-wise arithmetic is fast everywhere and gives the
    same bits every run, which byte-identical generated datasets rely on.
    """
    r: np.ndarray = rotation.astype(dtype)
    v: np.ndarray = vectors.astype(dtype, copy=False)
    rotated: np.ndarray = v[..., 0:1] * r[:, 0] + v[..., 1:2] * r[:, 1] + v[..., 2:3] * r[:, 2]
    return rotated
