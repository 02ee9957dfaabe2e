"""Pinhole cameras: configuration, intrinsics from field of view and resolution, projection.

The camera frame is optical (x right, y down, z forward). Square pixels, principal point at the
image centre; pixel (u, v) covers [u, u+1) x [v, v+1), so ``u = fx x / z + cx`` with ``cx = W / 2``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True, slots=True, kw_only=True)
class CameraConfig:
    """A pinhole camera, rendered by ray casting (:mod:`~avdata.generators.render`).

    Attributes:
        width, height: image size in pixels.
        horizontal_fov_deg: horizontal field of view.
        near_m: points nearer than this plane do not project (labels); the image is not clipped there.
        far_m: the camera's range: farther surfaces are sky in the image and out of view in the labels.
        rate_hz: frames per second.
    """

    width: int = 1242
    height: int = 375
    horizontal_fov_deg: float = 81.0
    near_m: float = 0.3
    far_m: float = 150.0
    rate_hz: float = 10.0

    @property
    def focal_px(self) -> float:
        """Focal length in pixels (fx = fy)."""
        # math.tan, not np.tan: numpy's tan loop gives other last bits on AVX-512 than on AVX2 (docs/determinism.md).
        return self.width / 2 / math.tan(math.radians(self.horizontal_fov_deg) / 2)

    @property
    def vertical_fov_deg(self) -> float:
        """The vertical field of view implied by the focal length and height."""
        return math.degrees(2 * math.atan(self.height / 2 / self.focal_px))

    @property
    def K(self) -> np.ndarray:  # noqa: N802 - the standard name of the intrinsic matrix
        """(3, 3) intrinsic matrix."""
        f = self.focal_px
        return np.array([[f, 0.0, self.width / 2], [0.0, f, self.height / 2], [0.0, 0.0, 1.0]])

    def project(self, points_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Projects points in the optical frame.

        Args:
            points_camera: (..., 3) points.

        Returns:
            (..., 2) pixel coordinates and (...,) bool, True where the point is beyond the near plane.
        """
        z = points_camera[..., 2]
        in_front = z > self.near_m
        safe_z = np.where(in_front, z, 1.0)
        f = self.focal_px
        uv = np.stack([f * points_camera[..., 0] / safe_z + self.width / 2,
                       f * points_camera[..., 1] / safe_z + self.height / 2], axis=-1)
        return uv, in_front

    def spec(self) -> dict[str, Any]:
        """The sensor spec written into the scene metadata."""
        return {"width": self.width, "height": self.height, "horizontal_fov_deg": self.horizontal_fov_deg,
                "near_m": self.near_m, "far_m": self.far_m, "rate_hz": self.rate_hz}
