"""Names of the tracking metric families and similarity measures.

Kept apart from the metric code so the command line can list the choices without importing
scipy (``avdata --help`` and every other subcommand would otherwise pay for it).
"""

from __future__ import annotations

from enum import Enum


class TrackingMetric(str, Enum):
    """Tracking metric families, named as TrackEval names its metric classes: the registry of their names.

    A member registers a family; the family itself is declared once, as ``FAMILY`` in the module
    ``avdata.eval.tracking.<member name in lower case>`` (see :mod:`avdata.eval.tracking.results`).
    """

    HOTA = "HOTA"
    CLEAR = "CLEAR"
    IDENTITY = "Identity"
    VACE = "VACE"
    IDEUCL = "IDEucl"
    TRACK_RATES = "TrackRates"


class Similarity(str, Enum):
    """How a ground-truth box and a tracker box are compared."""

    IOU_2D = "iou_2d"
    IOU_BEV = "iou_bev"
    IOU_3D = "iou_3d"
    EUCLIDEAN = "euclidean"
