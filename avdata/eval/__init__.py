"""Evaluation metrics that match their reference implementations.

Modules: ``geometry`` (rotated 3D / BEV / 2D IoU, centre distance), ``tracking`` (HOTA, CLEAR, Identity,
VACE, IDEucl, track rates; TrackEval 1.3.0), ``tracking_io`` (KITTI tracking and MOTChallenge protocols),
``nuscenes_detection`` (mAP, TP errors, NDS; nuscenes-devkit 1.2.0), ``nuscenes_tracking`` (AMOTA, AMOTP),
``kitti_detection`` (AP 11 / 40, 2D / BEV / 3D / AOS), ``prediction`` (ADE, FDE, minADE / minFDE in both
definitions, miss rates), ``unified`` (the avdata protocol on a unified dataset), ``report`` (JSON, Markdown,
PNG) and ``cli`` (the ``avdata eval`` subcommands).
"""
