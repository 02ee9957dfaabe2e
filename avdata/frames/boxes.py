"""Vectorised oriented 3D boxes that know their frame, and each source's box convention.

Unified convention (docs/conventions.md): a box is its centre (never the bottom), its size as
(length along the box's x, width along its y, height along its z) and the unit quaternion
(w, x, y, z) of the box frame in the reference frame ``frame``; yaw is the rotation of the box's x
axis about the reference z axis, counter-clockwise.

Corner order (same as nuScenes ``Box.corners()``; ``l, w, h`` halved):

====  ======  ======  ======
idx   x       y       z
====  ======  ======  ======
0     +l      +w      +h     front-left-top
1     +l      -w      +h     front-right-top
2     +l      -w      -h     front-right-bottom
3     +l      +w      -h     front-left-bottom
4     -l      +w      +h     rear-left-top
5     -l      -w      +h     rear-right-top
6     -l      -w      -h     rear-right-bottom
7     -l      +w      -h     rear-left-bottom
====  ======  ======  ======
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from avdata.errors import AvdataError
from avdata.frames import rotations
from avdata.frames.graph import FrameGraph
from avdata.frames.transform import Transform

_CORNER_SIGNS = np.array(
    [
        [1, 1, 1],
        [1, -1, 1],
        [1, -1, -1],
        [1, 1, -1],
        [-1, 1, 1],
        [-1, -1, 1],
        [-1, -1, -1],
        [-1, 1, -1],
    ],
    dtype=np.float64,
)

#: A reflection of the box's own y axis. A box is symmetric under it, so composing an improper
#: rotation with it describes the same solid with a proper (right-handed) box frame whose x axis,
#: the heading, is unchanged.
_FLIP_BOX_Y = np.diag([1.0, -1.0, 1.0])


@dataclass(frozen=True, slots=True, kw_only=True)
class Boxes3D:
    """N oriented boxes in one reference frame, as arrays.

    Attributes:
        center: (N, 3) box centres in ``frame``, metres.
        size_lwh: (N, 3) length, width, height in metres (along box x, y, z).
        quat_wxyz: (N, 4) unit quaternions of the box frame in ``frame``, w >= 0.
        frame: name of the reference frame.
        ids: (N,) object ids as strings, or None.
        classes: (N,) class names, or None.
        velocity: (N, 3) velocity in m/s, expressed in ``frame``'s axes, or None.
    """

    center: np.ndarray
    size_lwh: np.ndarray
    quat_wxyz: np.ndarray
    frame: str
    ids: np.ndarray | None = None
    classes: np.ndarray | None = None
    velocity: np.ndarray | None = None

    def __post_init__(self) -> None:
        center = np.asarray(self.center, dtype=np.float64).reshape(-1, 3)
        n = center.shape[0]
        size = np.asarray(self.size_lwh, dtype=np.float64).reshape(-1, 3)
        quat = np.asarray(self.quat_wxyz, dtype=np.float64).reshape(-1, 4)
        if size.shape[0] != n or quat.shape[0] != n:
            raise AvdataError(f"expected {n} sizes and quaternions, got {size.shape[0]} and {quat.shape[0]}")
        if n:
            # Quaternions off unit by more than float noise are a warning, beyond REPAIR_TOLERANCE an error.
            quat, _ = rotations.normalize_quat_checked(quat, where="box quaternions (w, x, y, z)")
            quat = np.where(quat[:, :1] < 0.0, -quat, quat)
        if np.any(size < 0.0):
            raise AvdataError(f"expected non-negative box sizes, got {size[np.any(size < 0, axis=1)][0].tolist()}")
        fields = {"center": center, "size_lwh": size, "quat_wxyz": quat}
        for name in ("ids", "classes"):
            value = getattr(self, name)
            if value is not None:
                value = np.asarray(value, dtype=str).reshape(-1)
                if value.shape[0] != n:
                    raise AvdataError(f"expected {n} {name}, got {value.shape[0]}")
                fields[name] = value
        if self.velocity is not None:
            velocity = np.asarray(self.velocity, dtype=np.float64).reshape(-1, 3)
            if velocity.shape[0] != n:
                raise AvdataError(f"expected {n} velocities, got {velocity.shape[0]}")
            fields["velocity"] = velocity
        for name, value in fields.items():
            value = np.array(value)
            value.flags.writeable = False
            object.__setattr__(self, name, value)

    # ----------------------------------------------------------------- constructors
    @classmethod
    def empty(cls, frame: str) -> Boxes3D:
        """No boxes, in ``frame``."""
        return cls(center=np.zeros((0, 3)), size_lwh=np.zeros((0, 3)), quat_wxyz=np.zeros((0, 4)), frame=frame)

    @classmethod
    def from_rotation(
        cls, center: np.ndarray, size_lwh: np.ndarray, rotation: np.ndarray, frame: str, **extra: np.ndarray | None
    ) -> Boxes3D:
        """From proper rotation matrices (N, 3, 3) of the box frames."""
        rotation = np.asarray(rotation, dtype=np.float64).reshape(-1, 3, 3)
        quat = rotations.quat_wxyz_from_matrix(rotation) if len(rotation) else np.zeros((0, 4))
        return cls(center=center, size_lwh=size_lwh, quat_wxyz=quat, frame=frame, **extra)

    @classmethod
    def from_yaw(
        cls, center: np.ndarray, size_lwh: np.ndarray, yaw_rad: np.ndarray, frame: str, **extra: np.ndarray | None
    ) -> Boxes3D:
        """Upright boxes rotated by ``yaw_rad`` (N,) about the reference z axis."""
        yaw_rad = np.asarray(yaw_rad, dtype=np.float64).reshape(-1)
        half = yaw_rad / 2.0
        quat = np.stack([np.cos(half), np.zeros_like(half), np.zeros_like(half), np.sin(half)], axis=1)
        return cls(center=center, size_lwh=size_lwh, quat_wxyz=quat, frame=frame, **extra)

    @classmethod
    def from_kitti_camera(
        cls,
        dimensions_hwl: np.ndarray,
        location_bottom: np.ndarray,
        rotation_y: np.ndarray,
        frame: str,
        **extra: np.ndarray | None,
    ) -> Boxes3D:
        """From KITTI labels in a rectified camera frame (x right, y down, z forward).

        KITTI's corner formula (devkit ``compute_box_3d``): corners = roty(ry) @ [x; y; z] + loc with
        x = ±l/2, y = 0 or -h, z = ±w/2, so length runs along the object's x, width along its z,
        height along -y (up), and ``location`` is the bottom centre. The unified box frame has
        x = roty(ry)·e_x, z = -e_y (up), y = z × x = roty(ry)·e_z; the centre is h/2 above the bottom.

        Args:
            dimensions_hwl: (N, 3) height, width, length in metres, as KITTI prints them.
            location_bottom: (N, 3) bottom-centre x, y, z in the camera frame.
            rotation_y: (N,) rotation about the camera y axis, radians.
            frame: the rectified camera frame name.
            **extra: ``ids``, ``classes``, ``velocity`` as in :class:`Boxes3D`.
        """
        hwl = np.asarray(dimensions_hwl, dtype=np.float64).reshape(-1, 3)
        bottom = np.asarray(location_bottom, dtype=np.float64).reshape(-1, 3)
        ry = np.asarray(rotation_y, dtype=np.float64).reshape(-1)
        cos, sin = np.cos(ry), np.sin(ry)
        zeros = np.zeros_like(ry)
        axis_x = np.stack([cos, zeros, -sin], axis=1)
        axis_y = np.stack([sin, zeros, cos], axis=1)
        axis_z = np.tile([0.0, -1.0, 0.0], (len(ry), 1))
        rotation = np.stack([axis_x, axis_y, axis_z], axis=2)
        center = bottom - hwl[:, :1] / 2.0 * np.array([0.0, 1.0, 0.0])
        size_lwh = hwl[:, [2, 1, 0]]
        return cls.from_rotation(center, size_lwh, rotation, frame, **extra)

    def to_kitti_camera(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(dimensions_hwl (N, 3), location_bottom (N, 3), rotation_y (N,)) in this box's frame.

        The frame must be a KITTI rectified camera frame (y down) and the boxes upright in it
        (box z along -y); rotation_y is wrapped to [-pi, pi).
        """
        rotation = self.rotation_matrix()
        up = rotation[:, :, 2]
        if len(self) and not np.allclose(up, [0.0, -1.0, 0.0], atol=1e-6):
            raise AvdataError(f"expected boxes upright in camera frame {self.frame!r} (z along -y), got tilted ones")
        axis_x = rotation[:, :, 0]
        rotation_y = _wrap_angle(np.arctan2(-axis_x[:, 2], axis_x[:, 0]))
        bottom = self.center + self.size_lwh[:, 2:3] / 2.0 * np.array([0.0, 1.0, 0.0])
        return self.size_lwh[:, [2, 1, 0]], bottom, rotation_y

    @classmethod
    def from_nuscenes(
        cls, center: np.ndarray, size_wlh: np.ndarray, quat_wxyz: np.ndarray, frame: str, **extra: np.ndarray | None
    ) -> Boxes3D:
        """From nuScenes boxes: centre, size as (width, length, height), quaternion (w, x, y, z)."""
        wlh = np.asarray(size_wlh, dtype=np.float64).reshape(-1, 3)
        return cls(center=center, size_lwh=wlh[:, [1, 0, 2]], quat_wxyz=quat_wxyz, frame=frame, **extra)

    def to_nuscenes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(center (N, 3), size_wlh (N, 3), quat_wxyz (N, 4)) as nuScenes stores them."""
        return self.center, self.size_lwh[:, [1, 0, 2]], self.quat_wxyz

    @classmethod
    def from_waymo(
        cls, center: np.ndarray, size_lwh: np.ndarray, heading_rad: np.ndarray, frame: str, **extra: np.ndarray | None
    ) -> Boxes3D:
        """From Waymo boxes: centre, (length, width, height), heading about +z (vehicle frame)."""
        return cls.from_yaw(center, size_lwh, heading_rad, frame, **extra)

    def to_waymo(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(center (N, 3), size_lwh (N, 3), heading_rad (N,)); boxes must be upright."""
        return self.center, self.size_lwh, self.yaw()

    @classmethod
    def from_av2(
        cls, center: np.ndarray, size_lwh: np.ndarray, quat_wxyz: np.ndarray, frame: str, **extra: np.ndarray | None
    ) -> Boxes3D:
        """From Argoverse 2 cuboids (tx/ty/tz_m, length/width/height_m, qw/qx/qy/qz): the unified convention."""
        return cls(center=center, size_lwh=size_lwh, quat_wxyz=quat_wxyz, frame=frame, **extra)

    def to_av2(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(center, size_lwh, quat_wxyz), unchanged: AV2's cuboid convention is the unified one."""
        return self.center, self.size_lwh, self.quat_wxyz

    @classmethod
    def concatenate(cls, boxes: list[Boxes3D]) -> Boxes3D:
        """Joins boxes of one frame; optional fields are kept only if every part has them."""
        if not boxes:
            raise AvdataError("expected at least one Boxes3D to concatenate, got none")
        frames = {b.frame for b in boxes}
        if len(frames) != 1:
            raise AvdataError(f"expected boxes in one frame, got frames {sorted(frames)}")

        def joined(name: str) -> np.ndarray | None:
            parts = [getattr(b, name) for b in boxes]
            return None if any(p is None for p in parts) else np.concatenate(parts)

        return cls(
            center=np.concatenate([b.center for b in boxes]),
            size_lwh=np.concatenate([b.size_lwh for b in boxes]),
            quat_wxyz=np.concatenate([b.quat_wxyz for b in boxes]),
            frame=boxes[0].frame,
            ids=joined("ids"),
            classes=joined("classes"),
            velocity=joined("velocity"),
        )

    # ----------------------------------------------------------------- views
    def __len__(self) -> int:
        return int(self.center.shape[0])

    def __getitem__(self, index: int | slice | np.ndarray) -> Boxes3D:
        index = np.arange(len(self))[index] if not isinstance(index, np.ndarray) or index.dtype != bool else index
        index = np.atleast_1d(index)
        return replace(
            self,
            center=self.center[index],
            size_lwh=self.size_lwh[index],
            quat_wxyz=self.quat_wxyz[index],
            ids=None if self.ids is None else self.ids[index],
            classes=None if self.classes is None else self.classes[index],
            velocity=None if self.velocity is None else self.velocity[index],
        )

    def rotation_matrix(self) -> np.ndarray:
        """(N, 3, 3) rotations of the box frames in the reference frame."""
        if not len(self):
            return np.zeros((0, 3, 3))
        return rotations.matrix_from_quat_wxyz(self.quat_wxyz)

    def yaw(self) -> np.ndarray:
        """(N,) heading: angle of the box x axis projected on the reference xy plane, in [-pi, pi)."""
        rotation = self.rotation_matrix()
        return _wrap_angle(np.arctan2(rotation[:, 1, 0], rotation[:, 0, 0]))

    def corners(self) -> np.ndarray:
        """(N, 8, 3) corners in the reference frame, in the order of the module docstring."""
        local = _CORNER_SIGNS[None, :, :] * (self.size_lwh[:, None, :] / 2.0)
        corners: np.ndarray = np.einsum("nij,nkj->nki", self.rotation_matrix(), local) + self.center[:, None, :]
        return corners

    def bev_corners(self) -> np.ndarray:
        """(N, 4, 2) footprint polygon in the reference xy plane, counter-clockwise.

        Order: front-left, rear-left, rear-right, front-right (bottom corners 3, 7, 6, 2).
        """
        return self.corners()[:, [3, 7, 6, 2], :2]

    def split(self, counts: list[int]) -> list[Boxes3D]:
        """Consecutive runs of ``counts[i]`` boxes (the counts sum to N), each in this frame.

        The pieces share this object's read-only arrays (views), and are not checked and normalised
        again: these rows already were, and normalising a unit quaternion again can change its last
        bit, so a piece holds exactly the values the boxes would have had converted on their own.

        Raises:
            AvdataError: the counts do not sum to the number of boxes.
        """
        if sum(counts) != len(self) or any(count < 0 for count in counts):
            raise AvdataError(f"expected non-negative counts summing to {len(self)}, got {counts}")
        pieces = []
        start = 0
        for count in counts:
            rows = slice(start, start + count)
            piece = object.__new__(Boxes3D)
            for name in self.__slots__:
                value = getattr(self, name)
                object.__setattr__(piece, name, value[rows] if isinstance(value, np.ndarray) else value)
            pieces.append(piece)
            start += count
        return pieces

    # ----------------------------------------------------------------- moving between frames
    def transform(self, target_T_frame: Transform, target_frame: str) -> Boxes3D:
        """The same boxes expressed in ``target_frame``.

        The one place where boxes change frame: centre ``c' = R c + t``, orientation ``R_box' = R
        R_box`` (full 3D orientation, roll and pitch kept), velocity ``v' = R v``. A batch of
        transforms moves each box by its own (boxes of different times, e.g. every object of a
        scene into the ego frame at its frame's time, in one call).

        A reflection (improper ``target_T_frame``) maps each box onto the mirrored solid; its box
        frame is made right-handed again by reflecting the box's own y axis, which leaves the solid,
        its size and its heading axis unchanged. Velocities are rotated (the velocity relative to
        the same reference, expressed in the target's axes).

        Args:
            target_T_frame: one transform from this box's frame to ``target_frame``, or (N,)
                transforms, one per box.
            target_frame: the name of the frame the result is in.

        Raises:
            AvdataError: a batch of transforms whose length is not the number of boxes.
        """
        shape = target_T_frame.shape
        if shape not in ((), (len(self),)):
            raise AvdataError(
                f"expected one transform or {len(self)} (one per box) to move boxes, got a batch of shape {shape}"
            )
        rotation = target_T_frame.rotation @ self.rotation_matrix()
        if shape == ():
            if not target_T_frame.is_proper:
                rotation = rotation @ _FLIP_BOX_Y
        else:
            improper = rotations.determinant(target_T_frame.rotation) < 0.0
            rotation[improper] = rotation[improper] @ _FLIP_BOX_Y
        quat = rotations.quat_wxyz_from_matrix(rotation) if len(self) else np.zeros((0, 4))
        return replace(
            self,
            center=target_T_frame.apply(self.center),
            quat_wxyz=quat,
            frame=target_frame,
            velocity=None if self.velocity is None else target_T_frame.apply_vector(self.velocity),
        )

    def to(
        self,
        target_frame: str,
        graph: FrameGraph,
        time_ns: int | np.ndarray | None = None,
        max_extrapolation_ns: int = 0,
    ) -> Boxes3D:
        """The same boxes in ``target_frame``, with the transform looked up in ``graph``.

        Args:
            target_frame: the frame to express the boxes in.
            graph: the scene's frame graph.
            time_ns: one time for every box, or (N,) times, one per box; None for a static chain.
            max_extrapolation_ns: as in :meth:`FrameGraph.lookup`.
        """
        target_T_frame = graph.lookup(target_frame, self.frame, time_ns, max_extrapolation_ns=max_extrapolation_ns)
        return self.transform(target_T_frame, target_frame)

    def image_boxes(self, frame_to_pixels: np.ndarray,
                    image_size_px: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The boxes as a camera sees them: the pixel rectangle around the projected corners, clipped to the image.

        Corners less than 0.1 m in front of the camera are left out (a box partly behind the camera is bounded
        by its corners in front); a box with no corner in front has no rectangle (NaN). Clipping keeps pixel
        centres: x in [0, width - 1], y in [0, height - 1] (KITTI's convention); a size of (0, 0) means unknown,
        nothing is clipped.

        Args:
            frame_to_pixels: (3, 4) projection from this box's frame to homogeneous pixels (e.g.
                :func:`avdata.loaders.items.projection`).
            image_size_px: (width, height) of the image.

        Returns:
            (N, 4) clipped ``(x0, y0, x1, y1)`` pixels, NaN where no corner is in front; (N,) truncation (the
            fraction of the unclipped rectangle outside the image, 1 where there is none); (N,) bool, whether
            a rectangle of positive area remains in the image.
        """
        n = len(self)
        if not n:
            return np.zeros((0, 4)), np.zeros(0), np.zeros(0, dtype=bool)
        corners = self.corners().reshape(-1, 3)
        homogeneous = np.c_[corners, np.ones(len(corners))] @ np.asarray(frame_to_pixels, dtype=np.float64).T
        depth = homogeneous[:, 2].reshape(n, 8)
        with np.errstate(divide="ignore", invalid="ignore"):
            pixels = (homogeneous[:, :2] / homogeneous[:, 2:]).reshape(n, 8, 2)
        front = depth > 0.1
        # Without nanmin's "All-NaN slice" warning for a box with no corner in front.
        lowest = np.min(np.where(front[:, :, None], pixels, np.inf), axis=1)
        highest = np.max(np.where(front[:, :, None], pixels, -np.inf), axis=1)
        box = np.where(np.any(front, axis=1)[:, None], np.concatenate([lowest, highest], axis=1), np.nan)
        width, height = image_size_px
        if width and height:
            clipped = np.clip(box, 0.0, [width - 1, height - 1, width - 1, height - 1])
        else:
            clipped = box
        area = (box[:, 2] - box[:, 0]) * (box[:, 3] - box[:, 1])
        clipped_area = (clipped[:, 2] - clipped[:, 0]) * (clipped[:, 3] - clipped[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            truncation = np.where(area > 0, 1.0 - clipped_area / area, 1.0)
        in_image = np.any(front, axis=1) & (clipped_area > 0)
        return clipped, truncation, in_image

    def contains(self, points: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
        """(N, P) whether each of P points (P, 3), in this frame, lies inside each box grown by ``margin_m``."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        local = np.einsum("nji,npj->npi", self.rotation_matrix(), points[None, :, :] - self.center[:, None, :])
        half = self.size_lwh[:, None, :] / 2.0 + margin_m
        inside: np.ndarray = np.all(np.abs(local) <= half, axis=2)
        return inside

    def count_points(self, points: np.ndarray) -> np.ndarray:
        """(N,) int64 number of the (P, 3) points (in this frame) inside each box.

        Points farther from every box centre than that box's half diagonal are dropped first (a cheap
        (N, P) distance test, in chunks), so the exact test of :meth:`contains` runs on the few near the boxes.
        """
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if not len(self) or not len(points):
            return np.zeros(len(self), dtype=np.int64)
        radius = np.linalg.norm(self.size_lwh, axis=1) / 2.0
        near = np.zeros(len(points), dtype=bool)
        for chunk in np.array_split(np.arange(len(points)), max(1, len(points) // 65536)):
            offsets = points[None, chunk, :] - self.center[:, None, :]
            near[chunk] = np.any(np.einsum("npi,npi->np", offsets, offsets) <= (radius**2)[:, None], axis=0)
        counts: np.ndarray = self.contains(points[near]).sum(axis=1).astype(np.int64)
        return counts


def _wrap_angle(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2.0 * np.pi) - np.pi
