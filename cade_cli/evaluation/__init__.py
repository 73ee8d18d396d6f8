"""Evaluation: protocols, metrics, the one benchmark loop and its reports.

* :mod:`~cade_cli.evaluation.protocols`: which bands are matched (``cs``, ``rgb``,
  ``native``); every returned map goes through the one fill stage
  (:func:`cade_cli.matching.disparity.densify`) there.
* :mod:`~cade_cli.evaluation.metrics`: EPE, bad-pixel rates, KITTI's D1, the invalid share, and the
  sparsification areas that say how well a matcher's confidence ranks its errors.
* :mod:`~cade_cli.evaluation.regions`: the pixel sets scored besides all pixels (non-occluded,
  depth edges, occluded), computed once per scene by the loop.
* :mod:`~cade_cli.evaluation.loop`: one unit of work per scene (decoded once), with task
  subsets, degradations (:mod:`~cade_cli.evaluation.degradations`) and timing
  (:mod:`~cade_cli.evaluation.timing`) as options; used by ``cade benchmark``, the
  scripts in ``benchmarks/`` and the training's validation metrics.
* :mod:`~cade_cli.evaluation.report`: Table-1-style tables and the Markdown report.
* :mod:`~cade_cli.evaluation.html_report`: the HTML report, with each scene's pictures
  (:mod:`~cade_cli.evaluation.album`, drawn where the maps are; error pictures:
  :mod:`~cade_cli.evaluation.error_maps`, as ``--save-dir`` writes them).

Import from the modules; this package imports nothing itself, so that
:mod:`~cade_cli.evaluation.timing` can be loaded before NumPy (to cap its threads).
"""
