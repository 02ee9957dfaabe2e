"""LiDAR model: beam tables and ray casting against analytic scenes."""

from __future__ import annotations

import numpy as np

from avdata.frames import Transform
from avdata.generators.lidar import BEAM_ELEVATIONS_DEG, LidarConfig, assemble_points, ray_returns
from avdata.generators.mesh import box_mesh
from avdata.generators.raycast import RaycastWorld, StaticGeometry, ray_array, rotated_rays
from avdata.generators.sensing import lidar_hits, lidar_rays
from avdata.generators.world import SimWorld
from tests.generators.scenes import scenery


def _wall_world(distance_m: float) -> RaycastWorld:
    # A wall whose near face is the plane x = distance_m, 200 m wide and tall.
    wall = box_mesh(np.array([[distance_m + 0.5, 0.0, 0.0]]), np.array([[1.0, 200.0, 200.0]]), np.eye(3)[None])
    empty = box_mesh(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3, 3)))
    return RaycastWorld(StaticGeometry(wall, np.full(12, 0.5, dtype=np.float32), np.full((12, 3), 0.5)), empty,
                        np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros((0, 3)))


def test_beam_tables_have_the_datasheet_counts_and_limits():
    assert len(BEAM_ELEVATIONS_DEG["hdl64e"]) == 64
    assert BEAM_ELEVATIONS_DEG["hdl64e"].max() == 2.0 and np.isclose(BEAM_ELEVATIONS_DEG["hdl64e"].min(), -24.33)
    assert len(BEAM_ELEVATIONS_DEG["vlp32c"]) == 32
    assert (BEAM_ELEVATIONS_DEG["vlp32c"].min(), BEAM_ELEVATIONS_DEG["vlp32c"].max()) == (-25.0, 15.0)
    assert len(set(BEAM_ELEVATIONS_DEG["vlp32c"].tolist())) == 32
    assert sorted(BEAM_ELEVATIONS_DEG["vlp16"].tolist()) == list(range(-15, 16, 2))


def test_lidar_facing_a_wall_at_10_m_measures_10_m_on_every_beam():
    config = LidarConfig(model="hdl64e", azimuth_steps=90, horizontal_fov_deg=90.0, max_range_m=100.0)
    dirs, ring = config.directions()
    hits = _wall_world(10.0).cast(ray_array(np.zeros(3), dirs.astype(np.float64)))
    points = assemble_points(config, dirs, ring, hits.range_m, hits.object_id, hits.reflectivity,
                             hits.cos_incidence, np.random.default_rng(0))
    # Every ray of a 90 deg fan hits the wall; the distance to the wall plane is 10 m on every beam.
    assert len(points["x"]) == len(dirs)
    np.testing.assert_allclose(points["x"], 10.0, atol=1e-4)
    assert set(points["ring"].tolist()) == set(range(64))
    # The ray straight ahead of each beam at zero azimuth: range 10 / cos(elevation).
    rng_m = np.sqrt(points["x"] ** 2 + points["y"] ** 2 + points["z"] ** 2)
    expected = 10.0 / (np.cos(np.arctan2(points["z"], np.hypot(points["x"], points["y"])))
                       * np.cos(np.arctan2(points["y"], points["x"])))
    np.testing.assert_allclose(rng_m, expected, rtol=1e-5)
    # Recovered elevations are the datasheet's.
    elevation = np.rad2deg(np.arcsin(points["z"] / rng_m))
    np.testing.assert_allclose(elevation, BEAM_ELEVATIONS_DEG["hdl64e"][points["ring"]], atol=1e-3)
    assert np.all(points["object_id"] == -1)


def test_intensity_falls_with_incidence_and_noise_has_the_configured_spread():
    config = LidarConfig(model="vlp16", azimuth_steps=360, horizontal_fov_deg=120.0, range_noise_std_m=0.05)
    dirs, ring = config.directions()
    hits = _wall_world(10.0).cast(ray_array(np.zeros(3), dirs.astype(np.float64)))
    points = assemble_points(config, dirs, ring, hits.range_m, hits.object_id, hits.reflectivity,
                             hits.cos_incidence, np.random.default_rng(1))
    rng_m = np.sqrt(points["x"] ** 2 + points["y"] ** 2 + points["z"] ** 2)
    error = rng_m - hits.range_m
    assert abs(error.std() - 0.05) < 0.005 and abs(error.mean()) < 0.005
    head_on = np.argmin(np.abs(np.arctan2(points["y"], points["x"])) + np.abs(points["z"]))
    grazing = np.argmax(np.abs(points["y"]))
    assert points["intensity"][head_on] > 2 * points["intensity"][grazing]
    dropped = assemble_points(LidarConfig(model="vlp16", azimuth_steps=360, horizontal_fov_deg=120.0, dropout=0.25),
                              dirs, ring, hits.range_m, hits.object_id, hits.reflectivity, hits.cos_incidence,
                              np.random.default_rng(2))
    assert abs(len(dropped["x"]) / len(dirs) - 0.75) < 0.02


def test_points_carry_the_id_of_the_object_they_hit_and_lie_on_its_box():
    world = SimWorld(scenery([]), np.array([5, 9]), np.array(["car", "pedestrian"]),
                     np.array([[4.0, 1.8, 1.5], [0.8, 0.7, 1.8]]))
    try:
        center = np.array([[8.0, 2.0, 0.75], [12.0, -3.0, 0.9]])
        yaw = np.array([0.3, -1.0])
        world.set_object_poses(center, yaw)
        config = LidarConfig(model="hdl64e", azimuth_steps=2048)
        dirs, ring = config.directions()
        origin = np.array([0.0, 0.0, 1.73])
        hits = world.raycast_world().cast(ray_array(origin, dirs.astype(np.float64)))
        points = assemble_points(config, dirs, ring, hits.range_m, hits.object_id, hits.reflectivity,
                                 hits.cos_incidence, np.random.default_rng(0))
        xyz = np.stack([points["x"], points["y"], points["z"]], axis=-1) + origin
        for k, (c, y, size) in enumerate(zip(center, yaw, world.size_lwh, strict=True)):
            mine = xyz[points["object_id"] == world.object_ids[k]]
            assert len(mine) > 20
            local = (mine - c) @ np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
            assert np.all(np.abs(local) <= size / 2 + 1e-3)
        assert set(np.unique(points["object_id"]).tolist()) == {-1, 5, 9}
    finally:
        world.close()


def test_rays_near_keeps_every_ray_that_meets_a_sphere_and_drops_most_others():
    rng = np.random.default_rng(7)
    config = LidarConfig(model="hdl64e", azimuth_steps=1024)
    dirs = config.directions()[0].astype(np.float64)
    # Spheres all around, near the sensor (down to 1.5 radii, where the cone is wide) and far, up to 60 deg high.
    distance = rng.uniform(2.0, 60.0, 40)
    azimuth = rng.uniform(-np.pi, np.pi, 40)
    elevation = rng.uniform(-0.5, 1.0, 40)
    center = distance[:, None] * np.c_[np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                                       np.sin(elevation)]
    radius = np.minimum(rng.uniform(0.3, 3.0, 40), distance / 1.5)
    near = config.rays_near(center, radius)
    # Exact test: the ray meets the sphere where its closest approach is within the radius (in front).
    along = dirs @ center.T
    closest = np.linalg.norm(center, axis=1)[None, :] ** 2 - along**2
    meets = ((along > 0) & (closest <= radius[None, :] ** 2)).any(axis=1)
    assert meets.sum() > 1000
    assert not (meets & ~near).any()
    assert near.sum() < 2 * meets.sum() + 0.05 * len(near)  # a cull, not "every ray"
    inside = config.rays_near(np.array([[0.5, 0.0, 0.0]]), np.array([1.0]))
    assert inside.all()


def test_rays_near_of_a_half_field_of_view_keeps_rays_of_spheres_across_its_edges_and_behind():
    rng = np.random.default_rng(11)
    config = LidarConfig(model="vlp32c", azimuth_steps=600, horizontal_fov_deg=180.0)
    dirs = config.directions()[0].astype(np.float64)
    # Centres all around, many near +-90 deg (the field of view's edges) and near 180 deg (behind, across the seam).
    azimuth = np.concatenate([rng.uniform(-np.pi, np.pi, 30), rng.normal(np.pi / 2, 0.1, 10),
                              rng.normal(-np.pi / 2, 0.1, 10), rng.normal(np.pi, 0.2, 10)])
    distance = rng.uniform(2.0, 40.0, len(azimuth))
    elevation = rng.uniform(-0.4, 0.3, len(azimuth))
    center = distance[:, None] * np.c_[np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                                       np.sin(elevation)]
    radius = np.minimum(rng.uniform(0.3, 4.0, len(azimuth)), distance / 1.2)
    near = config.rays_near(center, radius)
    along = dirs @ center.T
    closest = np.linalg.norm(center, axis=1)[None, :] ** 2 - along**2
    meets = ((along > 0) & (closest <= radius[None, :] ** 2)).any(axis=1)
    assert meets.sum() > 500
    assert not (meets & ~near).any()
    assert near.sum() < 2 * meets.sum() + 0.05 * len(near)
    # A sphere straddling the sensor's back: no firing of a front-only LiDAR can reach it.
    assert not config.rays_near(np.array([[-10.0, 0.0, 0.0]]), np.array([1.0])).any()


def test_points_patched_from_kept_static_returns_equal_points_computed_from_scratch():
    rng = np.random.default_rng(5)
    config = LidarConfig(model="hdl64e", azimuth_steps=256, min_range_m=0.9, max_range_m=60.0)
    dirs, ring = config.directions()
    n = len(ring)
    static_range = np.where(rng.random(n) < 0.8, rng.uniform(0.1, 90.0, n), np.inf).astype(np.float32)
    static_reflectivity = rng.uniform(0.1, 0.5, n).astype(np.float32)
    static_cos = rng.uniform(-1.0, 1.0, n).astype(np.float32)
    static = ray_returns(config, dirs, static_range, static_reflectivity, static_cos)
    # Objects in front of a quarter of the rays, some beyond the range limits.
    on_object = rng.random(n) < 0.25
    range_m = np.where(on_object, rng.uniform(0.2, 70.0, n).astype(np.float32), static_range)
    object_id = np.where(on_object, rng.integers(0, 40, n), -1).astype(np.int32)
    reflectivity = np.where(on_object, np.float32(0.6), static_reflectivity)
    cos_incidence = np.where(on_object, rng.uniform(-1.0, 1.0, n).astype(np.float32), static_cos)
    args = (config, dirs, ring, range_m, object_id, reflectivity, cos_incidence)
    patched = assemble_points(*args, np.random.default_rng(0), static)
    scratch = assemble_points(*args, np.random.default_rng(0))
    assert list(patched) == list(scratch)
    for name in scratch:
        assert patched[name].dtype == scratch[name].dtype
        np.testing.assert_array_equal(patched[name], scratch[name])
    assert 0.3 * n < len(scratch["x"]) < 0.9 * n and (scratch["object_id"] >= 0).sum() > 0.1 * n
    # With noise the kept returns do not apply: the sweep is computed from scratch.
    noisy = LidarConfig(model="hdl64e", azimuth_steps=256, range_noise_std_m=0.02)
    noisy_args = (noisy, dirs, ring, range_m, object_id, reflectivity, cos_incidence)
    np.testing.assert_array_equal(assemble_points(*noisy_args, np.random.default_rng(1), static)["x"],
                                  assemble_points(*noisy_args, np.random.default_rng(1))["x"])


def test_an_ego_lidar_skips_only_rays_that_surely_hit_its_own_car_first():
    # The ego (object 0), its LiDAR 20 cm above the roof; a car close behind, a van alongside and a pedestrian
    # ahead, whose culls keep many of the roof rays (the van's sphere is 1.1 m from the sensor, nearer than some
    # roof hits and farther than others); a box overlapping the ego's front (objects never do; geometry allows
    # it) that some rays meet before the roof; a wall. Skipped or not, every ray's answer is that of casting it.
    sizes = np.array([[4.5, 1.8, 1.5], [4.5, 1.8, 1.5], [5.0, 2.0, 2.2], [0.8, 0.7, 1.8], [0.8, 0.7, 1.8]])
    centers = np.array([[0.0, 0.0, 0.75], [-5.6, 0.3, 0.75], [0.5, 4.0, 1.1], [3.5, -1.8, 0.9], [1.8, 0.6, 1.9]])
    yaws = np.array([0.0, 0.1, -0.05, 1.0, 0.0])
    world = SimWorld(scenery([([10.0, -6.0, 2.0], [2.0, 4.0, 4.0])]), np.arange(5),
                     np.array(["car", "car", "van", "pedestrian", "pedestrian"]), sizes)
    try:
        world.set_object_poses(centers, yaws)
        center, rotation = world.object_poses()
        raycast = world.raycast_world()
    finally:
        world.close()
    agent_T_sensor = Transform.from_yaw(np.float64(0.0), translation=np.array([0.0, 0.0, 1.7]))
    agent_T_box = Transform.from_yaw(np.float64(0.0), translation=np.array([0.0, 0.0, 0.75]))
    world_T_sensor = Transform.from_yaw(np.float64(0.0), translation=np.zeros(3)) @ agent_T_sensor
    rays = lidar_rays(LidarConfig(azimuth_steps=1024), raycast, None, (agent_T_sensor.inverse() @ agent_T_box, sizes[0]))
    hits = lidar_hits(raycast, rays, world_T_sensor, center, rotation, sizes, carrier_index=0)
    cast = raycast.cast(ray_array(world_T_sensor.translation, world_T_sensor.apply_vector(rays.directions_sensor)))
    own = cast.object_id == 0
    assert own.sum() > 10_000 and {1, 2, 3, 4} <= set(cast.object_id.tolist())
    np.testing.assert_array_equal(hits.object_id, cast.object_id)
    assert np.isinf(hits.range_m[own]).all()
    for field in ("range_m", "reflectivity", "cos_incidence"):
        np.testing.assert_array_equal(getattr(hits, field)[~own], getattr(cast, field)[~own])


def test_rays_built_from_rows_and_rotated_columns_have_the_bits_of_the_plain_formulas():
    # The fast ray builders must give exactly the float32 values of assigning origins and directions and of
    # Transform.apply_vector (generated bytes depend on it); an awkward pose, rays in every direction.
    dirs, _ = LidarConfig(model="vlp32c", azimuth_steps=500).directions()
    world_T_sensor = Transform.from_euler("ZYX", np.array([2.1, -0.3, 0.7]), translation=np.array([12.3, -4.56, 7.89]))
    plain = np.empty((len(dirs), 6), dtype=np.float32)
    plain[:, :3] = world_T_sensor.translation
    plain[:, 3:] = world_T_sensor.apply_vector(dirs)
    rotated = rotated_rays(world_T_sensor.translation, world_T_sensor.rotation, np.ascontiguousarray(dirs.T))
    from_rows = ray_array(world_T_sensor.translation, world_T_sensor.apply_vector(dirs))
    assert rotated.dtype == from_rows.dtype == np.float32
    np.testing.assert_array_equal(rotated.view(np.uint32), plain.view(np.uint32))
    np.testing.assert_array_equal(from_rows.view(np.uint32), plain.view(np.uint32))
    # Per-ray origins and float64 input are rounded to float32 as an assignment rounds them.
    origins = np.random.default_rng(0).normal(size=(len(dirs), 3)) * 50
    plain[:, :3] = origins
    plain[:, 3:] = dirs.astype(np.float64) * 1.1
    np.testing.assert_array_equal(ray_array(origins, dirs.astype(np.float64) * 1.1).view(np.uint32), plain.view(np.uint32))
