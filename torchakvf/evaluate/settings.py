"""The settings of an evaluation besides the segmentation options, and the record of both that
guards an output folder against predictions made under other settings."""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import TorchAKVFError
from ..options import SegmentOptions, segment_options
from .k_auto import DEFAULT_K_RANGE, DEFAULT_RULE, RULES, check_k_range, scan_overseg
from .plan import DEFAULT_K_NO_GT, PROTOCOLS

__all__ = ["EvalSettings", "EVAL_SEGMENT_DEFAULTS", "eval_segment_options", "split_overrides",
           "changed_options", "prediction_record", "settings_guard"]

#: Segmentation options whose evaluation default differs from :func:`~torchakvf.parts.segment`'s:
#: the parts are not refined (the benchmark scores the labels as cut).
EVAL_SEGMENT_DEFAULTS = {"refine": False}


@dataclass(frozen=True)
class EvalSettings:
    """How an evaluation runs, besides the segmentation options (:class:`SegmentOptions`).

    protocol : "by-segmentation" (default) or "by-model" (see :mod:`.harness`)
    categories : category names (list or comma string; None: all 19)
    ids : mesh ids (list, or a string like "1,5,21-23"); combined with ``categories``
    per_category : keep only the first N meshes (by id) of each category (quick runs)
    k_mode : None (k from the protocol) or "auto" (:mod:`torchakvf.evaluate.k_auto`)
    k_range, k_rule : the k's tried and the rule with k_mode "auto" (default (2, 10), "merge")
    default_k : parts for meshes without human segmentations (given-k protocols)
    n_fields : fields untangled per mesh (None: the engine's default per k)
    coarse_faces : solve on meshes decimated to about N faces and cut the parts on the
        originals (None: full resolution; :mod:`torchakvf.mesh.coarse`)
    metrics : metric groups, e.g. "rand,hamming" (None: all)
    batch_faces : face budget of one batch (None:
        :func:`torchakvf.pipeline.batches.default_batch_faces` for the device)
    batch_bytes : bytes a batch's padded solver arrays may take on the batched path (None: a
        share of the device's free memory on a GPU, 256 MiB on the CPU;
        :func:`torchakvf.pipeline.batches.batch_bytes_budget`)
    workers : processes predicting batches side by side, one thread each (None: 1, this
        process); on the batched path the solving process and its host workers
    ray_workers : run the batches on this many Ray actors (:mod:`torchakvf.pipeline.ray_runner`;
        0: no Ray); with a cuda device one GPU each
    device : torch device of the predictions (use one worker on a GPU)
    plot : write rand_index.png and the galleries
    """

    protocol: str = "by-segmentation"
    categories: object = None
    ids: object = None
    per_category: int | None = None
    k_mode: str | None = None
    k_range: tuple | None = None
    k_rule: str = DEFAULT_RULE
    default_k: int = DEFAULT_K_NO_GT
    n_fields: int | None = None
    coarse_faces: int | None = None
    metrics: object = None
    batch_faces: int | None = None
    batch_bytes: int | None = None
    workers: int | None = None
    ray_workers: int = 0
    device: str = "cpu"
    plot: bool = True

    @property
    def auto(self) -> bool:
        return self.k_mode == "auto"

    def checked(self) -> "EvalSettings":
        """These settings with ``k_range`` filled in for k auto; one-line errors for bad values."""
        if self.protocol not in PROTOCOLS:
            raise TorchAKVFError(f"unknown protocol {self.protocol!r}; choose from {', '.join(PROTOCOLS)}")
        if self.k_mode not in (None, "auto"):
            raise TorchAKVFError(f"k_mode must be None or 'auto', got {self.k_mode!r}")
        if self.batch_faces is not None and int(self.batch_faces) < 1:
            raise TorchAKVFError(f"batch_faces must be positive, got {self.batch_faces}")
        if self.batch_bytes is not None and int(self.batch_bytes) < 1:
            raise TorchAKVFError(f"batch_bytes must be positive, got {self.batch_bytes}")
        if not isinstance(self.ray_workers, (int, np.integer)) or self.ray_workers < 0:
            raise TorchAKVFError(f"ray_workers must be an integer >= 0, got {self.ray_workers!r}")
        if not isinstance(self.default_k, (int, np.integer)) or self.default_k < 1:
            raise TorchAKVFError(f"default_k must be a positive integer, got {self.default_k!r}")
        n = self.n_fields
        if n is not None and (not isinstance(n, (int, np.integer)) or n < 1):
            raise TorchAKVFError(f"n_fields must be a positive integer, got {n!r}")
        if self.coarse_faces is not None and int(self.coarse_faces) < 0:
            raise TorchAKVFError(f"coarse_faces must be >= 0, got {self.coarse_faces}")
        k_range = self.k_range
        if self.auto:
            k_range = tuple(check_k_range(DEFAULT_K_RANGE if k_range is None else k_range))
            if self.k_rule not in RULES:
                raise TorchAKVFError(f"k_rule must be one of {RULES}, got {self.k_rule!r}")
        return dataclasses.replace(self, k_range=k_range, coarse_faces=int(self.coarse_faces or 0) or None)


def split_overrides(overrides: dict, settings_class) -> tuple[dict, dict]:
    """Keyword overrides split into (fields of ``settings_class``, :class:`SegmentOptions`
    fields); a name that is neither is a one-line error naming the valid ones."""
    mine = {f.name for f in dataclasses.fields(settings_class)}
    seg = set(SegmentOptions.names())
    unknown = sorted(set(overrides) - mine - seg)
    if unknown:
        raise TorchAKVFError(f"unknown option(s) {', '.join(unknown)}; choose from "
                             f"{', '.join(sorted(mine | seg))}")
    return ({k: v for k, v in overrides.items() if k in mine},
            {k: v for k, v in overrides.items() if k in seg})


def eval_segment_options(options: SegmentOptions | None, overrides: dict, auto: bool = False) -> SegmentOptions:
    """The segmentation options of an evaluation: ``options`` (None: the package's defaults
    with :data:`EVAL_SEGMENT_DEFAULTS`) with ``overrides`` applied. With k auto and no merge
    over-segmentation given, the scan's own (:func:`~torchakvf.evaluate.k_auto.scan_overseg`)."""
    given = dict(overrides)
    if options is None:
        given = {**EVAL_SEGMENT_DEFAULTS, **given}
        if auto:
            given["overseg"] = scan_overseg(given.get("overseg"))
        return segment_options(**given)
    return segment_options(options, **given)


def _jsonable(value):
    return json.loads(json.dumps(dataclasses.asdict(value) if dataclasses.is_dataclass(value) else value))


def changed_options(options: SegmentOptions) -> dict:
    """{name: value (JSON-able)} of the options that differ from the package's defaults, seed
    and remedy aside."""
    defaults = SegmentOptions().recorded()
    return {f: _jsonable(v) for f, v in options.recorded().items()
            if f not in ("seed", "remedy") and v != defaults[f]}


def prediction_record(options: SegmentOptions, settings: EvalSettings) -> dict:
    """What made the predictions, as settings.json records it: every segmentation option, also
    those left to their defaults, so that predictions made under other defaults are not
    resumed as these (``segment_kwargs``: the options that differ from the package's defaults,
    and the decimation)."""
    changed = changed_options(options)
    scan = SegmentOptions(overseg=scan_overseg(None)).merge_record()
    if settings.auto and changed.get("merge") == _jsonable(scan):
        del changed["merge"]           # the scan's own over-segmentation, not a choice of the caller
    if settings.coarse_faces:
        changed["coarse_faces"] = settings.coarse_faces
    auto = settings.auto
    return dict(seed=int(options.seed), remedy=options.remedy, n_fields=settings.n_fields,
                k_mode=settings.k_mode, k_range=list(settings.k_range) if auto else None,
                k_rule=settings.k_rule if auto else None, default_k=int(settings.default_k),
                segment_kwargs=dict(sorted(changed.items())),
                method=options.method,
                options={f: _jsonable(v) for f, v in options.recorded().items()})


def settings_guard(out: Path, prediction_settings: dict) -> None:
    """Refuse to mix predictions made with different settings in one folder (a corrupt
    settings.json is an error naming it, not silently replaced)."""
    path = out / "settings.json"
    if path.is_file():
        try:
            old = json.loads(path.read_text()).get("prediction")
        except (ValueError, AttributeError) as exc:
            raise TorchAKVFError(f"{path}: corrupt settings file ({exc}); delete it (with the "
                                 f"predictions it describes) or use another --out") from None
        diff = [] if old is None else sorted(k for k in set(old) | set(prediction_settings)
                                             if old.get(k) != prediction_settings.get(k))
        if diff:  # a setting absent from an older file reads as its default None
            raise TorchAKVFError(f"{out}: holds predictions made with other settings "
                                 f"({', '.join(diff)} differ); use another --out or delete it")
