"""Evaluation against the Princeton Segmentation Benchmark (PSB).

Submodules (import them directly; this package imports nothing on its own so that
``import torchakvf.evaluate`` stays cheap):

* :mod:`torchakvf.evaluate.metrics`     - the benchmark's four segmentation metrics
* :mod:`torchakvf.evaluate.psb`         - PSB data set access (meshes, human segmentations)
* :mod:`torchakvf.evaluate.psb_archive` - safe extraction / conversion of the official archive
"""
