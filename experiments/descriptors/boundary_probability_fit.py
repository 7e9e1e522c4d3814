"""Fit the per-face boundary probability on the procedural part-labelled corpus (never the PSB).

Inputs per face (what the package computes for its descriptors anyway): the 33 field and 8 part
descriptor columns and the crease cues (:mod:`torchakvf.parts.boundary_cues`) of the mesh the
fields are solved on. Target: a true part boundary within 0.02 (unit-area geodesic) of the face,
``descriptor_pass.boundary_target`` of the corpus labels carried to the decimated faces.

Steps:

1. ``--pass``: per corpus shape (the first ``--per-family`` of each family), ``descriptor_pass.one_mesh``
   (the descriptors as ``interop.face_features`` computes them, decimated canonically to ~4000
   faces; shipped merge weights), cached in ``--cache``;
2. ``--select``: each model form of :data:`FORMS` scored leave one family out on the corpus
   (average precision on the held-out family's faces, mean over families);
3. ``--out FILE``: the chosen form (:data:`CHOSEN`) fitted on every corpus face, written as the
   package's weights file (:func:`write_weights`; by default torchakvf/parts/boundary_weights.json).

Run::

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 nice python experiments/descriptors/boundary_probability_fit.py \\
        --corpus /tmp/corpus --cache /tmp/bprob_corpus/cache --pass [--reverse]     # two workers
    PYTHONPATH=$PWD OMP_NUM_THREADS=1 nice python experiments/descriptors/boundary_probability_fit.py \\
        --corpus /tmp/corpus --cache /tmp/bprob_corpus/cache --select --out DEFAULT

(the corpus: ``datasets_scripts/make_parts_corpus.py --out /tmp/corpus --per-family 30 --seed 0``).
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT))

from torchakvf.parts.boundary_cues import crease_cues  # noqa: E402
from torchakvf.parts.boundary_probability import PACKAGE_FILE, weights_record, write_weights  # noqa: E402

#: Model forms compared leave one family out: hidden layer widths (() = logistic regression).
FORMS = {"logistic": (), "mlp16": (16,), "mlp32x32": (32, 32)}
CHOSEN = "mlp32x32"
STEPS = 1000
BATCH = 2048
SEED = 0

log = logging.getLogger("boundary_probability_fit")


def corpus_pass(corpus: Path, cache: Path, per_family: int, reverse: bool = False) -> None:
    """``descriptor_pass.one_mesh`` of the first ``per_family`` shapes of each family, cached
    (``reverse``: in the opposite order, for a second worker sharing the cache)."""
    import descriptor_pass

    cache.mkdir(parents=True, exist_ok=True)
    shapes = json.loads((corpus / "index.json").read_text())["shapes"]
    for e in (shapes[::-1] if reverse else shapes):
        path = cache / f"{e['name']}.npz"
        if int(e["name"].rsplit("_", 1)[1]) >= per_family or path.exists():
            continue
        folder = corpus / e["family"]
        entry = SimpleNamespace(mesh_path=folder / f"{e['name']}.off", seg_paths=[folder / f"{e['name']}.seg"],
                                category="corpus_" + e["family"], mesh_id=0)
        t = time.process_time()
        tmp = path.with_suffix(".tmp.npz")
        np.savez_compressed(tmp, **descriptor_pass.one_mesh(entry))
        tmp.replace(path)
        log.info("%s: %.1f CPU s", e["name"], time.process_time() - t)


def model_inputs(d: dict) -> np.ndarray:
    """[F, 47] float64: field descriptors, part descriptors, crease cues of one cached mesh."""
    cues = crease_cues(d["packed_vertices"], d["packed_faces"])
    return np.concatenate([d["akvf"], d["akvf_parts"], cues], axis=1).astype(np.float64)


def load_corpus(cache: Path, per_family: int) -> list[dict]:
    out = []
    for path in sorted(cache.glob("*.npz")):
        if path.stem.endswith(".tmp"):      # another worker's file in the making
            continue
        family, i = path.stem.rsplit("_", 1)
        if int(i) >= per_family:
            continue
        with np.load(path) as z:
            d = {k: z[k] for k in z.files}
        out.append({"family": family, "x": model_inputs(d), "y": (d["target"] >= 0.5).astype(np.float64)})
    return out


def fit(x: np.ndarray, y: np.ndarray, hidden: tuple, seed: int = SEED) -> dict:
    """The model's parameters fitted on (x [N, d], y [N]): standardization, then ReLU layers of
    widths ``hidden`` and one logit; Adam (lr 3e-3, weight decay 1e-4), STEPS minibatches, float64."""
    mu, sd = x.mean(0), x.std(0) + 1e-6
    xt = torch.as_tensor((x - mu) / sd)
    yt = torch.as_tensor(y)[:, None]
    gen = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    layers, width = [], x.shape[1]
    for h in hidden:
        layers += [torch.nn.Linear(width, h), torch.nn.ReLU()]
        width = h
    model = torch.nn.Sequential(*layers, torch.nn.Linear(width, 1)).double()
    opt = torch.optim.Adam(model.parameters(), lr=3e-3, weight_decay=1e-4)
    loss_fn = torch.nn.BCEWithLogitsLoss()
    for _ in range(STEPS):
        idx = torch.randint(0, len(xt), (BATCH,), generator=gen)
        opt.zero_grad()
        loss_fn(model(xt[idx]), yt[idx]).backward()
        opt.step()
    linear = [m for m in model if isinstance(m, torch.nn.Linear)]
    return {"mean": mu, "scale": sd,
            "layers": [(m.weight.detach().numpy().copy(), m.bias.detach().numpy().copy()) for m in linear]}


def predict(params: dict, x: np.ndarray) -> np.ndarray:
    from torchakvf.parts.boundary_probability import apply_model

    return apply_model(params, x)


def average_precision(score: np.ndarray, positive: np.ndarray) -> float:
    order = np.argsort(-score, kind="stable")
    hit = positive[order].astype(np.float64)
    precision = np.cumsum(hit) / np.arange(1, len(hit) + 1)
    return float((precision * hit).sum() / max(hit.sum(), 1))


def leave_one_family_out(data: list[dict], hidden: tuple) -> dict:
    fams = list(dict.fromkeys(d["family"] for d in data))
    out = {}
    for fam in fams:
        tr = [d for d in data if d["family"] != fam]
        te = [d for d in data if d["family"] == fam]
        params = fit(np.concatenate([d["x"] for d in tr]), np.concatenate([d["y"] for d in tr]), hidden)
        out[fam] = average_precision(predict(params, np.concatenate([d["x"] for d in te])),
                                     np.concatenate([d["y"] for d in te]) > 0.5)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--corpus", default="/tmp/corpus")
    ap.add_argument("--cache", required=True)
    ap.add_argument("--per-family", type=int, default=30,
                    help="the first N shapes of each family (default 30: the whole default corpus)")
    ap.add_argument("--pass", dest="run_pass", action="store_true")
    ap.add_argument("--reverse", action="store_true",
                    help="with --pass: visit the shapes in the opposite order (a second worker on the same cache)")
    ap.add_argument("--select", action="store_true")
    ap.add_argument("--out", default=None, help="weights file to write (DEFAULT: the package's)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    torch.set_num_threads(1)
    if args.run_pass:
        corpus_pass(Path(args.corpus), Path(args.cache), args.per_family, args.reverse)
    data = load_corpus(Path(args.cache), args.per_family)
    log.info("%d shapes, %d faces, positive rate %.3f", len(data), sum(len(d["y"]) for d in data),
             np.concatenate([d["y"] for d in data]).mean())
    if args.select:
        for name, hidden in FORMS.items():
            per = leave_one_family_out(data, hidden)
            v = np.array(list(per.values()))
            print(f"{name}: AP {v.mean():.3f} ± {v.std():.3f} | " + " ".join(f"{k} {a:.3f}" for k, a in per.items()))
    if args.out:
        params = fit(np.concatenate([d["x"] for d in data]), np.concatenate([d["y"] for d in data]), FORMS[CHOSEN])
        n_fam = len({d["family"] for d in data})
        record = weights_record(params, f"{len(data)} procedural corpus shapes of {n_fam} families")
        write_weights(record, PACKAGE_FILE if args.out == "DEFAULT" else Path(args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
