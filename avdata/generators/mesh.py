"""Triangle meshes of the simple shapes the simulated world is made of, built batch-first.

Every shape becomes vertices (V, 3) and triangles (T, 3) in the world frame, together with one entry
per triangle saying which shape it came from, so a ray hit's primitive index maps to an object id with
one array lookup.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Unit box corners (x, y, z in {-1/2, +1/2}) and 12 outward-facing triangles (counter-clockwise seen
# from outside).
_BOX_CORNERS = np.array(
    [[-0.5, -0.5, -0.5], [0.5, -0.5, -0.5], [0.5, 0.5, -0.5], [-0.5, 0.5, -0.5],
     [-0.5, -0.5, 0.5], [0.5, -0.5, 0.5], [0.5, 0.5, 0.5], [-0.5, 0.5, 0.5]]
)
_BOX_TRIANGLES = np.array(
    [[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
     [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]]
)


@dataclass(frozen=True, slots=True, kw_only=True)
class TriangleSoup:
    """Triangles of many shapes in one array.

    Attributes:
        vertices: (V, 3) float32 vertex positions in the world frame.
        triangles: (T, 3) uint32 vertex indices.
        shape_index: (T,) int64 index of the shape each triangle belongs to.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    shape_index: np.ndarray

    @staticmethod
    def concatenate(parts: list[TriangleSoup], shape_offsets: list[int]) -> TriangleSoup:
        """Joins soups, adding ``shape_offsets[i]`` to the shape indices of part ``i``."""
        vertex_offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
        return TriangleSoup(
            vertices=np.concatenate([p.vertices for p in parts]).astype(np.float32),
            triangles=np.concatenate(
                [p.triangles + np.uint32(off) for p, off in zip(parts, vertex_offsets, strict=True)]
            ).astype(np.uint32),
            shape_index=np.concatenate(
                [p.shape_index + off for p, off in zip(parts, shape_offsets, strict=True)]
            ),
        )


def box_corners(center: np.ndarray, size_lwh: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Corners of oriented boxes.

    Args:
        center: (N, 3) box centres.
        size_lwh: (N, 3) length, width, height.
        rotation: (N, 3, 3) box-to-world rotations.

    Returns:
        (N, 8, 3) corners, in the order of ``_BOX_CORNERS``.
    """
    local = _BOX_CORNERS[None] * size_lwh[:, None, :]
    corners: np.ndarray = np.einsum("nij,nkj->nki", rotation, local) + center[:, None, :]
    return corners


def box_mesh(center: np.ndarray, size_lwh: np.ndarray, rotation: np.ndarray) -> TriangleSoup:
    """Closed triangle meshes of N oriented boxes (12 triangles each).

    Args:
        center: (N, 3) box centres.
        size_lwh: (N, 3) length, width, height.
        rotation: (N, 3, 3) box-to-world rotations.
    """
    n = len(center)
    corners = box_corners(center, size_lwh, rotation)
    triangles = _BOX_TRIANGLES[None] + 8 * np.arange(n)[:, None, None]
    return TriangleSoup(
        vertices=corners.reshape(-1, 3).astype(np.float32),
        triangles=triangles.reshape(-1, 3).astype(np.uint32),
        shape_index=np.repeat(np.arange(n), 12),
    )


def _template_mesh(template_vertices: np.ndarray, template_triangles: np.ndarray, center: np.ndarray,
                   scale: np.ndarray) -> TriangleSoup:
    n = len(center)
    vertices = template_vertices[None] * scale[:, None, :] + center[:, None, :]
    triangles = template_triangles[None] + len(template_vertices) * np.arange(n)[:, None, None]
    return TriangleSoup(
        vertices=vertices.reshape(-1, 3).astype(np.float32),
        triangles=triangles.reshape(-1, 3).astype(np.uint32),
        shape_index=np.repeat(np.arange(n), len(template_triangles)),
    )


def cylinder_mesh(center: np.ndarray, radius: np.ndarray, height: np.ndarray, sides: int = 12) -> TriangleSoup:
    """Upright (z-axis) closed cylinders approximated by prisms with ``sides`` faces.

    Args:
        center: (N, 3) centres (half-way up).
        radius: (N,) radii in metres.
        height: (N,) heights in metres.
        sides: faces of each prism.
    """
    angle = 2.0 * np.pi * np.arange(sides) / sides
    ring = np.stack([np.cos(angle), np.sin(angle)], axis=-1)
    vertices = np.concatenate(
        [np.c_[ring, np.full(sides, -0.5)], np.c_[ring, np.full(sides, 0.5)], [[0, 0, -0.5], [0, 0, 0.5]]]
    )
    i = np.arange(sides)
    j = (i + 1) % sides
    bottom, top = 2 * sides, 2 * sides + 1
    triangles = np.concatenate(
        [
            np.stack([i, j, sides + j], axis=-1),
            np.stack([i, sides + j, sides + i], axis=-1),
            np.stack([np.full(sides, bottom), j, i], axis=-1),
            np.stack([np.full(sides, top), sides + i, sides + j], axis=-1),
        ]
    )
    scale = np.stack([radius, radius, height], axis=-1)
    return _template_mesh(vertices, triangles, center, scale)


def sphere_mesh(center: np.ndarray, radius: np.ndarray, rings: int = 6, segments: int = 10) -> TriangleSoup:
    """UV spheres.

    Args:
        center: (N, 3) centres.
        radius: (N,) radii in metres.
        rings: latitude bands from pole to pole.
        segments: longitude segments around the z axis.
    """
    polar = np.pi * np.arange(1, rings) / rings
    azimuth = 2.0 * np.pi * np.arange(segments) / segments
    p, a = np.meshgrid(polar, azimuth, indexing="ij")
    body = np.stack([np.sin(p) * np.cos(a), np.sin(p) * np.sin(a), np.cos(p)], axis=-1).reshape(-1, 3)
    vertices = np.concatenate([body, [[0, 0, 1], [0, 0, -1]]])
    north, south = len(body), len(body) + 1
    r, s = np.meshgrid(np.arange(rings - 2), np.arange(segments), indexing="ij")
    a0 = r * segments + s
    a1 = r * segments + (s + 1) % segments
    b0, b1 = a0 + segments, a1 + segments
    quads = np.concatenate([np.stack([a0, b0, b1], -1).reshape(-1, 3), np.stack([a0, b1, a1], -1).reshape(-1, 3)])
    s1 = np.arange(segments)
    s2 = (s1 + 1) % segments
    last = (rings - 2) * segments
    caps = np.concatenate(
        [np.stack([np.full(segments, north), s1, s2], -1), np.stack([np.full(segments, south), last + s2, last + s1], -1)]
    )
    triangles = np.concatenate([quads, caps])
    return _template_mesh(vertices, triangles, center, np.repeat(radius[:, None], 3, axis=1))
