"""PSB shape classification (19 categories) from per-face AKVF descriptors pooled over each mesh,
beside ShapeDNA and both together, with the same model and folds in one run.

Every descriptor comes from ``descriptor_pass.py``'s cache (meshes decimated to ~4000 faces, at
unit area). Label = category, known from the mesh id (no segmentation is read). Rows:

* **AKVF pooled**: each of the 41 per-face columns (the 33 of
  :func:`torchakvf.fields.descriptors.face_descriptors`, the 8 of
  :func:`torchakvf.parts.part_descriptors.part_descriptors`) summarized over the mesh by its
  area-weighted mean, standard deviation and 10/50/90 % quantiles (205 dims); beside it the
  same of the 33 field columns alone;
* **AKVF pooled + Killing spectrum**: the same and log(1 + λ·area) of the 32 AKVFs (the
  headline AKVF row: both are what the AKVF pass gives);
* **ShapeDNA**: the first 32 non-zero eigenvalues λ·area of the cotan Laplace-Beltrami operator
  (lumped mass), log;
* **AKVF pooled + spectrum + ShapeDNA**;
* **AKVF histograms** (spectrum + area-weighted histograms of the untangled φ at 32 fields,
  the earlier AKVF histogram descriptor (Killing spectrum + histograms of the untangled features),
  recomputed from the same cache) and a **trivial** descriptor (log face/vertex counts, extent
  ratios, components).

Model: multinomial logistic regression (L2 1e-2, full-batch L-BFGS in torch) on standardized
descriptors (training-fold statistics); stratified 5-fold cross-validation, seed 0; accuracy
mean ± std over the folds. Run::

    PYTHONPATH=$PWD nice -n 5 python benchmarks/classify_descriptors.py --cache DIR \\
        --out benchmarks/results/classify_descriptors
"""
from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

import descriptor_pass
import numpy as np
import torch

SEED = 0
FOLDS = 5
L2 = 1e-2
QUANTILES = (0.1, 0.5, 0.9)
HIST_BINS = 16

log = logging.getLogger("classify_descriptors")


def weighted_quantiles(x: np.ndarray, w: np.ndarray, qs) -> np.ndarray:
    """[len(qs), k] area-weighted quantiles of each column of x [F, k]."""
    out = np.empty((len(qs), x.shape[1]))
    for j in range(x.shape[1]):
        order = np.argsort(x[:, j])
        cw = np.cumsum(w[order]) / w.sum()
        out[:, j] = x[order, j][np.minimum(np.searchsorted(cw, qs), len(cw) - 1)]
    return out


def pooled(d: dict, keys=("akvf", "akvf_parts")) -> np.ndarray:
    """Mean, std and quantiles of every per-face AKVF column of the groups ``keys``, area-weighted."""
    x = np.concatenate([d[k] for k in keys], axis=1).astype(np.float64)
    a = d["area"] / d["area"].sum()
    mean = a @ x
    std = np.sqrt(np.maximum(a @ (x - mean) ** 2, 0.0))
    return np.concatenate([mean, std, weighted_quantiles(x, a, QUANTILES).ravel()])


def spectrum(d: dict) -> np.ndarray:
    return np.log1p(np.maximum(d["eigenvalues"], 0.0))


def shapedna(d: dict) -> np.ndarray:
    return np.log(np.maximum(d["shapedna"], 1e-12))


def histograms(d: dict) -> np.ndarray:
    """The earlier AKVF descriptor: spectrum + histograms of φ at 32 fields."""
    phi = d["phi32"].astype(np.float64)
    a = d["area"] / d["area"].sum()
    rel = phi / np.maximum(phi.max(axis=0, keepdims=True), 1e-300)
    edges = np.linspace(0.0, 1.0, HIST_BINS + 1)
    pooled_ = np.histogram(rel.ravel(), bins=edges, weights=np.repeat(a, rel.shape[1]))[0] / rel.shape[1]
    share = phi.max(axis=1) / np.maximum(phi.sum(axis=1), 1e-300)
    dominance = np.histogram(share, bins=edges, weights=a)[0]
    support = np.sort((a[:, None] * (rel > 0.5)).sum(axis=0))
    return np.concatenate([spectrum(d), pooled_, dominance, support])


ROWS = {
    "AKVF pooled per-face descriptors": pooled,
    "AKVF pooled field descriptors only": lambda d: pooled(d, ("akvf",)),
    "AKVF pooled + Killing spectrum": lambda d: np.concatenate([pooled(d), spectrum(d)]),
    "ShapeDNA (cotan Laplacian spectrum)": shapedna,
    "AKVF pooled + spectrum + ShapeDNA": lambda d: np.concatenate([pooled(d), spectrum(d), shapedna(d)]),
    "AKVF histograms (the earlier descriptor)": histograms,
    "trivial (counts, extents)": lambda d: d["trivial"],
}


def stratified_folds(y: np.ndarray, k: int, seed: int) -> np.ndarray:
    """[N] fold of each sample: each class's samples shuffled and dealt round-robin."""
    rng = np.random.default_rng(seed)
    fold = np.empty(len(y), dtype=np.int64)
    for c in np.unique(y):
        idx = rng.permutation(np.flatnonzero(y == c))
        fold[idx] = np.arange(len(idx)) % k
    return fold


def fit_logistic(x: np.ndarray, y: np.ndarray, n_classes: int):
    """Multinomial logistic regression, L2 penalty L2·|W|², L-BFGS; returns (W, b)."""
    xt = torch.as_tensor(x, dtype=torch.float64)
    yt = torch.as_tensor(y, dtype=torch.long)
    w = torch.zeros(x.shape[1], n_classes, dtype=torch.float64, requires_grad=True)
    b = torch.zeros(n_classes, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.LBFGS([w, b], max_iter=500, tolerance_grad=1e-9, line_search_fn="strong_wolfe")

    def closure():
        opt.zero_grad()
        loss = torch.nn.functional.cross_entropy(xt @ w + b, yt) + L2 * (w * w).sum()
        loss.backward()
        return loss

    opt.step(closure)
    return w.detach(), b.detach()


def cross_validate(x: np.ndarray, y: np.ndarray, folds: np.ndarray) -> list[float]:
    n_classes = int(y.max()) + 1
    acc = []
    for k in range(int(folds.max()) + 1):
        tr, te = folds != k, folds == k
        mu, sd = x[tr].mean(0), x[tr].std(0) + 1e-12
        w, b = fit_logistic((x[tr] - mu) / sd, y[tr], n_classes)
        pred = (torch.as_tensor((x[te] - mu) / sd) @ w + b).argmax(1).numpy()
        acc.append(float((pred == y[te]).mean()))
    return acc


def main(argv=None) -> int:
    ap = descriptor_pass.cache_parser(__doc__.split("\n")[0])
    ap.add_argument("--out", default="benchmarks/results/classify_descriptors")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    torch.set_num_threads(args.threads)
    from torchakvf.evaluate.psb import CATEGORIES

    data, missing = descriptor_pass.load_all(args.psb, Path(args.cache), compute=False)
    cats = sorted({d["category"] for d in data}, key=CATEGORIES.index)
    y = np.array([cats.index(d["category"]) for d in data])
    folds = stratified_folds(y, FOLDS, SEED)
    rows = {}
    for name, vec in ROWS.items():
        x = np.stack([vec(d) for d in data])
        acc = cross_validate(x, y, folds)
        rows[name] = {"dims": int(x.shape[1]), "fold_accuracy": acc,
                      "mean": float(np.mean(acc)), "std": float(np.std(acc))}
        log.info("%s: %.3f ± %.3f", name, np.mean(acc), np.std(acc))
    akvf_s = [float(d["seconds_akvf"]) for d in data]
    parts_s = [float(d["seconds_parts"]) for d in data]
    result = {"meshes": len(data), "categories": cats, "folds": FOLDS, "seed": SEED, "l2": L2,
              "left_out": missing, "chance": 1.0 / len(cats),
              "per_category": {c: int((y == i).sum()) for i, c in enumerate(cats)},
              "akvf_seconds_total": sum(akvf_s), "akvf_seconds_median": float(np.median(akvf_s)),
              "parts_seconds_total": sum(parts_s), "parts_seconds_median": float(np.median(parts_s)),
              "results": rows}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    lines = [f"# PSB shape classification from pooled per-face descriptors ({len(data)} meshes, "
             f"{len(cats)} categories)", "",
             f"Stratified {FOLDS}-fold cross-validation (seed {SEED}), multinomial logistic regression "
             f"(L2 {L2:g}) on standardized descriptors, all rows in one run from one descriptor pass "
             f"(meshes decimated to ~{descriptor_pass.COARSE_FACES} faces); chance = {1 / len(cats):.3f}. "
             "`benchmarks/classify_descriptors.py`.", "",
             "| descriptor | dims | accuracy (mean ± std over folds) |", "|---|---:|---:|"]
    lines += [f"| {k} | {r['dims']} | {r['mean']:.3f} ± {r['std']:.3f} |" for k, r in rows.items()]
    lines += ["", f"Meshes left out (solver failure or not in the cache): {missing or 'none'}.",
              f"AKVF part of the descriptor pass (decimate, solve 32 fields, untangle at 8/16/32, "
              f"field descriptors, 18 segmentations for the part descriptors): {sum(akvf_s):.0f} s in all, "
              f"median {np.median(akvf_s):.1f} s per mesh, of which the part descriptors {sum(parts_s):.0f} s, "
              f"median {np.median(parts_s):.1f} s."]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
