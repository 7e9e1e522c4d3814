"""Scoring one mesh's predictions against its human segmentations (the benchmark's protocols)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import TorchAKVFError
from ..io import load_mesh
from . import metrics as M
from . import psb as P
from .plan import PredictionPlan, human_mode

#: ``--metrics`` names and the scores.csv columns they fill.
METRIC_GROUPS = {
    "rand": ("rand_index_error",),
    "hamming": ("hamming_distance", "hamming_missing_rate", "hamming_false_alarm_rate"),
    "gce": ("gce",),
    "lce": ("lce",),
    "cd": ("cut_discrepancy",),
}
METRICS = tuple(c for cols in METRIC_GROUPS.values() for c in cols)

__all__ = ["METRIC_GROUPS", "METRICS", "MeshScore", "MeshScorer", "parse_metrics",
           "score_segmentation", "score_protocol", "score_mesh", "mean_dicts"]


@dataclass
class MeshScore:
    """One row of scores.csv.

    ks : the k's predicted for this mesh (by-segmentation: its distinct human counts)
    metrics : {metric: mean over the compared human segmentations} (empty without a score)
    references : {"Human" | "One segment" | "Every face": {metric: value}} ("Human": 1-RI only)
    status : "ok", "no score" (no human segmentations) or "failed: <reason>"
    k_auto : with k = "auto": details of the choice (chosen k, human mode, 1-RI per k tried)
    converged : whether the mesh's eigensolve converged (None: not recorded)
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
    converged: bool | None = None

    @property
    def scored(self) -> bool:
        return self.status == "ok"


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


class MeshScorer:
    """Scores segmentations of one mesh against references, sharing the edge graph."""

    def __init__(self, vertices, faces, groups):
        self.groups = groups
        self.graph = M.EdgeGraph(vertices, faces) if "cd" in groups or "hamming" in groups else None
        self.areas = self.graph.face_areas if self.graph is not None else None

    def score(self, pred, gt) -> dict:
        g = self.groups
        # one contingency table for the rand, hamming and consistency metrics of the pair
        out = M.compare_segmentations(pred, gt, self.areas, rand="rand" in g, hamming="hamming" in g,
                                      consistency="gce" in g or "lce" in g)
        for name in {"gce", "lce"} - set(g):
            out.pop(name, None)
        if "cd" in g:
            out["cut_discrepancy"] = self.graph.cut_discrepancy(np.asarray(pred, dtype=np.int64),
                                                                np.asarray(gt, dtype=np.int64))
        return out


def mean_dicts(dicts: list) -> dict:
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
    scorer = MeshScorer(vertices, faces, parse_metrics(metrics))
    return score_protocol(scorer, preds, gts, protocol, k)


def score_protocol(scorer, preds, gts, protocol, k=None) -> dict:
    if protocol == "by-segmentation" and k is None:
        per = [scorer.score(preds[_count(g)], g) for g in gts]
    else:
        k = human_mode([_count(g) for g in gts]) if k is None else k
        per = [scorer.score(preds[k], g) for g in gts]
    return mean_dicts(per)


def _count(labels) -> int:
    return P.segment_count(labels)


def score_mesh(plan: PredictionPlan, mesh, protocol, groups, auto, failure) -> MeshScore:
    """The scores.csv row of one mesh (``mesh``: its loaded input, or None to load it;
    ``failure``: why its prediction failed, or None)."""
    e = plan.entry
    failure = failure or plan.failure
    meta = {} if plan.failure else plan.meta()
    faces = int(meta.get("faces", 0)) or plan.faces or (mesh.n_faces if mesh is not None else 0)
    mode = human_mode(plan.counts) if plan.counts else None
    row = MeshScore(mesh_id=e.mesh_id, category=e.category, faces=faces, ks=list(plan.ks),
                    seconds=float(meta.get("seconds", 0.0)), human_mode=mode,
                    converged=meta.get("converged"))
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
        mesh = load_mesh(e.mesh_path)
    row.faces = mesh.n_faces
    gts = [P.read_seg(s) for s in e.seg_paths]
    preds = {}
    for k in ([k_chosen] if auto else plan.ks):
        lab = P.read_seg(plan.pred_path(k))
        if lab.size != mesh.n_faces:
            row.status = (f"failed: {plan.pred_path(k)}: {lab.size} labels for {mesh.n_faces} faces "
                          f"(a stale prediction? delete it and re-run)")
            return row
        preds[k] = lab
    scorer = MeshScorer(mesh.vertices, mesh.faces, groups)
    if auto:
        row.metrics = score_protocol(scorer, preds, gts, "by-model", k=k_chosen)
    elif protocol == "by-segmentation":
        row.metrics = score_protocol(scorer, preds, gts, protocol)
    else:
        row.metrics = score_protocol(scorer, preds, gts, protocol, k=plan.ks[0])
    n = mesh.n_faces
    row.references = {
        "Human": {"rand_index_error": P.human_pairwise_rand_index_error(e, gts)},
        "One segment": score_protocol(scorer, {1: np.zeros(n, np.int64)}, gts, "by-model", k=1),
        "Every face": score_protocol(scorer, {n: np.arange(n, dtype=np.int64)}, gts, "by-model", k=n),
    }
    return row
