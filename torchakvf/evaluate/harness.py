"""Benchmark evaluation on the Princeton Segmentation Benchmark: predict, score, summarise.

:func:`evaluate_psb` runs the method on (a selection of) the PSB meshes and writes::

    <out>/pred/<id>/<id>_k<k>.seg     one prediction per distinct k asked for (PSB format)
    <out>/pred/<id>/<id>_meta.json    per mesh: compute seconds, Killing eigenvalues, k-means costs
                                      (and, with k = "auto", the scan of k's and the k chosen)
    <out>/scores.csv                  per mesh: category, faces, k's, every metric, seconds, status
    <out>/summary.md                  per category and overall, with reference rows
    <out>/rand_index.png              per-category 1 - RI bars (the paper's Figure 11)
    <out>/settings.json               the settings that made the predictions

Protocols (:data:`PROTOCOLS`)
    ``"by-segmentation"`` (the benchmark's default): for each human segmentation j of a mesh,
    the prediction with k = its segment count k_j is compared with segmentation j only; the
    mesh's score is the mean over its human segmentations. ``"by-model"``: one prediction per
    mesh with k = the most common human segment count (ties: the smaller), compared with every
    human segmentation, mean. With ``k_mode="auto"`` each mesh gets one prediction with the k
    :mod:`torchakvf.evaluate.k_auto` chooses, compared with every human segmentation, mean.

Meshes without human segmentations (held-back categories) are predicted with
:data:`DEFAULT_K_NO_GT` parts (or the automatic k) and get status ``"no score"``.

Batching: meshes are sorted by (number of k's needed, face count) and grouped into batches of
at most ``batch_faces`` faces. Per batch the AKVFs are computed once (n = 36: segment's largest
default, 32, plus its 4 spare fields; or ``n_fields``) and shared by every k. Meshes need
different sets of k's, so the batch is segmented in *rounds*:
round r segments every mesh with its r-th k (ascending). A mesh with fewer k's than the round
count is padded with k = 1 (cheap: its clustering is trivial, but its boundary extraction
still runs - this wasted work is the price of ``segment`` wanting an :class:`AKVFResult` of
the whole batch). Rounds whose field counts agree (every k <= 8 untangles N = 16) share one
untangling. The default budget is the corpus runner's for the device
(:data:`torchakvf.pipeline.runner.DEFAULT_BATCH_FACES`: on CPU about one PSB mesh a batch,
which measured faster than larger batches).

Resume: a prediction file is written atomically as soon as its round is done; a re-run skips
every (mesh, k) whose file exists, so an interrupted run loses at most one round of one batch.
A mesh whose predictions all exist is only scored. ``settings.json`` guards against mixing
predictions made with different settings in one output folder.

The ``seconds`` of a mesh are its share (by face count) of the AKVF solve of its batch and of
each segmentation round it took part in (accumulated over runs, kept in ``_meta.json``), plus
the time spent scoring it in this run.
"""
from __future__ import annotations

import collections
import csv
import io
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import TorchAKVFError
from ..io.outputs import atomic_write_bytes, write_seg
from . import metrics as M
from . import psb as P

__all__ = ["evaluate_psb", "EvalSummary", "MeshScore", "PROTOCOLS", "METRIC_GROUPS", "METRICS",
           "DEFAULT_K_NO_GT", "parse_metrics", "score_segmentation", "human_mode"]

PROTOCOLS = ("by-segmentation", "by-model")
#: ``--metrics`` names and the scores.csv columns they fill.
METRIC_GROUPS = {
    "rand": ("rand_index_error",),
    "hamming": ("hamming_distance", "hamming_missing_rate", "hamming_false_alarm_rate"),
    "gce": ("gce",),
    "lce": ("lce",),
    "cd": ("cut_discrepancy",),
}
METRICS = tuple(c for cols in METRIC_GROUPS.values() for c in cols)
#: k for meshes without human segmentations (given-k protocols): the median over the 300
#: labelled PSB meshes of their most common human segment count.
DEFAULT_K_NO_GT = 6
#: k given to a mesh that sits out a segmentation round (its result is discarded).
_PAD_K = 1
_SHORT = {"rand_index_error": "1-RI", "hamming_distance": "HD", "hamming_missing_rate": "Rm",
          "hamming_false_alarm_rate": "Rf", "gce": "GCE", "lce": "LCE", "cut_discrepancy": "CD"}
REFERENCES = ("Human", "One segment", "Every face")


# ---------------------------------------------------------------------------------------------
# results
# ---------------------------------------------------------------------------------------------

@dataclass
class MeshScore:
    """One row of scores.csv.

    ks : the k's predicted for this mesh (by-segmentation: its distinct human counts)
    metrics : {metric: mean over the compared human segmentations} (empty without a score)
    references : {"Human" | "One segment" | "Every face": {metric: value}} ("Human": 1-RI only)
    status : "ok", "no score" (no human segmentations) or "failed: <reason>"
    k_auto : with k = "auto": details of the choice (chosen k, human mode, 1-RI per k tried)
    """

    mesh_id: int
    category: str
    faces: int
    ks: list
    metrics: dict = field(default_factory=dict)
    seconds: float = float("nan")
    status: str = "ok"
    human_mode: int | None = None
    references: dict = field(default_factory=dict)
    k_auto: dict | None = None

    @property
    def scored(self) -> bool:
        return self.status == "ok"


@dataclass
class EvalSummary:
    """What :func:`evaluate_psb` measured.

    rows : one :class:`MeshScore` per mesh, by mesh id
    per_category : {category: {metric: mean over its scored meshes}}
    overall_meshes : {metric: mean over every scored mesh}
    overall_categories : {metric: mean of the category means}
    references : {reference: {category | "overall_meshes" | "overall_categories": {metric: v}}}
    counts : {category: {"scored", "no score", "failed"}}
    """

    rows: list
    per_category: dict
    overall_meshes: dict
    overall_categories: dict
    references: dict
    counts: dict
    settings: dict
    wall_seconds: float
    predict_seconds: float
    score_seconds: float
    out_dir: Path
    k_auto: dict | None = None

    @property
    def rand_index_error(self) -> float:
        """Overall 1 - RI (mean over the scored meshes)."""
        return self.overall_meshes.get("rand_index_error", float("nan"))

    def row(self, mesh_id: int) -> MeshScore:
        for r in self.rows:
            if r.mesh_id == mesh_id:
                return r
        raise KeyError(mesh_id)


# ---------------------------------------------------------------------------------------------
# scoring
# ---------------------------------------------------------------------------------------------

def parse_metrics(spec) -> tuple[str, ...]:
    """``"rand,hamming,gce,lce,cd"`` (or a list, or None = all) -> the metric groups asked for."""
    if spec is None:
        return tuple(METRIC_GROUPS)
    names = [s.strip().lower() for s in (spec.split(",") if isinstance(spec, str) else spec)]
    names = [s for s in names if s]
    if names == ["all"]:
        return tuple(METRIC_GROUPS)
    bad = [s for s in names if s not in METRIC_GROUPS]
    if bad or not names:
        raise TorchAKVFError(f"unknown metric(s) {', '.join(map(repr, bad)) or '(none given)'}; "
                             f"choose from {','.join(METRIC_GROUPS)}")
    return tuple(g for g in METRIC_GROUPS if g in names)


class _MeshScorer:
    """Scores segmentations of one mesh against references, sharing the edge graph."""

    def __init__(self, vertices, faces, groups):
        self.groups = groups
        self.graph = M._EdgeGraph(vertices, faces) if "cd" in groups or "hamming" in groups else None
        self.areas = self.graph.face_areas if self.graph is not None else None

    def score(self, pred, gt) -> dict:
        out = {}
        g = self.groups
        if "rand" in g:
            out["rand_index_error"] = M.rand_index_error(pred, gt)
        if "hamming" in g:
            hd = M.hamming_distance(pred, gt, self.areas)
            out.update(hamming_distance=hd.distance, hamming_missing_rate=hd.missing_rate,
                       hamming_false_alarm_rate=hd.false_alarm_rate)
        if "gce" in g or "lce" in g:
            gce, lce = M.consistency_errors(pred, gt)
            if "gce" in g:
                out["gce"] = gce
            if "lce" in g:
                out["lce"] = lce
        if "cd" in g:
            out["cut_discrepancy"] = self.graph.cut_discrepancy(np.asarray(pred, dtype=np.int64),
                                                                np.asarray(gt, dtype=np.int64))
        return out


def _mean_dicts(dicts: list) -> dict:
    """Per-key mean, NaNs left out (a CD with no cut); NaN where every value is NaN."""
    keys = [k for k in METRICS if any(k in d for d in dicts)]
    out = {}
    for k in keys:
        vals = np.array([d.get(k, np.nan) for d in dicts], dtype=np.float64)
        vals = vals[np.isfinite(vals)]
        out[k] = float(vals.mean()) if vals.size else float("nan")
    return out


def score_segmentation(vertices, faces, preds: dict, gts: list, protocol: str, metrics=None,
                       k: int | None = None) -> dict:
    """Mean metrics of one mesh's predictions ``{k: labels}`` against its human ``gts``.

    ``"by-segmentation"``: human j is compared with ``preds[count_j]``; otherwise the single
    prediction ``preds[k]`` (default: the human mode) is compared with every human.
    """
    scorer = _MeshScorer(vertices, faces, parse_metrics(metrics))
    return _score_protocol(scorer, preds, gts, protocol, k)


def _score_protocol(scorer, preds, gts, protocol, k=None) -> dict:
    if protocol == "by-segmentation" and k is None:
        per = [scorer.score(preds[_count(g)], g) for g in gts]
    else:
        k = human_mode([_count(g) for g in gts]) if k is None else k
        per = [scorer.score(preds[k], g) for g in gts]
    return _mean_dicts(per)


def _count(labels) -> int:
    return int(np.unique(labels).size)


def human_mode(counts) -> int:
    """Most common segment count (ties: the smaller)."""
    c = collections.Counter(int(v) for v in counts)
    return min(c, key=lambda v: (-c[v], v))


# ---------------------------------------------------------------------------------------------
# selection and planning
# ---------------------------------------------------------------------------------------------

def _select(entries, categories, ids, per_category):
    if categories is not None:
        if isinstance(categories, str):
            categories = [c for c in categories.split(",") if c.strip()]
        lookup = {c.lower(): c for c in P.BENCHMARK_CATEGORIES}
        wanted = []
        for c in categories:
            c = c.strip()
            if c.lower() in {a.lower() for a in P.ABSENT_CATEGORIES}:
                raise TorchAKVFError(f"category {c!r} has no meshes in the benchmark")
            if c.lower() not in lookup:
                raise TorchAKVFError(f"unknown PSB category {c!r}; choose from "
                                     f"{', '.join(P.BENCHMARK_CATEGORIES)}")
            wanted.append(lookup[c.lower()])
        entries = [e for e in entries if e.category in set(wanted)]
    if ids is not None:
        if isinstance(ids, str):
            ids = _parse_ids(ids)
        ids = sorted({int(i) for i in ids})
        have = {e.mesh_id for e in entries}
        missing = [i for i in ids if i not in have]
        if missing:
            raise TorchAKVFError(f"PSB mesh id(s) {', '.join(map(str, missing[:10]))} not found "
                                 f"(among the selected categories)")
        entries = [e for e in entries if e.mesh_id in set(ids)]
    if per_category is not None:
        if int(per_category) < 1:
            raise TorchAKVFError(f"per_category must be >= 1, got {per_category}")
        seen = collections.Counter()
        kept = []
        for e in entries:  # sorted by id: the first N of each category
            if seen[e.category] < int(per_category):
                kept.append(e)
                seen[e.category] += 1
        entries = kept
    return entries


def _parse_ids(text: str) -> list[int]:
    """``"1,5,21-23"`` -> [1, 5, 21, 22, 23]."""
    out = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            if "-" in part:
                a, b = part.split("-", 1)
                out.extend(range(int(a), int(b) + 1))
            else:
                out.append(int(part))
        except ValueError:
            raise TorchAKVFError(f"bad mesh id {part!r} in --ids (use e.g. 1,5,21-23)") from None
    return out


@dataclass
class _Plan:
    entry: P.PSBEntry
    counts: list                # human segment counts (k order), [] without gt
    ks: list                    # k's this mesh's score needs (empty with k = auto)
    pred_dir: Path

    @property
    def mesh_id(self) -> int:
        return self.entry.mesh_id

    def pred_path(self, k: int) -> Path:
        return self.pred_dir / f"{self.mesh_id}_k{k}.seg"

    @property
    def meta_path(self) -> Path:
        return self.pred_dir / f"{self.mesh_id}_meta.json"

    def meta(self) -> dict:
        try:
            return json.loads(self.meta_path.read_text())
        except (OSError, ValueError):
            return {}

    def auto_k(self) -> int | None:
        k = self.meta().get("auto", {}).get("chosen")
        return int(k) if k is not None else None

    def missing(self, auto: bool) -> list:
        if auto:
            k = self.auto_k()
            return ["auto"] if k is None or not self.pred_path(k).is_file() else []
        return [k for k in self.ks if not self.pred_path(k).is_file()]


def _settings_guard(out: Path, prediction_settings: dict) -> None:
    """Refuse to mix predictions made with different settings in one folder."""
    path = out / "settings.json"
    if path.is_file():
        try:
            old = json.loads(path.read_text()).get("prediction")
        except ValueError:
            old = None
        diff = [] if old is None else sorted(k for k in set(old) | set(prediction_settings)
                                             if old.get(k) != prediction_settings.get(k))
        if diff:  # a setting added later, absent from an old file, reads as its default None
            raise TorchAKVFError(f"{out}: holds predictions made with other settings "
                                 f"({', '.join(diff)} differ); use another --out or delete it")


# ---------------------------------------------------------------------------------------------
# the run
# ---------------------------------------------------------------------------------------------

class _Progress:
    def __init__(self, enabled, total_faces: int):
        self.fn = enabled if callable(enabled) else (self._print if enabled else None)
        self.total = max(total_faces, 1)
        self.done = 0
        self.t0 = time.perf_counter()
        self.last = ""

    @staticmethod
    def _print(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    def __call__(self, msg: str) -> None:
        if self.fn is not None:
            self.fn(msg)

    def advance(self, faces: int, msg: str) -> None:
        self.last = msg
        self.done += faces
        el = time.perf_counter() - self.t0
        eta = el / self.done * (self.total - self.done) if self.done else float("nan")
        self(f"[{100 * self.done / self.total:5.1f}% of faces, {el / 60:.1f} min, "
             f"ETA {eta / 60:.1f} min] {msg}")


def evaluate_psb(psb_root, out_dir, categories=None, protocol: str = "by-segmentation", ids=None,
                 per_category: int | None = None, seed: int = 0, remedy: str | None = None,
                 n_fields: int | None = None, batch_faces: int | None = None, k_mode: str | None = None,
                 progress=True, metrics=None, k_range=None, k_rule: str = "elbow",
                 default_k: int = DEFAULT_K_NO_GT, plot: bool = True, workers: int | None = None,
                 **segment_kwargs) -> EvalSummary:
    """Run the method on PSB meshes, score it against the human segmentations, write reports.

    Parameters
    ----------
    psb_root : folder with ``meshes/N.off[.gz]`` and ``gt/N/N_k.seg[.gz]``
    out_dir : output folder (see the module notes for what is written; re-running resumes)
    categories : category names (list or comma string; default all 19)
    protocol : "by-segmentation" (default) or "by-model"
    ids : mesh ids (list, or a string like "1,5,21-23"); combined with ``categories``
    per_category : keep only the first N meshes (by id) of each category (quick runs)
    seed, remedy, n_fields : as in :func:`torchakvf.parts.segment` (remedy default
        :data:`torchakvf.parts.DEFAULT_REMEDY`; n_fields default 2k in [16, 32])
    batch_faces : face budget of one batch (meshes larger than it run alone; default the
        corpus runner's CPU budget)
    k_mode : None (k from the protocol) or "auto" (:mod:`torchakvf.evaluate.k_auto`)
    progress : True (lines on stderr), False, or a callable taking one line
    metrics : metric groups, e.g. "rand,hamming" (default all: rand,hamming,gce,lce,cd)
    k_range, k_rule : the k's tried and the rule with k_mode="auto" (default (2, 10), "elbow")
    default_k : parts for meshes without human segmentations (given-k protocols)
    plot : write rand_index.png
    workers : processes predicting batches side by side, each on one thread (default 1:
        this process; :func:`torchakvf.pipeline.parallel.default_workers` is one per core)
    segment_kwargs : passed on to :func:`torchakvf.parts.segment` (boundary,
        min_part_fraction, kmeans_restarts, ...); ``refine`` defaults to False here;
        ``coarse_faces=N`` solves on meshes decimated to about N faces (the batch is built
        with it, see :mod:`torchakvf.mesh.coarse`) and cuts the parts on the originals

    Returns
    -------
    EvalSummary
    """
    from ..parts import DEFAULT_REMEDY  # heavy imports only when a run starts

    t_start = time.perf_counter()
    if protocol not in PROTOCOLS:
        raise TorchAKVFError(f"unknown protocol {protocol!r}; choose from {', '.join(PROTOCOLS)}")
    if k_mode not in (None, "auto"):
        raise TorchAKVFError(f"k_mode must be None or 'auto', got {k_mode!r}")
    auto = k_mode == "auto"
    groups = parse_metrics(metrics)
    remedy = DEFAULT_REMEDY if remedy is None else remedy
    if batch_faces is None:
        batch_faces = default_eval_batch_faces("cpu", segment_kwargs.get("coarse_faces"))
    if int(batch_faces) < 1:
        raise TorchAKVFError(f"batch_faces must be positive, got {batch_faces}")
    if not isinstance(default_k, (int, np.integer)) or default_k < 1:
        raise TorchAKVFError(f"default_k must be a positive integer, got {default_k!r}")
    if n_fields is not None and (not isinstance(n_fields, (int, np.integer)) or n_fields < 1):
        raise TorchAKVFError(f"n_fields must be a positive integer, got {n_fields!r}")
    if auto:
        from .k_auto import DEFAULT_K_RANGE, RULES, _check_range
        k_range = tuple(_check_range(DEFAULT_K_RANGE if k_range is None else k_range))
        if k_rule not in RULES:
            raise TorchAKVFError(f"k_rule must be one of {RULES}, got {k_rule!r}")
    from ..operators import REMEDIES
    from ..parts.segment import BOUNDARIES

    if remedy not in REMEDIES:
        raise TorchAKVFError(f"unknown remedy {remedy!r}; choose from {', '.join(REMEDIES)}")
    if segment_kwargs.get("boundary", BOUNDARIES[0]) not in BOUNDARIES:
        raise TorchAKVFError(f"boundary must be one of {', '.join(BOUNDARIES)}, "
                             f"got {segment_kwargs['boundary']!r}")
    import inspect

    from ..parts import segment as _segment
    allowed = set(inspect.signature(_segment).parameters) - {"meshes", "k", "seed", "remedy", "n_fields"}
    unknown = sorted(set(segment_kwargs) - allowed)
    if unknown:
        raise TorchAKVFError(f"unknown segment option(s) {', '.join(unknown)}; "
                             f"choose from {', '.join(sorted(allowed))}")
    segment_kwargs.setdefault("refine", False)

    root = Path(psb_root)
    try:
        entries = P.find_psb_meshes(root)
    except FileNotFoundError as exc:
        raise TorchAKVFError(str(exc)) from None
    entries = _select(entries, categories, ids, per_category)
    if not entries:
        raise TorchAKVFError(f"no PSB meshes selected under {root}")

    out = Path(out_dir)
    pred_settings = dict(seed=int(seed), remedy=remedy, n_fields=n_fields, k_mode=k_mode,
                         k_range=list(k_range) if auto else None, k_rule=k_rule if auto else None,
                         default_k=int(default_k), segment_kwargs=dict(sorted(segment_kwargs.items())))
    _settings_guard(out, pred_settings)
    run_settings = dict(psb_root=str(root), protocol=protocol, categories=categories if categories is None
                        else sorted({e.category for e in entries}), ids=ids if ids is None else
                        sorted(e.mesh_id for e in entries), per_category=per_category,
                        batch_faces=int(batch_faces), metrics=list(groups))
    atomic_write_bytes(out / "settings.json", json.dumps(
        {"prediction": pred_settings, "run": run_settings}, indent=2).encode())

    # ---- plan: which k's each mesh needs ------------------------------------------------------
    plans = []
    for e in entries:
        counts = P.human_segment_counts(e) if e.has_gt else []
        if auto:
            ks = []
        elif not counts:
            ks = [int(default_k)]
        elif protocol == "by-segmentation":
            ks = sorted(set(counts))
        else:
            ks = [human_mode(counts)]
        plans.append(_Plan(e, counts, ks, out / "pred" / str(e.mesh_id)))

    todo = [p for p in plans if p.missing(auto)]
    faces_of = {}
    for p in todo:
        faces_of[p.mesh_id] = _face_count(p.entry.mesh_path)
    prog = _Progress(progress, sum(faces_of.values()))
    prog(f"torchakvf eval: {len(plans)} meshes ({len(plans) - len(todo)} already predicted), "
         f"protocol {protocol}{', k auto' if auto else ''}, remedy {remedy}, out {out}")

    rows: dict[int, MeshScore] = {}
    score_seconds = 0.0
    t_pred = time.perf_counter()
    failed: dict[int, str] = {}

    def score_and_store(plan, mesh):
        nonlocal score_seconds
        t0 = time.perf_counter()
        rows[plan.mesh_id] = _score_mesh(plan, mesh, protocol, groups, auto, failed.get(plan.mesh_id))
        dt = time.perf_counter() - t0
        score_seconds += dt
        rows[plan.mesh_id].seconds += dt

    # meshes already predicted: score only
    todo_ids = {p.mesh_id for p in todo}
    for p in plans:
        if p.mesh_id not in todo_ids:
            score_and_store(p, None)

    # ---- predict, batch by batch ---------------------------------------------------------------
    # Sorted by (number of k's still missing, faces): a batch's meshes then need about the same
    # number of segmentation rounds (little padding) and have similar sizes (little padding of
    # the [B, F_max] tensors).
    n_missing = {p.mesh_id: len(p.missing(auto)) for p in todo}
    solved = solved_face_counts(faces_of, segment_kwargs.get("coarse_faces"))
    batches = _make_batches(sorted(todo, key=lambda p: (n_missing[p.mesh_id], faces_of[p.mesh_id],
                                                        p.mesh_id)), solved, int(batch_faces))
    from ..pipeline.parallel import map_batches

    n_batch = 0
    n_workers = 1 if workers is None else int(workers)
    args = (auto, seed, remedy, n_fields, k_range, k_rule, segment_kwargs, faces_of)
    for res in map_batches(batches, _predict_in_worker, args, workers=n_workers):
        batch = res.batch
        if res.split:
            prog(f"a batch failed ({res.error}); retrying its {len(batch)} meshes one by one")
            continue
        n_batch += 1
        if res.error is not None:
            p = batch[0]
            failed[p.mesh_id] = res.error
            prog(f"mesh {p.mesh_id} failed: {failed[p.mesh_id]}")
            meshes = {p.mesh_id: None}
            prog.advance(faces_of[p.mesh_id], f"mesh {p.mesh_id}: failed")
        else:
            meshes, msg, _ = res.result
            prog.advance(int(sum(faces_of[p.mesh_id] for p in batch)), f"batch {n_batch}: {msg}")
        for p in batch:
            score_and_store(p, meshes.get(p.mesh_id))
        _write_reports(out, rows, plans, protocol, groups, auto, time.perf_counter() - t_start,
                       pred_settings, run_settings, plot=False)
    predict_seconds = time.perf_counter() - t_pred - score_seconds

    wall = time.perf_counter() - t_start
    summary = _write_reports(out, rows, plans, protocol, groups, auto, wall, pred_settings,
                             run_settings, plot=plot)
    summary.predict_seconds = predict_seconds
    summary.score_seconds = score_seconds
    prog(f"done in {wall / 60:.1f} min: overall 1-RI {summary.rand_index_error:.4f} "
         f"({sum(r.scored for r in summary.rows)} meshes scored) -> {out / 'summary.md'}")
    return summary


def _face_count(path: Path) -> int:
    """Face count from an OFF header (cheap; used only to plan batches)."""
    import gzip

    with open(path, "rb") as fh:
        magic = fh.read(2)
    opener = gzip.open if magic == b"\x1f\x8b" else open
    with opener(path, "rt") as fh:
        tokens = []
        for line in fh:
            tokens += line.split("#", 1)[0].split()
            if len(tokens) >= 3:
                break
    try:
        return int(tokens[2])
    except (IndexError, ValueError):
        return 1


def default_eval_batch_faces(device, coarse_faces=None) -> int:
    """The face budget of a batch by default: the corpus runner's for the device; on CPU with
    decimation, one decimated mesh per batch (the cores are used by worker processes instead,
    and a batch re-solves every mesh when one of them needs more eigenpairs)."""
    from ..mesh.coarse import DECIMATE_ABOVE
    from ..pipeline.runner import default_batch_faces

    if coarse_faces and str(device).startswith("cpu"):
        return int(DECIMATE_ABOVE * coarse_faces)
    return default_batch_faces(device)


def solved_face_counts(faces_of: dict, coarse_faces) -> dict:
    """{mesh id: faces of the mesh the solver sees}: the input's, or about ``coarse_faces`` for
    a mesh that will be decimated (the face budget of a batch counts what is solved)."""
    if not coarse_faces:
        return dict(faces_of)
    from ..mesh.coarse import DECIMATE_ABOVE
    return {i: (f if f <= DECIMATE_ABOVE * coarse_faces else int(coarse_faces)) for i, f in faces_of.items()}


def _make_batches(plans, faces_of, budget):
    batches, cur, cur_faces = [], [], 0
    for p in plans:
        f = faces_of[p.mesh_id]
        if cur and cur_faces + f > budget:
            batches.append(cur)
            cur, cur_faces = [], 0
        cur.append(p)
        cur_faces += f
    if cur:
        batches.append(cur)
    return batches


def _predict_in_worker(batch, auto, seed, remedy, n_fields, k_range, k_rule, segment_kwargs,
                       faces_of, device="cpu"):
    """:func:`_predict_batch` without progress lines (it may run in a worker process);
    returns (its loaded meshes, its one-line summary, its stage timings)."""
    prog = _Progress(False, 1)
    timings: dict = {}
    meshes = _predict_batch(batch, auto, seed, remedy, n_fields, k_range, k_rule, segment_kwargs,
                            faces_of, prog, 0, 0, device=device, timings=timings)
    try:  # the process's peak so far (MiB): where it jumps, this batch set a new peak
        import resource
        timings["process_maxrss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    except ImportError:  # pragma: no cover - not on Windows
        pass
    return meshes, prog.last, timings


def _predict_batch(batch, auto, seed, remedy, n_fields, k_range, k_rule, segment_kwargs,
                   faces_of, prog, n_batch, n_left, *, device="cpu", timings=None):
    """AKVFs once for the batch, then every missing k; writes predictions and meta files.

    device : torch device of the batch's computation (evaluate_psb: cpu).
    timings : optional dict the stage seconds of this batch are added to (``torchakvf bench``):
        "load", "pack" (clean + pack), "akvf", "segment" (with k auto: the scan) and, given k,
        "segment_by_k" ({k: seconds}, each round charged to its meshes' k's by face share),
        "write" (predictions + meta files). CUDA is synchronized before each reading when given.

    Returns {mesh_id: Mesh} (the loaded input meshes, for scoring)."""
    from ..fields.akvf import akvf_falling_back
    from ..fields.untangle import untangle
    from ..io import load_mesh
    from ..mesh import MeshBatch
    from ..parts import segment
    from ..parts.segment import SPARE_FIELDS, UNTANGLE_RESTARTS, default_n_fields, field_counts

    tick = _stage_clock(timings, device)
    t0 = time.perf_counter()
    # The batch carries its decimation (coarse_faces), so segment() takes the rest as usual.
    segment_kwargs = dict(segment_kwargs)
    coarse_faces = segment_kwargs.pop("coarse_faces", None)
    meshes = {p.mesh_id: load_mesh(p.entry.mesh_path) for p in batch}
    tick("load")
    mb = MeshBatch.from_meshes([meshes[p.mesh_id] for p in batch], device=device,
                               coarse_faces=coarse_faces)
    tick("pack")
    faces = np.array([len(m.faces) for m in mb.meshes], dtype=np.float64)
    share = faces / faces.sum()
    seconds = np.zeros(len(batch))
    # A fixed n per run (not the batch's largest need), so a mesh's fields do not depend on
    # which meshes share its batch: the largest default n (32; the scan's n for auto) plus the
    # spare fields segment() itself computes to see degenerate clusters.
    if n_fields is not None:
        n_akvf = int(n_fields)
    elif auto:
        n_akvf = default_n_fields(k_range[1]) + SPARE_FIELDS
    else:
        n_akvf = default_n_fields(10 ** 6) + SPARE_FIELDS
    fields, fell_back = akvf_falling_back(mb, n=n_akvf, seed=seed, remedy=remedy)
    mb = fields.batch
    tick("akvf")
    t_akvf = time.perf_counter() - t0
    seconds += t_akvf * share
    eig = fields.eigenvalues.detach().cpu().numpy().astype(float)
    costs = [dict() for _ in batch]
    extra = [dict() for _ in batch]
    n_rounds = 0
    if auto:
        from .k_auto import RULES, pick_k, scan_k

        t1 = time.perf_counter()
        scan = scan_k(fields, k_range, rule=k_rule, seed=seed, remedy=remedy, n_fields=n_fields,
                      keep=True, **segment_kwargs)
        seconds += (time.perf_counter() - t1) * share
        tick("segment")
        for b, p in enumerate(batch):
            k = scan.chosen[b]
            write_seg(p.pred_path(k), scan.segmentations[k].meshes[b].labels)
            costs[b] = {str(kk): float(c) for kk, c in zip(scan.ks, scan.costs[b])}
            by_rule = {r: pick_k(scan.ks, scan.costs[b], r, scan.eigenvalues[b]) for r in RULES}
            ri_by_k = {}
            if p.entry.has_gt:  # 1-RI of every k tried (cheap), to compare the choice with an oracle
                gts = [P.read_seg(s) for s in p.entry.seg_paths]
                for kk in scan.ks:
                    lab = scan.segmentations[kk].meshes[b].labels
                    ri_by_k[str(kk)] = float(np.mean([M.rand_index_error(lab, g) for g in gts]))
            extra[b]["auto"] = dict(chosen=k, rule=k_rule, ks=scan.ks, n_fields=scan.n_fields,
                                    by_rule=by_rule, rand_index_error_by_k=ri_by_k)
        n_rounds = len(scan.ks)
    else:
        missing = [sorted(p.missing(False)) for p in batch]
        untangled = {}
        n_rounds = max(len(m) for m in missing)
        for r in range(n_rounds):
            active = [b for b in range(len(batch)) if r < len(missing[b])]
            ks = [missing[b][r] if r < len(missing[b]) else _PAD_K for b in range(len(batch))]
            t1 = time.perf_counter()
            ns = tuple(field_counts(fields, ks, n_fields))
            if ns not in untangled:  # k's with the same field counts (2k <= 16) share one
                untangled[ns] = untangle(fields, n=list(ns), seed=seed,
                                         restarts=segment_kwargs.get("untangle_restarts", UNTANGLE_RESTARTS))
            seg = segment(fields, k=ks, seed=seed, remedy=remedy, n_fields=n_fields,
                          untangled=untangled[ns], **segment_kwargs)
            tick("segment", [(ks[b], faces[b]) for b in active])
            for b in active:
                write_seg(batch[b].pred_path(ks[b]), seg.meshes[b].labels)
                costs[b][str(ks[b])] = float(seg.meshes[b].cost)
            tick("write")
            dt = time.perf_counter() - t1
            act_faces = faces[active]
            seconds[active] += dt * act_faces / act_faces.sum()
    for b, p in enumerate(batch):
        meta = p.meta()
        meta["faces"] = int(meshes[p.mesh_id].n_faces)
        meta["seconds"] = float(meta.get("seconds", 0.0)) + float(seconds[b])
        meta["eigenvalues"] = eig[b].tolist()
        meta.setdefault("costs", {}).update(costs[b])
        meta.update(extra[b])
        meta["coarse_faces"] = None if mb.coarse_of(b) is None else len(mb.coarse_of(b).coarse.faces)
        fb = [why for i, why in fell_back if i == b]
        if fb:
            meta["full_resolution_because"] = fb[0]
        atomic_write_bytes(p.meta_path, json.dumps(meta, indent=1).encode())
    tick("write")
    prog.advance(int(sum(faces_of[p.mesh_id] for p in batch)),
                 f"{len(batch)} meshes, {int(faces.sum())} faces, "
                 f"akvf {t_akvf:.1f}s, {n_rounds} k-rounds {time.perf_counter() - t0 - t_akvf:.1f}s")
    return meshes


def _stage_clock(timings, device):
    """``tick(stage, by_k=None)``: adds the seconds since the previous tick to ``timings[stage]``
    (and, with ``by_k`` = [(k, faces), ...], splits them over ``timings["segment_by_k"]`` by
    face share); a no-op when ``timings`` is None."""
    if timings is None:
        return lambda stage, by_k=None: None
    import torch

    sync = torch.cuda.synchronize if str(device).startswith("cuda") else (lambda: None)
    last = [time.perf_counter()]

    def tick(stage, by_k=None):
        sync()
        now = time.perf_counter()
        dt, last[0] = now - last[0], now
        timings[stage] = timings.get(stage, 0.0) + dt
        if by_k:
            per = timings.setdefault("segment_by_k", {})
            total = float(sum(f for _, f in by_k)) or 1.0
            for k, f in by_k:
                per[int(k)] = per.get(int(k), 0.0) + dt * float(f) / total
    return tick


def _score_mesh(plan: _Plan, mesh, protocol, groups, auto, failure) -> MeshScore:
    e = plan.entry
    meta = plan.meta()
    faces = int(meta.get("faces", 0)) or (mesh.n_faces if mesh is not None else 0)
    mode = human_mode(plan.counts) if plan.counts else None
    row = MeshScore(mesh_id=e.mesh_id, category=e.category, faces=faces, ks=list(plan.ks),
                    seconds=float(meta.get("seconds", 0.0)), human_mode=mode)
    if failure is not None:
        row.status = f"failed: {failure}"
        return row
    k_chosen = plan.auto_k() if auto else None
    if auto:
        row.ks = [k_chosen]
        a = meta.get("auto", {})
        row.k_auto = dict(chosen=k_chosen, human_mode=mode, by_rule=a.get("by_rule", {}),
                          rand_index_error_by_k={int(k): v for k, v in
                                                 a.get("rand_index_error_by_k", {}).items()})
    if not e.has_gt:
        row.status = "no score"
        return row
    if mesh is None:
        from ..io import load_mesh
        mesh = load_mesh(e.mesh_path)
    row.faces = mesh.n_faces
    gts = [P.read_seg(s) for s in e.seg_paths]
    ks_needed = [k_chosen] if auto else plan.ks
    preds = {}
    for k in ks_needed:
        lab = P.read_seg(plan.pred_path(k))
        if lab.size != mesh.n_faces:
            raise TorchAKVFError(f"{plan.pred_path(k)}: {lab.size} labels for {mesh.n_faces} faces "
                                 f"(a stale prediction? delete it and re-run)")
        preds[k] = lab
    scorer = _MeshScorer(mesh.vertices, mesh.faces, groups)
    if auto:
        row.metrics = _score_protocol(scorer, preds, gts, "by-model", k=k_chosen)
    elif protocol == "by-segmentation":
        row.metrics = _score_protocol(scorer, preds, gts, protocol)
    else:
        row.metrics = _score_protocol(scorer, preds, gts, protocol, k=plan.ks[0])
    n = mesh.n_faces
    row.references = {
        "Human": {"rand_index_error": P.human_pairwise_rand_index_error(e, gts)},
        "One segment": _score_protocol(scorer, {1: np.zeros(n, np.int64)}, gts, "by-model", k=1),
        "Every face": _score_protocol(scorer, {n: np.arange(n, dtype=np.int64)}, gts, "by-model", k=n),
    }
    return row


# ---------------------------------------------------------------------------------------------
# reports
# ---------------------------------------------------------------------------------------------

def _aggregate(rows, groups):
    cols = [c for g in groups for c in METRIC_GROUPS[g]]
    cats = [c for c in P.BENCHMARK_CATEGORIES if any(r.category == c for r in rows)]
    per_cat, counts = {}, {}
    refs = {name: {} for name in REFERENCES}
    for c in cats:
        rs = [r for r in rows if r.category == c]
        ok = [r for r in rs if r.scored]
        counts[c] = {"scored": len(ok), "no score": sum(r.status == "no score" for r in rs),
                     "failed": sum(r.status.startswith("failed") for r in rs)}
        if ok:
            per_cat[c] = {k: v for k, v in _mean_dicts([r.metrics for r in ok]).items() if k in cols}
            per_cat[c]["seconds"] = float(np.mean([r.seconds for r in ok]))
            for name in REFERENCES:
                refs[name][c] = _mean_dicts([r.references.get(name, {}) for r in ok])
    ok_all = [r for r in rows if r.scored]
    overall_m = _mean_dicts([r.metrics for r in ok_all]) if ok_all else {}
    overall_c = _mean_dicts(list(per_cat.values())) if per_cat else {}
    if ok_all:
        overall_m["seconds"] = float(np.mean([r.seconds for r in ok_all]))
        overall_c["seconds"] = float(np.mean([v["seconds"] for v in per_cat.values()]))
    for name in REFERENCES:
        if ok_all:
            refs[name]["overall_meshes"] = _mean_dicts([r.references.get(name, {}) for r in ok_all])
            refs[name]["overall_categories"] = _mean_dicts([refs[name][c] for c in per_cat])
    return cats, per_cat, counts, overall_m, overall_c, refs


def _k_auto_stats(rows):
    ok = [r for r in rows if r.scored and r.k_auto and r.human_mode is not None]
    if not ok:
        return None
    out = {"per_category": {}, "overall": {}}

    def stats(rs):
        chosen = np.array([r.k_auto["chosen"] for r in rs])
        mode = np.array([r.human_mode for r in rs])
        at_mode = [r.k_auto["rand_index_error_by_k"].get(r.human_mode) for r in rs]
        at_mode = [v for v in at_mode if v is not None]
        best = [min(r.k_auto["rand_index_error_by_k"].values()) for r in rs
                if r.k_auto["rand_index_error_by_k"]]
        rules = {}
        for rule in (rs[0].k_auto.get("by_rule") or {}):
            rules[rule] = float(np.mean([r.k_auto["by_rule"].get(rule) == r.human_mode for r in rs]))
        return dict(n=len(rs), hit_rate=float(np.mean(chosen == mode)),
                    within_1=float(np.mean(np.abs(chosen - mode) <= 1)),
                    mean_chosen=float(chosen.mean()), mean_mode=float(mode.mean()),
                    rand_index_error=float(np.mean([r.metrics.get("rand_index_error", np.nan)
                                                    for r in rs])),
                    rand_index_error_at_mode=float(np.mean(at_mode)) if at_mode else float("nan"),
                    n_mode_in_range=len(at_mode),
                    rand_index_error_best_k=float(np.mean(best)) if best else float("nan"),
                    hit_rate_by_rule=rules)
    for c in P.BENCHMARK_CATEGORIES:
        rs = [r for r in ok if r.category == c]
        if rs:
            out["per_category"][c] = stats(rs)
    out["overall"] = stats(ok)
    return out


def _fmt(v, digits=4) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v:.{digits}f}"


def _write_reports(out, rows_by_id, plans, protocol, groups, auto, wall, pred_settings,
                   run_settings, plot) -> EvalSummary:
    rows = [rows_by_id[p.mesh_id] for p in plans if p.mesh_id in rows_by_id]
    cols = [c for g in groups for c in METRIC_GROUPS[g]]
    # scores.csv
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    ref_cols = ["human_rand_index_error", "one_segment_rand_index_error",
                "every_face_rand_index_error"]
    w.writerow(["id", "category", "faces", "ks", *METRICS, "seconds", "status", "human_mode",
                *ref_cols])
    for r in rows:
        ks = ";".join(map(str, r.ks))
        if r.k_auto:
            ks = f"auto:{ks}"
        refs = [r.references.get(n, {}).get("rand_index_error") for n in REFERENCES]
        w.writerow([r.mesh_id, r.category, r.faces, ks,
                    *[_fmt(r.metrics.get(m), 6) if m in r.metrics else "" for m in METRICS],
                    _fmt(r.seconds, 2), r.status, "" if r.human_mode is None else r.human_mode,
                    *[_fmt(v, 6) if v is not None else "" for v in refs]])
    atomic_write_bytes(out / "scores.csv", buf.getvalue().encode())

    cats, per_cat, counts, overall_m, overall_c, refs = _aggregate(rows, groups)
    kstats = _k_auto_stats(rows) if auto else None
    summary = EvalSummary(rows=rows, per_category=per_cat, overall_meshes=overall_m,
                          overall_categories=overall_c, references=refs, counts=counts,
                          settings={"prediction": pred_settings, "run": run_settings},
                          wall_seconds=wall, predict_seconds=float("nan"),
                          score_seconds=float("nan"), out_dir=out, k_auto=kstats)
    atomic_write_bytes(out / "summary.md", _summary_md(summary, cats, cols, protocol, auto).encode())
    if plot:
        _plot(out / "rand_index.png", summary, cats, protocol, auto)
    return summary


def _summary_md(s: EvalSummary, cats, cols, protocol, auto) -> str:
    L = []
    pred, run = s.settings["prediction"], s.settings["run"]
    n_ok = sum(r.scored for r in s.rows)
    n_no = sum(r.status == "no score" for r in s.rows)
    n_fail = sum(r.status.startswith("failed") for r in s.rows)
    L.append("# torchakvf on the Princeton Segmentation Benchmark\n")
    L.append(f"- protocol: **{'k auto (' + str(pred['k_rule']) + ', k in ' + str(pred['k_range']) + ')' if auto else protocol}**")
    L.append(f"- meshes: {len(s.rows)} ({n_ok} scored, {n_no} without human segmentations: no score, "
             f"{n_fail} failed)")
    L.append(f"- settings: seed {pred['seed']}, remedy {pred['remedy']}, n_fields "
             f"{pred['n_fields'] or 'default (2k in [16, 32])'}, segment {pred['segment_kwargs']}, "
             f"k without ground truth {pred['default_k']}, batch_faces {run['batch_faces']}, "
             f"metrics {','.join(run['metrics'])}")
    L.append(f"- wall time of this run: {s.wall_seconds:.1f} s "
             f"({s.wall_seconds / 60:.1f} min); mean compute per scored mesh "
             f"{_fmt(s.overall_meshes.get('seconds'), 1)} s")
    L.append("- all values are dissimilarities (lower is better); 1-RI faces counted, "
             "Hamming area weighted, GCE/LCE faces counted, CD / average radius\n")

    L.append("## 1 - Rand Index per category\n")
    L.append("| category | meshes | torchakvf | Human | One segment | Every face |")
    L.append("|---|---:|---:|---:|---:|---:|")
    for c in cats:
        cnt = s.counts[c]
        label = f"{cnt['scored']}" + (f" (+{cnt['no score']} no score)" if cnt["no score"] else "") \
            + (f" ({cnt['failed']} failed)" if cnt["failed"] else "")
        if c in s.per_category:
            L.append(f"| {c} | {label} | {_fmt(s.per_category[c].get('rand_index_error'))} | "
                     + " | ".join(_fmt(s.references[n].get(c, {}).get("rand_index_error"))
                                  for n in REFERENCES) + " |")
        else:
            L.append(f"| {c} | {label} | no score | - | - | - |")
    for key, name in (("overall_meshes", "**overall (mean over meshes)**"),
                      ("overall_categories", "**overall (mean over categories)**")):
        ours = s.overall_meshes if key == "overall_meshes" else s.overall_categories
        L.append(f"| {name} | {n_ok} | **{_fmt(ours.get('rand_index_error'))}** | "
                 + " | ".join(_fmt(s.references[n].get(key, {}).get("rand_index_error"))
                              for n in REFERENCES) + " |")

    L.append("\n## All metrics per category (torchakvf)\n")
    L.append("| category | " + " | ".join(_SHORT[c] for c in cols) + " | seconds |")
    L.append("|---|" + "---:|" * (len(cols) + 1))
    for c in cats:
        if c in s.per_category:
            v = s.per_category[c]
            L.append(f"| {c} | " + " | ".join(_fmt(v.get(m)) for m in cols)
                     + f" | {_fmt(v.get('seconds'), 1)} |")
    for name, v in (("overall (meshes)", s.overall_meshes), ("overall (categories)", s.overall_categories)):
        if v:
            L.append(f"| **{name}** | " + " | ".join(_fmt(v.get(m)) for m in cols)
                     + f" | {_fmt(v.get('seconds'), 1)} |")

    L.append("\n## Reference rows (overall, mean over meshes)\n")
    L.append("| reference | " + " | ".join(_SHORT[c] for c in cols) + " |")
    L.append("|---|" + "---:|" * len(cols))
    L.append("| torchakvf | " + " | ".join(_fmt(s.overall_meshes.get(m)) for m in cols) + " |")
    for n in REFERENCES:
        v = s.references[n].get("overall_meshes", {})
        L.append(f"| {n} | " + " | ".join(_fmt(v.get(m)) for m in cols) + " |")
    L.append("\n\"Human\": mean 1-RI over all pairs of a mesh's human segmentations (other metrics "
             "not computed). \"One segment\" / \"Every face\": every face in one segment / each face "
             "its own segment, scored like a prediction (their cut discrepancy is undefined / "
             "trivial).")

    if s.k_auto:
        L.append("\n## Automatic k\n")
        L.append("| category | meshes | chosen = human mode | within 1 | mean k chosen | mean human "
                 "mode | 1-RI (auto k) | 1-RI (k = human mode, same scan) | 1-RI (best k of scan) |")
        L.append("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
        items = list(s.k_auto["per_category"].items()) + [("**overall**", s.k_auto["overall"])]
        for c, v in items:
            L.append(f"| {c} | {v['n']} | {_fmt(v['hit_rate'], 2)} | {_fmt(v['within_1'], 2)} | "
                     f"{_fmt(v['mean_chosen'], 1)} | {_fmt(v['mean_mode'], 1)} | "
                     f"{_fmt(v['rand_index_error'])} | {_fmt(v['rand_index_error_at_mode'])}"
                     f" ({v['n_mode_in_range']}) | {_fmt(v['rand_index_error_best_k'])} |")
        rules = s.k_auto["overall"].get("hit_rate_by_rule", {})
        if rules:
            L.append("\nHit rate (chosen = human mode) of each rule on the same scans: "
                     + ", ".join(f"{r} {_fmt(v, 2)}" for r, v in rules.items()))
    fails = [r for r in s.rows if r.status.startswith("failed")]
    if fails:
        L.append("\n## Failed meshes\n")
        for r in fails:
            L.append(f"- {r.mesh_id} ({r.category}): {r.status[len('failed: '):]}")
    return "\n".join(L) + "\n"


def _plot(path: Path, s: EvalSummary, cats, protocol, auto) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [c for c in cats if c in s.per_category] + (["Overall"] if s.per_category else [])
    if not names:
        return
    series = [("torchakvf", lambda c: (s.overall_meshes if c == "Overall" else s.per_category[c]))]
    for n in REFERENCES:
        series.append((n, lambda c, n=n: s.references[n].get("overall_meshes" if c == "Overall" else c, {})))
    colors = ["#1f77b4", "#2ca02c", "#bbbbbb", "#777777"]
    x = np.arange(len(names))
    width = 0.8 / len(series)
    fig, ax = plt.subplots(figsize=(max(6, 0.75 * len(names) + 2), 4.2))
    for i, ((label, get), color) in enumerate(zip(series, colors)):
        vals = [get(c).get("rand_index_error", np.nan) for c in names]
        ax.bar(x + (i - (len(series) - 1) / 2) * width, vals, width, label=label, color=color)
    ax.set_xticks(x)
    ax.set_xticklabels(names, rotation=45, ha="right")
    ax.set_ylabel("1 - Rand Index (lower is better)")
    ax.set_ylim(0, 1)
    ax.set_title(f"PSB, {'k auto' if auto else protocol}: overall 1-RI "
                 f"{_fmt(s.overall_meshes.get('rand_index_error'), 3)}")
    ax.legend(ncol=4, fontsize=8, loc="upper left")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
