"""Evaluation metrics that match their reference implementations.

Layout (each concept in one place):

* :mod:`.geometry`: rotated 3D / BEV / 2D IoU and centre distances;
* :mod:`.matching`: the public matching API (candidate sweep, per-frame Hungarian, greedy centre matching);
* :mod:`.tracking`: HOTA, CLEAR, Identity, VACE, IDEucl and track rates (TrackEval 1.3.0), one module per
  family with typed results (:class:`~avdata.eval.tracking.FamilyResult`, field names as ``str`` Enums), and the
  protocols :mod:`.tracking.kitti`, :mod:`.tracking.mot` and :mod:`.tracking.nuscenes` (AMOTA, AMOTP);
* :mod:`.detection`: one module per detection protocol (:mod:`.detection.kitti`, :mod:`.detection.nuscenes`,
  :mod:`.detection.av2`, :mod:`.detection.waymo`); its docstring says how to add one;
* :mod:`.prediction`: ADE, FDE, minADE / minFDE in both definitions, miss rates;
* :mod:`.safety`: RSS safe-distance violations of the ego (``avdata eval safety``);
* :mod:`.unified`: the avdata protocol on a unified dataset (ground truth from ``index/*.parquet``, ego poses
  from ``frames.parquet``);
* :mod:`.nuscenes_gt`: nuScenes ground truth shared by detection and tracking; :mod:`.textfiles`: numbers
  from text result files;
* :mod:`.problems`: :class:`~avdata.eval.problems.EvalWarning` for accepted-but-suspicious inputs;
* :mod:`.report` (JSON, Markdown, PNG) and :mod:`.cli` (the ``avdata eval`` subcommands and the protocol
  registry).

Inputs are as strict as the reference implementations: where TrackEval or the nuScenes devkit refuses an input,
these raise :class:`~avdata.errors.InputError` with one line naming the file, sequence / sample and value.
"""
