"""Seeing and comparing datasets: a Foxglove layout, rendered pictures and videos, cross-dataset statistics.

* :mod:`~avdata.viz.layout`: ``avdata view``: a Foxglove layout for a dataset's topics.
* :mod:`~avdata.viz.render`: ``avdata render``: a bird's-eye view and each camera with projected boxes (PNG / MP4).
* :mod:`~avdata.viz.stats`: ``avdata stats``: distributions per dataset and the distances between datasets.
"""
