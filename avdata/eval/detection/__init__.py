"""Detection protocols: one module per benchmark, each ``evaluate_<protocol>(...) -> <typed result>``.

* :mod:`.kitti`: KITTI object AP 11 / 40 for 2D, BEV and 3D boxes and AOS (``evaluate_kitti_detection`` ->
  ``KittiDetectionResult``);
* :mod:`.nuscenes`: nuScenes mAP, TP errors and NDS (``evaluate_nuscenes_detection`` ->
  ``NuScenesDetectionResult``);
* :mod:`.av2`: Argoverse 2's AP, ATE, ASE, AOE, CDS (``evaluate_av2_detection`` -> ``Av2DetectionResult``);
* :mod:`.waymo`: Waymo's 3D AP and APH at LEVEL_1 and LEVEL_2 per type (``evaluate_waymo_detection``).

Adding a protocol:

1. a module here with the loaders of the benchmark's files and ``evaluate_<protocol>(gt, pred, config) ->
   <Protocol>Result``, a frozen keyword-only dataclass whose metric names are a ``str`` Enum and whose
   ``summary()`` returns ``{class: {metric: value}}`` (the JSON ``--json`` writes);
2. one :class:`avdata.eval.cli.Protocol` entry in :data:`avdata.eval.cli.DETECTION_PROTOCOLS`: what GT and PRED
   are (shown by ``--help``), whether ``--plots`` draws anything, and the runner;
3. input checks as strict as the reference implementation (refuse what it refuses, with one line naming file,
   sample and value) and an oracle test against it.

Matching helpers are public in :mod:`avdata.eval.matching` (greedy centre matching, Hungarian per frame) and
box overlaps in :mod:`avdata.eval.geometry`; modules never import each other's private names.
"""
