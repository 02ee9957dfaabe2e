"""Analytic worlds for the generator tests, where the right answer is known."""

from __future__ import annotations

import numpy as np

from avdata.generators.town import StaticScenery


def scenery(boxes: list[tuple[list[float], list[float]]], with_ground: bool = True) -> StaticScenery:
    """A static world of axis-aligned boxes given as (centre, size), on a ground slab whose top is z = 0."""
    centers = [c for c, _ in boxes]
    sizes = [s for _, s in boxes]
    kinds = ["wall"] * len(boxes)
    if with_ground:
        centers.append([0.0, 0.0, -0.1])
        sizes.append([400.0, 400.0, 0.2])
        kinds.append("ground")
    return StaticScenery(
        box_center=np.array(centers, dtype=np.float64).reshape(-1, 3),
        box_size=np.array(sizes, dtype=np.float64).reshape(-1, 3),
        box_kind=np.array(kinds),
        cylinder_center=np.zeros((0, 3)),
        cylinder_radius=np.zeros(0),
        cylinder_height=np.zeros(0),
        sphere_center=np.zeros((0, 3)),
        sphere_radius=np.zeros(0),
    )
