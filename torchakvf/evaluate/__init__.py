"""Evaluation against the Princeton Segmentation Benchmark (PSB).

Submodules (import them directly; this package imports nothing on its own so that
``import torchakvf.evaluate`` stays cheap):

* :mod:`torchakvf.evaluate.metrics`     - the benchmark's four segmentation metrics
* :mod:`torchakvf.evaluate.psb`         - PSB data set access (meshes, human segmentations)
* :mod:`torchakvf.evaluate.archive`     - safe extraction of untrusted zip / tar archives
* :mod:`torchakvf.evaluate.psb_archive` - preparing the PSB from its official archive (file or URL):
  conversion of the benchmark's layout into ours
* :mod:`torchakvf.evaluate.harness`     - ``evaluate_psb``: plan, predict, score, report, as a
  corpus run (:func:`torchakvf.pipeline.runner.run_corpus`) of
  :class:`~torchakvf.evaluate.eval_task.EvalTask`
  (:mod:`~torchakvf.evaluate.settings` (EvalSettings, the settings.json guard),
  :mod:`~torchakvf.evaluate.plan` (meshes and their k's), :mod:`~torchakvf.evaluate.predict`,
  :mod:`~torchakvf.evaluate.score`, :mod:`~torchakvf.evaluate.report`,
  :mod:`~torchakvf.evaluate.gallery`)
* :mod:`torchakvf.evaluate.k_auto`      - choosing k per mesh
* :mod:`torchakvf.evaluate.commands`    - the ``eval`` command

Layers: ``evaluate`` uses ``parts`` (the segmentation engine) and ``pipeline`` (the corpus
runner, worker processes, the batch planner); only :mod:`torchakvf.bench` (which times the evaluation's
prediction) imports ``evaluate``.
"""
