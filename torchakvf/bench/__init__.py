"""``torchakvf bench``: throughput of the evaluation's PSB segmentation against its own
baselines, measured in one run.

* :mod:`torchakvf.bench.run`     - :func:`run_bench`: select, warm up, the runs, the ratios
* :mod:`torchakvf.bench.runs`    - the runs: torchakvf through the evaluation's batching, scipy
* :mod:`torchakvf.bench.sweep`   - batched against one mesh at a time at several face budgets
* :mod:`torchakvf.bench.report`  - report.json, report.md and the summary lines
* :mod:`torchakvf.bench.command` - the ``bench`` command of the CLI

Layers: ``bench`` uses ``evaluate`` (the prediction path it times) and ``pipeline``; nothing
else imports ``bench``.
"""
