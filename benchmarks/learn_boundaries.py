"""Learning where people cut: per-face boundary prediction on the PSB from AKVF descriptors,
classical descriptors and both, with one model and one training budget for every row.

Data: the 15 PSB categories with human segmentations, every mesh decimated as the eval does
(~4000 faces); per-mesh descriptors and targets come from ``descriptor_pass.py``'s cache.
Target per face (computed before any model was run, fixed here):

* **majority** (the headline): at least half of the people who segmented the mesh cut within
  ``BOUNDARY_RADIUS`` = 0.02 (geodesic, lengths at unit area; about 1.5 face rings) of the face;
* **any**: at least one person did (reported beside it; one over-segmenting person marks much
  of a mesh, so it is noisier).

Protocol: leave one category out (15 folds). The model is trained on the faces of the other 14
categories and scored on every face of the held-out one by average precision (AP, the area under
the precision-recall curve, step-wise; chance = the positive rate). Rows differ only in the
input columns. Model, the same for every row and fold: standardization (training mean/std), an
MLP d -> 32 -> 32 -> 2 (ReLU; one output per target), Adam (lr 3e-3, weight decay 1e-4),
:data:`STEPS` minibatches of :data:`BATCH` faces drawn uniformly from the training faces,
binary cross-entropy, seeded; float32. Nothing is tuned on a held-out category: no early
stopping, no per-fold choices.

Run (descriptors cached by ``descriptor_pass.py`` first)::

    PYTHONPATH=$PWD nice -n 5 python benchmarks/learn_boundaries.py --cache DIR \\
        --out benchmarks/results/learn_boundaries
"""
from __future__ import annotations

import json
import logging
import sys
import time
from pathlib import Path

import descriptor_pass
import numpy as np
import torch

STEPS = 1000
BATCH = 2048
HIDDEN = 32
SEED = 0
TARGETS = ("majority", "any")

log = logging.getLogger("learn_boundaries")


def _columns(*keys):
    """The per-face columns [F, k] of one cached mesh: the named groups side by side."""
    return lambda d: np.concatenate([d[k] for k in keys], axis=1)


CLASSICAL = ("curvature", "hks", "wks", "sdf")
AKVF = ("akvf", "akvf_parts")
#: Rows: name -> the per-face columns [F, k] of one cached mesh.
ROWS = {
    "curvature (k1, k2 at 3 radii)": _columns("curvature"),
    "HKS (8 times)": _columns("hks"),
    "WKS (8 energies)": _columns("wks"),
    "SDF (2)": _columns("sdf"),
    "classical (curvature + HKS + WKS + SDF)": _columns(*CLASSICAL),
    "AKVF descriptors (fields 33 + parts 8)": _columns(*AKVF),
    "AKVF field descriptors (33)": _columns("akvf"),
    "AKVF part descriptors (8)": _columns("akvf_parts"),
    "classical + AKVF descriptors": _columns(*CLASSICAL, *AKVF),
    "classical + AKVF field descriptors": _columns(*CLASSICAL, "akvf"),
    "curvature + AKVF descriptors": _columns("curvature", *AKVF),
    "raw untangled norms φ at 32 fields (column order as solved)": _columns("phi32"),
    "boundary probability alone (1)": _columns("akvf_boundary"),
    "crease cues (6)": _columns("cues"),
    "AKVF descriptors + boundary probability (41 + 1)": _columns(*AKVF, "akvf_boundary"),
    "AKVF descriptors + crease cues (41 + 6)": _columns(*AKVF, "cues"),
    "package descriptors (AKVF 41 + crease cues 6 + boundary probability 1)": _columns(*AKVF, "cues", "akvf_boundary"),
    "classical + crease cues": _columns(*CLASSICAL, "cues"),
    "classical + AKVF descriptors + crease cues": _columns(*CLASSICAL, *AKVF, "cues"),
    "classical + package descriptors": _columns(*CLASSICAL, *AKVF, "cues", "akvf_boundary"),
}
SINGLE_CLASSICAL = ("curvature (k1, k2 at 3 radii)", "HKS (8 times)", "WKS (8 energies)", "SDF (2)")
AKVF_ROW = "AKVF descriptors (fields 33 + parts 8)"
CLASSICAL_ROW = "classical (curvature + HKS + WKS + SDF)"
BOTH_ROW = "classical + AKVF descriptors"
PACKAGE_ROW = "package descriptors (AKVF 41 + crease cues 6 + boundary probability 1)"
ALL_ROW = "classical + package descriptors"
#: (with, without): the gains reported per held-out category
PAIRS = ((ALL_ROW, CLASSICAL_ROW), (BOTH_ROW, CLASSICAL_ROW), ("classical + AKVF field descriptors", CLASSICAL_ROW),
         ("classical + AKVF descriptors + crease cues", CLASSICAL_ROW), ("classical + crease cues", CLASSICAL_ROW),
         ("curvature + AKVF descriptors", SINGLE_CLASSICAL[0]), (ALL_ROW, BOTH_ROW),
         (ALL_ROW, "classical + AKVF descriptors + crease cues"),
         ("AKVF descriptors + boundary probability (41 + 1)", AKVF_ROW), (PACKAGE_ROW, AKVF_ROW),
         (PACKAGE_ROW, "AKVF descriptors + crease cues (41 + 6)"))


def average_precision(score: np.ndarray, positive: np.ndarray) -> float:
    """Step-wise AP: the mean, over the positives, of the precision at each one's rank."""
    order = np.argsort(-score, kind="stable")
    hit = positive[order].astype(np.float64)
    if hit.sum() == 0:
        return float("nan")
    precision = np.cumsum(hit) / np.arange(1, len(hit) + 1)
    return float((precision * hit).sum() / hit.sum())


def targets_of(d: dict) -> np.ndarray:
    """[F, 2] float32: the majority and any targets of the module docstring."""
    t = d["target"]
    return np.stack([t >= 0.5, t > 0], axis=1).astype(np.float32)


def fit_predict(x_train: np.ndarray, y_train: np.ndarray, x_test: np.ndarray) -> np.ndarray:
    """[F_test, 2] logits of the module docstring's MLP trained on (x_train, y_train)."""
    mu, sd = x_train.mean(0), x_train.std(0) + 1e-6
    xt = torch.as_tensor((x_train - mu) / sd, dtype=torch.float32)
    yt = torch.as_tensor(y_train)
    gen = torch.Generator().manual_seed(SEED)
    torch.manual_seed(SEED)
    model = torch.nn.Sequential(torch.nn.Linear(xt.shape[1], HIDDEN), torch.nn.ReLU(),
                                torch.nn.Linear(HIDDEN, HIDDEN), torch.nn.ReLU(),
                                torch.nn.Linear(HIDDEN, yt.shape[1]))
    opt = torch.optim.Adam(model.parameters(), lr=3e-3, weight_decay=1e-4)
    loss_fn = torch.nn.BCEWithLogitsLoss()
    for _ in range(STEPS):
        idx = torch.randint(0, len(xt), (BATCH,), generator=gen)
        opt.zero_grad()
        loss = loss_fn(model(xt[idx]), yt[idx])
        loss.backward()
        opt.step()
    with torch.no_grad():
        return model(torch.as_tensor((x_test - mu) / sd, dtype=torch.float32)).numpy()


def leave_one_category_out(data: list[dict], columns) -> dict:
    """{category: {target: AP}} over held-out categories, for one row's columns."""
    xs = [np.asarray(columns(d), dtype=np.float32) for d in data]
    ys = [targets_of(d) for d in data]
    cats = np.array([d["category"] for d in data])
    out = {}
    for cat in dict.fromkeys(cats):
        train = np.flatnonzero(cats != cat)
        test = np.flatnonzero(cats == cat)
        logits = fit_predict(np.concatenate([xs[i] for i in train]), np.concatenate([ys[i] for i in train]),
                             np.concatenate([xs[i] for i in test]))
        y = np.concatenate([ys[i] for i in test])
        out[str(cat)] = {t: average_precision(logits[:, k], y[:, k] > 0.5) for k, t in enumerate(TARGETS)}
    return out


def summary(per_cat: dict, target: str) -> tuple[float, float]:
    v = np.array([r[target] for r in per_cat.values()])
    return float(np.nanmean(v)), float(np.nanstd(v))


def report(result: dict) -> list[str]:
    rows, cats = result["rows"], result["categories"]
    lines = [f"# Learning human cuts on the PSB: leave one category out ({len(cats)} categories, "
             f"{result['meshes']} meshes)", "",
             "Per-face boundary prediction, `benchmarks/learn_boundaries.py` (protocol in its docstring): "
             f"the same MLP (d-{HIDDEN}-{HIDDEN}-2, {STEPS} Adam steps of {BATCH} faces, seed {SEED}) for "
             "every row; average precision on the held-out category's faces; mean ± std over the "
             f"{len(cats)} held-out categories. Meshes decimated to ~{descriptor_pass.COARSE_FACES} faces; a "
             f"face is positive when people cut within {descriptor_pass.BOUNDARY_RADIUS} (unit-area "
             "geodesic) of it: **majority** = at least half of them, **any** = at least one.", "",
             "| descriptor | dims | AP majority | AP any |", "|---|---:|---:|---:|"]
    chance = result["chance"]
    lines.append(f"| chance (positive rate) | | {chance['majority'][0]:.3f} ± {chance['majority'][1]:.3f} "
                 f"| {chance['any'][0]:.3f} ± {chance['any'][1]:.3f} |")
    for name, r in rows.items():
        m = summary(r["per_category"], "majority")
        a = summary(r["per_category"], "any")
        lines.append(f"| {name} | {r['dims']} | {m[0]:.3f} ± {m[1]:.3f} | {a[0]:.3f} ± {a[1]:.3f} |")
    lines += ["", "What adding columns changes, per held-out category (paired, AP majority):", "",
              "| rows | mean gain ± std over categories | categories improved |", "|---|---:|---:|"]
    for with_, without in PAIRS:
        if with_ in rows and without in rows:
            g = np.array([rows[with_]["per_category"][c]["majority"] - rows[without]["per_category"][c]["majority"]
                          for c in cats])
            lines.append(f"| {with_} − {without} | {g.mean():+.3f} ± {g.std():.3f} | {(g > 0).sum()} of {len(g)} |")
    shown = [n for n in SINGLE_CLASSICAL + (CLASSICAL_ROW, AKVF_ROW, PACKAGE_ROW, BOTH_ROW, ALL_ROW) if n in rows]
    gain = ALL_ROW in rows and CLASSICAL_ROW in rows
    title = "Per held-out category, AP majority" + (" (last column: the first pair's gain)" if gain else "")
    lines += ["", title + ":",
              "", "| category | chance | " + " | ".join(shown) + (" | gain |" if gain else " |"),
              "|---|" + "---:|" * (1 + len(shown) + gain)]
    for c in cats:
        cells = [f"{rows[n]['per_category'][c]['majority']:.3f}" for n in shown]
        if gain:
            g = rows[ALL_ROW]["per_category"][c]["majority"] - rows[CLASSICAL_ROW]["per_category"][c]["majority"]
            cells.append(f"{g:+.3f}")
        lines.append(f"| {c} | {result['chance_per_category'][c]:.3f} | " + " | ".join(cells) + " |")
    return lines


def main(argv=None) -> int:
    ap = descriptor_pass.cache_parser(__doc__.split("\n")[0])
    ap.add_argument("--out", default="benchmarks/results/learn_boundaries")
    ap.add_argument("--rows", default=None, help="comma-separated row indices (default: all)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    torch.set_num_threads(args.threads)
    data, missing = descriptor_pass.load_all(args.psb, Path(args.cache), compute=False)
    data = [d for d in data if "target" in d]
    cats = list(dict.fromkeys(d["category"] for d in sorted(data, key=lambda d: d["mesh_id"])))
    names = list(ROWS) if args.rows is None else [list(ROWS)[int(i)] for i in args.rows.split(",")]
    rows = {}
    for name in names:
        t = time.perf_counter()
        per_cat = leave_one_category_out(data, ROWS[name])
        rows[name] = {"dims": int(np.asarray(ROWS[name](data[0])).shape[1]), "per_category": per_cat,
                      "seconds": time.perf_counter() - t}
        log.info("%s: AP majority %.3f ± %.3f (%.0f s)", name, *summary(per_cat, "majority"), rows[name]["seconds"])
    by_cat = {c: np.concatenate([targets_of(d) for d in data if d["category"] == c]) for c in cats}
    chance = {t: (float(np.mean([by_cat[c][:, k].mean() for c in cats])),
                  float(np.std([by_cat[c][:, k].mean() for c in cats]))) for k, t in enumerate(TARGETS)}
    seconds = [float(d["seconds_akvf"]) for d in data], [float(d["seconds_classical"]) for d in data]
    result = {"meshes": len(data), "categories": cats, "missing": missing, "chance": chance,
              "chance_per_category": {c: float(by_cat[c][:, 0].mean()) for c in cats},
              "faces": int(sum(len(d["target"]) for d in data)),
              "descriptor_seconds": {"akvf_total": sum(seconds[0]), "classical_total": sum(seconds[1]),
                                     "akvf_per_mesh_median": float(np.median(seconds[0])),
                                     "classical_per_mesh_median": float(np.median(seconds[1]))},
              "rows": rows}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    lines = report(result)
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
