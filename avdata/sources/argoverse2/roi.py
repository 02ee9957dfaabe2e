"""The region of interest (ROI) raster of an AV2 log map, built as av2-api 0.3.6 builds it.

av2's detection evaluation keeps a cuboid only if one of its 8 vertices lies in the ROI
(``compute_objects_in_roi_mask``). The ROI is not stored: ``ArgoverseStaticMap.from_map_dir(...,
build_raster=True)`` makes it from the vector map's drivable-area polygons, step for step:

1. grid: 10 cm cells; ``x_min = floor(min x)``, ``y_min = floor(min y)`` (likewise ceil for the
   maxima) over every polygon vertex; ``h = int((y_max - y_min + 1) * 10)``, ``w`` likewise;
   ``p_grid = 10 * (p_city - (x_min, y_min))`` (a Sim(2) with R = I).
2. each polygon's vertices to the grid, rounded half to even (``np.round``) to int32, drawn with
   Pillow ``ImageDraw.polygon(outline=1, fill=1)`` on an ``L`` image: the drivable-area mask.
3. ROI = every cell whose L2 distance (OpenCV ``distanceTransform``, ``DIST_MASK_PRECISE``) to the
   nearest drivable-area cell is at most 5 m = 50 cells.
4. a city point is in the ROI when its grid coordinates, truncated toward zero (``astype(int64)``),
   index a cell inside the grid whose value is 1.

Pillow's polygon filling is reproduced by calling Pillow (a dependency of matplotlib), because
scan-conversion rules at edge cells differ between rasterisers and the ROI edge decides which
cuboids count; the test compares the whole raster cell for cell with av2's.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from avdata.errors import InputError
from avdata.inputs import read_regular_file, unique_object

#: av2 ``ONLINE_RASTER_RESOLUTION_SCALE``: cells per metre.
RASTER_CELLS_PER_M = 10.0
#: av2 ``ROI_ISOCONTOUR_M``: how far the ROI reaches beyond the drivable area.
ROI_DILATION_M = 5.0


@dataclass(frozen=True, slots=True, kw_only=True)
class RoiRaster:
    """A binary ROI grid and the map from city xy to grid (column, row) coordinates.

    Attributes:
        mask: (H, W) uint8, 1 inside the ROI.
        origin_city_m: (2,) city (x, y) of grid cell (0, 0)'s corner: ``p_grid = scale * (p_city - origin)``.
        cells_per_m: grid scale.
    """

    mask: np.ndarray
    origin_city_m: np.ndarray
    cells_per_m: float

    def contains(self, points_city: np.ndarray) -> np.ndarray:
        """(N,) bool: whether each (N, 2+) city point falls in a ROI cell (False outside the grid)."""
        xy = np.asarray(points_city, dtype=np.float64)[:, :2]
        # av2's Sim2.transform_from: (p @ R.T + t) * s with R = I, t = -origin.
        grid = ((xy + (-self.origin_city_m)) * self.cells_per_m).astype(np.int64)
        height, width = self.mask.shape
        inside = (grid[:, 1] >= 0) & (grid[:, 1] < height) & (grid[:, 0] >= 0) & (grid[:, 0] < width)
        values = np.zeros(len(xy), dtype=bool)
        values[inside] = self.mask[grid[inside, 1], grid[inside, 0]] == 1
        return values


def read_drivable_areas(map_dir: Path) -> list[np.ndarray]:
    """The drivable-area polygons of ``map/log_map_archive_*.json``, each (K, 3) city xyz, in file order."""
    paths = sorted(map_dir.glob("log_map_archive_*.json"))
    if len(paths) != 1:
        raise InputError(f"{map_dir}: expected one log_map_archive_*.json, got {[p.name for p in paths]}")
    try:
        raw = read_regular_file(paths[0])  # a FIFO is refused, not waited on
    except OSError as error:
        raise InputError(f"{paths[0]}: cannot read ({error.strerror or error})") from None
    try:
        data = json.loads(raw, object_pairs_hook=unique_object)  # ValueError: a key given twice
        areas = data["drivable_areas"]
        polygons = [
            np.array([[float(v["x"]), float(v["y"]), float(v["z"])] for v in area["area_boundary"]])
            for area in areas.values()
        ]
    except (ValueError, KeyError, TypeError, AttributeError) as error:
        raise InputError(f"{paths[0]}: expected drivable_areas with area_boundary x, y, z, got {error!r}") from None
    polygons = [p for p in polygons if len(p)]
    if not polygons:
        raise InputError(f"{paths[0]}: expected at least one drivable area, got none")
    return polygons


def roi_raster(polygons_city: list[np.ndarray]) -> RoiRaster:
    """The ROI grid of drivable-area polygons (see the module docstring for each step)."""
    import cv2
    from PIL import Image, ImageDraw

    x_min = math.floor(min(p[:, 0].min() for p in polygons_city))
    y_min = math.floor(min(p[:, 1].min() for p in polygons_city))
    x_max = math.ceil(max(p[:, 0].max() for p in polygons_city))
    y_max = math.ceil(max(p[:, 1].max() for p in polygons_city))
    height = int((y_max - y_min + 1) * RASTER_CELLS_PER_M)
    width = int((x_max - x_min + 1) * RASTER_CELLS_PER_M)
    origin = np.array([x_min, y_min], dtype=np.float64)
    image = Image.new("L", size=(width, height), color=0)
    draw = ImageDraw.Draw(image)
    for polygon in polygons_city:
        grid = np.round((polygon[:, :2] + (-origin)) * RASTER_CELLS_PER_M).astype(np.int32)
        draw.polygon([(x, y) for x, y in grid.tolist()], outline=1, fill=1)
    drivable = np.array(image)
    distance = cv2.distanceTransform(1 - drivable, distanceType=cv2.DIST_L2, maskSize=cv2.DIST_MASK_PRECISE)
    mask = (distance.astype(np.float32) <= ROI_DILATION_M * RASTER_CELLS_PER_M).astype(np.uint8)
    return RoiRaster(mask=mask, origin_city_m=origin, cells_per_m=RASTER_CELLS_PER_M)


def log_roi(log_dir: Path) -> RoiRaster:
    """The ROI raster of one log (``<log_dir>/map``)."""
    return roi_raster(read_drivable_areas(log_dir / "map"))
