"""Simulated V2I scenes: a pybullet world, ray-cast sensors, and labels of what each sensor can see.

Pipeline (one module each): :mod:`~avdata.generators.town` builds a procedural town (lanes,
intersections, sidewalks, crosswalks, buildings, walls, poles, trees, parking spaces);
:mod:`~avdata.generators.traffic` drives vehicles (IDM car-following, signalised intersections) and
pedestrians with sizes from :mod:`~avdata.generators.sizes`; :mod:`~avdata.generators.bodies` holds the
objects' poses in pybullet; :mod:`~avdata.generators.world` adds the matching ray-casting geometry;
:mod:`~avdata.generators.raycast` casts LiDAR rays (:mod:`~avdata.generators.lidar`) and camera rays
(:mod:`~avdata.generators.render`) through Open3D with an object id per hit;
:mod:`~avdata.generators.visibility` labels what each sensor sees; :mod:`~avdata.generators.simulator`
steps a scene's world and agents, :mod:`~avdata.generators.sensing` samples one frame's sensors, and
:mod:`~avdata.generators.scenario` runs a scenario (:mod:`~avdata.generators.config`, ``presets/*.yaml``)
and writes the unified format;
:mod:`~avdata.generators.cli` is ``avdata generate``.

Open3D and pybullet are imported only inside this package (``pip install 'avdata[sim]'``).
"""
