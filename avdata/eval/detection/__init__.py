"""Detection metrics of each dataset's own protocol, one module per protocol.

* ``av2``: Argoverse 2's AP, ATE, ASE, AOE, CDS (av2's ``evaluate``);
* ``waymo``: Waymo's 3D AP and APH at LEVEL_1 and LEVEL_2 per type (``waymo_open_dataset.metrics``).
"""
