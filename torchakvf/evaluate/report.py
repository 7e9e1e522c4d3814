"""The reports of an evaluation: scores.csv, summary.md, rand_index.png, gallery/<Category>.png
and the :class:`EvalSummary` returned."""
from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..io.outputs import atomic_write_bytes
from . import psb as P
from .gallery import write_galleries
from .score import METRIC_GROUPS, METRICS, mean_dicts

__all__ = ["EvalSummary", "REFERENCES", "write_reports"]

_SHORT = {"rand_index_error": "1-RI", "hamming_distance": "HD", "hamming_missing_rate": "Rm",
          "hamming_false_alarm_rate": "Rf", "gce": "GCE", "lce": "LCE", "cut_discrepancy": "CD"}
REFERENCES = ("Human", "One segment", "Every face")


@dataclass
class EvalSummary:
    """What :func:`evaluate_psb` measured.

    rows : one :class:`MeshScore` per mesh, by mesh id
    per_category : {category: {metric: mean over its scored meshes}}
    overall_meshes : {metric: mean over every scored mesh}
    overall_categories : {metric: mean of the category means}
    references : {reference: {category | "overall_meshes" | "overall_categories": {metric: v}}}
    counts : {category: {"scored", "no score", "failed"}}
    problems : one line per bad input (a human .seg left out, a file outside the benchmark's
        numbering, a corrupt meta file), each naming the file
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
    problems: list = field(default_factory=list)
    galleries: dict = field(default_factory=dict)

    @property
    def failed(self) -> bool:
        """Whether anything went wrong: a mesh failed, or an input was left out."""
        return bool(self.problems) or any(r.status.startswith("failed") for r in self.rows)

    @property
    def rand_index_error(self) -> float:
        """Overall 1 - RI (mean over the scored meshes)."""
        return self.overall_meshes.get("rand_index_error", float("nan"))

    def row(self, mesh_id: int):
        """The :class:`~torchakvf.evaluate.score.MeshScore` of one mesh."""
        for r in self.rows:
            if r.mesh_id == mesh_id:
                return r
        raise KeyError(mesh_id)


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
            per_cat[c] = {k: v for k, v in mean_dicts([r.metrics for r in ok]).items() if k in cols}
            per_cat[c]["seconds"] = float(np.mean([r.seconds for r in ok]))
            for name in REFERENCES:
                refs[name][c] = mean_dicts([r.references.get(name, {}) for r in ok])
    ok_all = [r for r in rows if r.scored]
    overall_m = mean_dicts([r.metrics for r in ok_all]) if ok_all else {}
    overall_c = mean_dicts(list(per_cat.values())) if per_cat else {}
    if ok_all:
        overall_m["seconds"] = float(np.mean([r.seconds for r in ok_all]))
        overall_c["seconds"] = float(np.mean([v["seconds"] for v in per_cat.values()]))
    for name in REFERENCES:
        if ok_all:
            refs[name]["overall_meshes"] = mean_dicts([r.references.get(name, {}) for r in ok_all])
            refs[name]["overall_categories"] = mean_dicts([refs[name][c] for c in per_cat])
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


def write_reports(out, rows_by_id, plans, settings, groups, wall, recorded, *, plot,
                  problems=()) -> EvalSummary:
    """Writes scores.csv, summary.md (and with ``plot`` rand_index.png and the galleries, drawn
    in up to ``settings.workers`` processes: :func:`~torchakvf.evaluate.gallery.gallery_workers`)
    from the rows so far.

    settings : the run's :class:`~torchakvf.evaluate.settings.EvalSettings`
    recorded : {"prediction": ..., "run": ...} as settings.json holds them
    """
    protocol, auto = settings.protocol, settings.auto
    workers = 1 if settings.workers is None else int(settings.workers)
    rows = [rows_by_id[p.mesh_id] for p in plans if p.mesh_id in rows_by_id]
    cols = [c for g in groups for c in METRIC_GROUPS[g]]
    # scores.csv
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    ref_cols = ["human_rand_index_error", "one_segment_rand_index_error",
                "every_face_rand_index_error"]
    w.writerow(["id", "category", "faces", "ks", *METRICS, "seconds", "status", "human_mode",
                *ref_cols, "converged"])
    for r in rows:
        ks = ";".join(map(str, r.ks))
        if r.k_auto:
            ks = f"auto:{ks}"
        refs = [r.references.get(n, {}).get("rand_index_error") for n in REFERENCES]
        w.writerow([r.mesh_id, r.category, r.faces, ks,
                    *[_fmt(r.metrics.get(m), 6) if m in r.metrics else "" for m in METRICS],
                    _fmt(r.seconds, 2), r.status, "" if r.human_mode is None else r.human_mode,
                    *[_fmt(v, 6) if v is not None else "" for v in refs],
                    "" if r.converged is None else int(bool(r.converged))])
    atomic_write_bytes(out / "scores.csv", buf.getvalue().encode())

    cats, per_cat, counts, overall_m, overall_c, refs = _aggregate(rows, groups)
    kstats = _k_auto_stats(rows) if auto else None
    summary = EvalSummary(rows=rows, per_category=per_cat, overall_meshes=overall_m,
                          overall_categories=overall_c, references=refs, counts=counts,
                          settings=dict(recorded),
                          wall_seconds=wall, predict_seconds=float("nan"),
                          score_seconds=float("nan"), out_dir=out, k_auto=kstats,
                          problems=list(problems))
    if plot:
        summary.galleries = write_galleries(out, plans, rows, workers=workers)
    atomic_write_bytes(out / "summary.md", _summary_md(summary, cats, cols, protocol, auto).encode())
    if plot:
        _plot(out / "rand_index.png", summary, cats, protocol, auto)
    return summary


def _summary_md(s: EvalSummary, cats, cols, protocol, auto) -> str:
    L = _header_lines(s, protocol, auto)
    L += _rand_index_lines(s, cats)
    L += _metric_lines(s, cats, cols)
    if s.k_auto:
        L += _k_auto_lines(s.k_auto)
    L += _trouble_lines(s)
    return "\n".join(L) + "\n"


def _header_lines(s: EvalSummary, protocol, auto) -> list:
    L = []
    pred, run = s.settings["prediction"], s.settings["run"]
    n_ok = sum(r.scored for r in s.rows)
    n_no = sum(r.status == "no score" for r in s.rows)
    n_fail = sum(r.status.startswith("failed") for r in s.rows)
    L.append("# torchakvf on the Princeton Segmentation Benchmark\n")
    shown = f"k auto ({pred['k_rule']}, k in {pred['k_range']})" if auto else protocol
    L.append(f"- protocol: **{shown}**")
    L.append(f"- meshes: {len(s.rows)} ({n_ok} scored, {n_no} without human segmentations: no score, "
             f"{n_fail} failed)")
    n_fields = pred['n_fields'] or "default (3 max(k, 8) rounded up to 8s, in [16, 32], for method merge; 2k for paper)"
    L.append(f"- settings: seed {pred['seed']}, remedy {pred['remedy']}, n_fields {n_fields}, "
             f"segment {pred['segment_kwargs']}, "
             f"k without ground truth {pred['default_k']}, batch_faces {run['batch_faces']}, "
             f"metrics {','.join(run['metrics'])}")
    L.append(f"- wall time of this run: {s.wall_seconds:.1f} s "
             f"({s.wall_seconds / 60:.1f} min); mean compute per scored mesh "
             f"{_fmt(s.overall_meshes.get('seconds'), 1)} s")
    L.append("- all values are dissimilarities (lower is better); 1-RI faces counted, "
             "Hamming area weighted, GCE/LCE faces counted, CD / average radius\n")
    return L


def _rand_index_lines(s: EvalSummary, cats) -> list:
    n_ok = sum(r.scored for r in s.rows)
    L = ["## 1 - Rand Index per category\n"]
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
    return L


def _metric_lines(s: EvalSummary, cats, cols) -> list:
    L = ["\n## All metrics per category (torchakvf)\n"]
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
    return L


def _k_auto_lines(k_auto: dict) -> list:
    L = ["\n## Automatic k\n"]
    L.append("| category | meshes | chosen = human mode | within 1 | mean k chosen | mean human "
             "mode | 1-RI (auto k) | 1-RI (k = human mode, same scan) | 1-RI (best k of scan) |")
    L.append("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    items = list(k_auto["per_category"].items()) + [("**overall**", k_auto["overall"])]
    for c, v in items:
        L.append(f"| {c} | {v['n']} | {_fmt(v['hit_rate'], 2)} | {_fmt(v['within_1'], 2)} | "
                 f"{_fmt(v['mean_chosen'], 1)} | {_fmt(v['mean_mode'], 1)} | "
                 f"{_fmt(v['rand_index_error'])} | {_fmt(v['rand_index_error_at_mode'])}"
                 f" ({v['n_mode_in_range']}) | {_fmt(v['rand_index_error_best_k'])} |")
    rules = k_auto["overall"].get("hit_rate_by_rule", {})
    if rules:
        L.append("\nHit rate (chosen = human mode) of each rule on the same scans: "
                 + ", ".join(f"{r} {_fmt(v, 2)}" for r, v in rules.items()))
    return L


def _trouble_lines(s: EvalSummary) -> list:
    """Failed meshes, unconverged eigensolves, galleries and input problems."""
    L = []
    fails = [r for r in s.rows if r.status.startswith("failed")]
    if fails:
        L.append("\n## Failed meshes\n")
        for r in fails:
            L.append(f"- {r.mesh_id} ({r.category}): {r.status[len('failed: '):]}")
    unconverged = [r for r in s.rows if r.converged is False]
    if unconverged:
        L.append("\n## Eigensolves that did not converge\n")
        L.append("Scored, but their AKVFs did not reach the solver's residual tolerance (see "
                 "max_residual in pred/<id>/<id>_meta.json): "
                 + ", ".join(f"{r.mesh_id} ({r.category})" for r in unconverged))
    if s.galleries:
        L.append("\n## Galleries\n")
        L.append("Each mesh's prediction beside one human segmentation at the same k, with its 1-RI: "
                 + ", ".join(f"[{c}]({rel})" for c, rel in s.galleries.items()))
    if s.problems:
        L.append("\n## Input problems\n")
        L.extend(f"- {line}" for line in s.problems)
    return L


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
