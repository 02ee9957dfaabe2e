"""Spinning LiDAR models: real beam elevation tables, ray generation, and points from ray hits.

Elevation tables (degrees, laser order as in each manual):

- HDL-64E (S2/S3): 64 lasers in two blocks, upper 32 from +2.0 to -8.33 deg in 1/3 deg steps and
  lower 32 from -8.83 to -24.33 deg in 1/2 deg steps (Velodyne HDL-64E S2 datasheet: vertical field
  of view +2 to -24.9 deg, ~0.4 deg resolution; the per-unit calibration file refines these by
  ~0.1 deg).
- VLP-32C: the 32 angles of the VLP-32C user manual, table 9-2 (-25 to +15 deg, dense around -1 deg).
- VLP-16: -15 to +15 deg in 2 deg steps, interleaved as in the VLP-16 manual (laser 0 = -15,
  laser 1 = +1, ...).

Points are returned in the sensor frame (x forward, y left, z up), azimuth-major: all beams of the
first azimuth step, then the next. Intensity is ``reflectivity * |cos(incidence)| * exp(-2 alpha r)``
with atmospheric attenuation ``alpha = 0.005 / m``, in [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from avdata import portable_math
from avdata.errors import InputError

BEAM_ELEVATIONS_DEG: dict[str, np.ndarray] = {
    "hdl64e": np.concatenate([np.linspace(2.0, -8.33, 32), np.linspace(-8.83, -24.33, 32)]),
    "vlp32c": np.array(
        [-25.0, -1.0, -1.667, -15.639, -11.31, 0.0, -0.667, -8.843, -7.254, 0.333, -0.333, -6.148, -5.333,
         1.333, 0.667, -4.0, -4.667, 1.667, 1.0, -3.667, -3.333, 3.333, 2.333, -2.667, -3.0, 7.0, 4.667,
         -2.333, -2.0, 15.0, 10.333, -1.333]
    ),
    "vlp16": np.array([-15.0, 1.0, -13.0, 3.0, -11.0, 5.0, -9.0, 7.0, -7.0, 9.0, -5.0, 11.0, -3.0, 13.0, -1.0, 15.0]),
}

ATTENUATION_PER_M = 0.005


@dataclass(frozen=True, slots=True, kw_only=True)
class LidarConfig:
    """A spinning LiDAR.

    Attributes:
        model: key of :data:`BEAM_ELEVATIONS_DEG` ("hdl64e", "vlp32c", "vlp16").
        azimuth_steps: firings per sweep over the horizontal field of view.
        horizontal_fov_deg: horizontal field of view, centred on the sensor's x axis.
        max_range_m: returns beyond this are dropped.
        min_range_m: returns closer than this are dropped.
        rate_hz: sweeps per second.
        range_noise_std_m: standard deviation of Gaussian range noise (0: exact ranges).
        dropout: probability that a return is lost.
    """

    model: str = "hdl64e"
    azimuth_steps: int = 2048
    horizontal_fov_deg: float = 360.0
    max_range_m: float = 120.0
    min_range_m: float = 0.5
    rate_hz: float = 10.0
    range_noise_std_m: float = 0.0
    dropout: float = 0.0

    def __post_init__(self) -> None:
        if self.model not in BEAM_ELEVATIONS_DEG:
            raise InputError(f"lidar model: expected one of {sorted(BEAM_ELEVATIONS_DEG)}, got {self.model!r}")

    @property
    def elevations_rad(self) -> np.ndarray:
        """(B,) beam elevations in radians."""
        elevations: np.ndarray = np.deg2rad(BEAM_ELEVATIONS_DEG[self.model])
        return elevations

    def azimuths_rad(self) -> np.ndarray:
        """(A,) firing azimuths, counter-clockwise from x; cell centres across the field of view."""
        fov = np.deg2rad(self.horizontal_fov_deg)
        azimuths: np.ndarray = (np.arange(self.azimuth_steps) + 0.5) * fov / self.azimuth_steps - fov / 2
        return azimuths

    def directions(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit ray directions in the sensor frame and each ray's beam (ring) index.

        Returns:
            (A * B, 3) float32 directions, azimuth-major, and (A * B,) uint16 ring indices.
        """
        elevation = self.elevations_rad
        azimuth = self.azimuths_rad()
        az, el = np.meshgrid(azimuth, elevation, indexing="ij")
        cos_el = np.cos(el)
        dirs = np.stack([cos_el * np.cos(az), cos_el * np.sin(az), np.sin(el)], axis=-1).reshape(-1, 3)
        ring = np.broadcast_to(np.arange(len(elevation), dtype=np.uint16), az.shape).reshape(-1)
        return dirs.astype(np.float32), ring.copy()

    def rays_near(self, center_sensor: np.ndarray, radius_m: np.ndarray) -> np.ndarray:
        """Which rays may pass through any of N spheres: a conservative cull before casting at objects.

        A ray can only meet a sphere of radius r whose centre is at distance d if its angle to the centre
        is at most ``asin(r / d)`` (any angle when the sensor is inside). That bounds the beam's
        elevation and, on a cone around the centre, the azimuth (``asin(sin(alpha) / cos(elevation))``),
        widened by 1 mrad for the float32 directions. The azimuths are evenly spaced, so each sphere's
        azimuth window is a range of firing indices (one more on each side against rounding): the beams
        of every sphere are added at the start of its range and removed after its end, and a running sum
        over the azimuths says which (azimuth, beam) pairs any sphere reaches, without an (N, A) array.

        Args:
            center_sensor: (N, 3) sphere centres in the sensor frame.
            radius_m: (N,) sphere radii.

        Returns:
            (A * B,) bool, azimuth-major like :meth:`directions`; False only for rays that miss every sphere.
        """
        margin_rad = 1e-3
        n_azimuth, n_beam = self.azimuth_steps, len(self.elevations_rad)
        distance = np.linalg.norm(center_sensor, axis=-1)
        inside = distance <= radius_m
        ratio = np.where(inside, 1.0, radius_m / np.maximum(distance, 1e-9))
        half_angle = np.where(inside, np.pi, portable_math.arcsin(np.clip(ratio, 0.0, 1.0)))
        elevation = portable_math.arcsin(np.clip(center_sensor[:, 2] / np.maximum(distance, 1e-9), -1.0, 1.0))
        azimuth = portable_math.arctan2(center_sensor[:, 1], center_sensor[:, 0])
        sin_ratio = np.sin(np.minimum(half_angle, np.pi / 2)) / np.maximum(np.cos(elevation), 1e-9)
        half_width = np.where((half_angle < np.pi / 2) & (sin_ratio < 1.0), portable_math.arcsin(np.minimum(sin_ratio, 1.0)),
                              np.pi)
        beam_ok = np.abs(self.elevations_rad[None, :] - elevation[:, None]) <= half_angle[:, None] + margin_rad
        # Firing k is at (k + 0.5) * step - fov / 2; the window [azimuth - w, azimuth + w] is also tried one
        # turn lower and higher, so a window across +-180 deg still finds the firings on the other side.
        step = np.deg2rad(self.horizontal_fov_deg) / n_azimuth
        half_fov = np.deg2rad(self.horizontal_fov_deg) / 2
        width = half_width + margin_rad
        turns = np.array([-2 * np.pi, 0.0, 2 * np.pi])
        low = azimuth[:, None] - width[:, None] + turns
        high = azimuth[:, None] + width[:, None] + turns
        first = np.clip(np.ceil((low + half_fov) / step - 0.5) - 1, 0, n_azimuth).astype(np.int64)
        last = np.clip(np.floor((high + half_fov) / step - 0.5) + 1, -1, n_azimuth - 1).astype(np.int64)
        every = (width >= np.pi)[:, None] & (turns == 0.0)
        first = np.where(every, 0, first)
        last = np.where(every, n_azimuth - 1, last)
        sphere, window = np.nonzero(last >= first)
        beams = beam_ok[sphere].astype(np.int32)
        change = np.zeros((n_azimuth + 1, n_beam), dtype=np.int32)
        np.add.at(change, first[sphere, window], beams)
        np.subtract.at(change, last[sphere, window] + 1, beams)
        return (np.cumsum(change[:-1], axis=0) > 0).reshape(-1)

    def spec(self) -> dict[str, Any]:
        """The sensor spec written into the scene metadata."""
        return {
            "model": self.model,
            "beams": int(len(self.elevations_rad)),
            "elevations_deg": BEAM_ELEVATIONS_DEG[self.model].round(4).tolist(),
            "azimuth_steps": self.azimuth_steps,
            "horizontal_fov_deg": self.horizontal_fov_deg,
            "max_range_m": self.max_range_m,
            "min_range_m": self.min_range_m,
            "rate_hz": self.rate_hz,
            "range_noise_std_m": self.range_noise_std_m,
            "dropout": self.dropout,
        }


@dataclass(frozen=True, slots=True, kw_only=True)
class RayReturns:
    """Every ray's exact return (no noise, no dropout), misses included: a fixed sensor's static returns.

    Computed once per scene from the static hits and patched per frame where an object is hit
    (:func:`assemble_points`); every field is a function of its own ray alone, so the patched sweep has
    the bits of one computed from scratch.

    Attributes:
        keep: (R,) bool, the ray returns a point (finite hit within the range limits).
        x, y, z: (R,) float32 point in the sensor frame (0 where not kept).
        intensity: (R,) float32 (0 where not kept).
    """

    keep: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    intensity: np.ndarray


def _point_fields(direction: np.ndarray, r: np.ndarray, range_m: np.ndarray, reflectivity: np.ndarray,
                  cos_incidence: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """x, y, z and intensity (float32) of returns: (K, 3) directions, (K,) float32 measured and true ranges."""
    attenuation = portable_math.exp(-2.0 * ATTENUATION_PER_M * range_m.astype(np.float64))
    intensity = reflectivity * np.abs(cos_incidence) * attenuation
    return ((direction[:, 0] * r).astype(np.float32, copy=False), (direction[:, 1] * r).astype(np.float32, copy=False),
            (direction[:, 2] * r).astype(np.float32, copy=False), np.clip(intensity, 0.0, 1.0).astype(np.float32))


def ray_returns(config: LidarConfig, directions_sensor: np.ndarray, range_m: np.ndarray, reflectivity: np.ndarray,
                cos_incidence: np.ndarray) -> RayReturns:
    """The exact return of every ray (see :class:`RayReturns`); arguments as in :func:`assemble_points`."""
    keep = np.isfinite(range_m) & (range_m >= np.float64(config.min_range_m)) & (range_m <= np.float64(config.max_range_m))
    index = np.flatnonzero(keep)
    fields = _point_fields(directions_sensor[index], range_m[index].astype(np.float32, copy=False), range_m[index],
                           reflectivity[index], cos_incidence[index])
    x, y, z, intensity = (np.zeros(len(range_m), dtype=np.float32) for _ in range(4))
    for out, values in zip((x, y, z, intensity), fields, strict=True):
        out[index] = values
    return RayReturns(keep=keep, x=x, y=y, z=z, intensity=intensity)


def assemble_points(
    config: LidarConfig,
    directions_sensor: np.ndarray,
    ring: np.ndarray,
    range_m: np.ndarray,
    object_id: np.ndarray,
    reflectivity: np.ndarray,
    cos_incidence: np.ndarray,
    rng: np.random.Generator,
    static: RayReturns | None = None,
) -> dict[str, np.ndarray]:
    """Turns ray hits into the point fields of one sweep.

    Args:
        config: the LiDAR.
        directions_sensor: (R, 3) unit ray directions in the sensor frame.
        ring: (R,) beam index of each ray.
        range_m: (R,) distance to the first hit (float32 or float64), inf for a miss.
        object_id: (R,) id of the object hit, -1 for the static world.
        reflectivity: (R,) reflectivity of the surface hit.
        cos_incidence: (R,) cosine of the angle between the ray and the surface normal.
        rng: generator for noise and dropout (drawn for every ray, so the stream does not depend on hits).
        static: the returns of these rays' static hits, which every ray with object id -1 has (used only
            without noise and dropout): then only the rays that hit an object are computed.

    Returns:
        Ordered fields: x, y, z, intensity (float32), ring (uint16), object_id (int32), in the sensor frame.
    """
    noise = rng.standard_normal(len(range_m)) * config.range_noise_std_m if config.range_noise_std_m > 0 else None
    kept = rng.random(len(range_m)) >= config.dropout if config.dropout > 0 else True
    if static is not None and noise is None and config.dropout <= 0:
        changed = np.flatnonzero(object_id != -1)
        patch = ray_returns(config, directions_sensor[changed], range_m[changed], reflectivity[changed],
                            cos_incidence[changed])
        keep = static.keep.copy()
        keep[changed] = patch.keep
        index = np.flatnonzero(keep)
        fields = []
        for whole, part in ((static.x, patch.x), (static.y, patch.y), (static.z, patch.z),
                            (static.intensity, patch.intensity)):
            values = whole.copy()
            values[changed] = part
            fields.append(values[index])
        x, y, z, intensity = fields
    else:
        # Without noise the measured range is the hit itself, in its own dtype; the float64 limits make every
        # comparison exact either way.
        measured = range_m if noise is None else range_m.astype(np.float64) + noise
        keep = (kept & np.isfinite(range_m) & (measured >= np.float64(config.min_range_m))
                & (measured <= np.float64(config.max_range_m)))
        index = np.flatnonzero(keep)
        x, y, z, intensity = _point_fields(directions_sensor[index], measured[index].astype(np.float32, copy=False),
                                           range_m[index], reflectivity[index], cos_incidence[index])
    return {
        "x": x,
        "y": y,
        "z": z,
        "intensity": intensity,
        "ring": ring[index].astype(np.uint16, copy=False),
        "object_id": object_id[index].astype(np.int32, copy=False),
    }
