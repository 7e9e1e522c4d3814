"""Choosing the second merge (:class:`torchakvf.options.ConcaveChoice`): both merges' parts on every
labelled shape, and the rule's (ratio, floor) chosen leave one group out.

``--collect``: for each shape (the labelled PSB meshes, or a procedural corpus), decimated to
4000 faces as the CLI does, at each k its truths have: the final labels of the learned merge
alone (``merge_choice=None``) and of the hand-set merge alone (the choice's weights as the
first merge, ``merge_choice=None``; the AKVFs and the over-segmentation are the same), their
1 - Rand index against the truths with that k, and each partition's weakest boundary
(:func:`torchakvf.parts.concave_choice.weakest_boundary` on the input mesh's dual edges). One
pickle per data set.

``--report``: for each (ratio, floor) of a grid, the shapes where the hand-set partition's
weakest boundary is above the floor and above ratio x the learned one's take the hand-set
partition; a group's score is the mean over its shapes (a PSB mesh: the mean over its humans,
as ``torchakvf eval`` scores it). The rule is chosen to minimize the mean over the 30 groups
of the PSB's 15 labelled categories and the first corpus's 15 families, and scored
leave-one-group-out (each group with the rule chosen without it); any further corpus given is
scored with the rule chosen on all 30 groups. ``--criterion mean`` scores a partition by the
mean over its boundaries instead of the least (a variant the result file compares);
``--collect --no-graphcut`` collects the merged labels before the graph cut, errors and
boundaries alike (the result file's "before the graph cut" rows judged those boundaries but
scored the labels after the cut, with an exploratory version of this script).

    PYTHONPATH=$PWD nice python3 experiments/generality/concave_choice_cv.py --collect psb --out /tmp/cc/psb.pkl
    PYTHONPATH=$PWD nice python3 experiments/generality/concave_choice_cv.py --collect /tmp/corpus_s0 \\
        --out /tmp/cc/s0.pkl
    PYTHONPATH=$PWD nice python3 experiments/generality/concave_choice_cv.py --collect /tmp/corpus_s1 \\
        --out /tmp/cc/s1.pkl
    PYTHONPATH=$PWD python3 experiments/generality/concave_choice_cv.py --report /tmp/cc/psb.pkl /tmp/cc/s0.pkl \\
        /tmp/cc/s1.pkl

(/tmp/corpus_s0 and /tmp/corpus_s1: ``datasets_scripts/make_parts_corpus.py --per-family 20 --seed 0``
and ``--seed 1``.) Result: experiments/results/generality_concave_choice.md.
"""
from __future__ import annotations

import argparse
import collections
import itertools
import pickle
import sys
from multiprocessing import get_context
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from items import corpus_items, psb_items, read_truth  # noqa: E402

RATIOS = (1.1, 1.2, 1.3, 1.5, 1.75, 2.0, 3.0, 5.0)
FLOORS = (0.0, 0.02, 0.05, 0.1)


def boundary_stats(dual, labels) -> dict:
    from torchakvf.parts.concave_choice import boundary_concavity

    bends = boundary_concavity(labels, dual)
    return dict(least=float(bends.min()) if len(bends) else float("inf"),
                mean=float(bends.mean()) if len(bends) else float("inf"))


def collect_item(args):
    item, coarse, graphcut = args
    import torch

    torch.set_num_threads(1)
    import torchakvf as ta
    from torchakvf.evaluate.metrics import rand_index_error
    from torchakvf.options import ConcaveChoice
    from torchakvf.parts.concavity import dual_edges
    from torchakvf.parts.segmenter import Segmenter

    truths = [read_truth(p) for p in item.truths]
    ks = sorted({int(t.max()) + 1 for t in truths})
    mesh = ta.load_mesh(item.mesh_path)
    try:
        learned = Segmenter([mesh], coarse_faces=coarse, merge_choice=None, graphcut=graphcut).segment_each_k([ks])
        hand = Segmenter(learned.fields, merge=ConcaveChoice().weights, merge_choice=None,
                         graphcut=graphcut).segment_each_k([ks])
        dual = dual_edges(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces))
    except Exception as exc:                       # noqa: BLE001 - recorded, the run goes on
        print(f"{item.key} FAILED {type(exc).__name__}: {exc}", flush=True)
        return []
    out = []
    for k in ks:
        with_k = [t for t in truths if int(t.max()) + 1 == k]
        rec = dict(key=item.key, group=item.group, kind=item.kind, k=k, humans=len(with_k))
        for name, res in (("learned", learned), ("hand", hand)):
            labels = np.asarray(res.meshes[0][k].labels)
            rec[f"err_{name}"] = float(np.mean([rand_index_error(labels, t) for t in with_k]))
            rec[f"bound_{name}"] = boundary_stats(dual, labels)
        out.append(rec)
    return out


def collect(source: str, out: Path, coarse: int, graphcut: bool, workers: int) -> None:
    items = psb_items() if source == "psb" else corpus_items(source)
    recs = []
    with get_context("spawn").Pool(workers) as pool:
        for got in pool.imap_unordered(collect_item, [(it, coarse, graphcut) for it in items], chunksize=1):
            recs += got
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "wb") as fh:
        pickle.dump(recs, fh)
    print(f"{len(recs)} (shape, k) records -> {out}")


def takes_hand(rec, rule, criterion: str) -> bool:
    if rule is None:
        return False
    ratio, floor = rule
    mine, theirs = rec["bound_learned"][criterion], rec["bound_hand"][criterion]
    return bool(np.isfinite(theirs) and theirs > floor and theirs > ratio * mine)


def group_scores(recs, rule, criterion: str) -> dict:
    """{group: mean over its shapes of the shape's error (PSB: each human's k weighs as many
    humans as drew it)}."""
    per = collections.defaultdict(lambda: collections.defaultdict(list))
    for r in recs:
        err = r["err_hand"] if takes_hand(r, rule, criterion) else r["err_learned"]
        per[r["group"]][r["key"]] += [err] * int(r["humans"])
    return {g: float(np.mean([np.mean(v) for v in shapes.values()])) for g, shapes in per.items()}


def report(paths: list[Path], criterion: str) -> None:
    sets = {}
    for p in paths:
        with open(p, "rb") as fh:
            sets[p.stem] = pickle.load(fh)
    names = list(sets)
    fit = names[:2]                                 # the PSB and the first corpus choose the rule
    grid = [None] + list(itertools.product(RATIOS, FLOORS))
    tab = {(n, rule): group_scores(sets[n], rule, criterion) for n in names for rule in grid}
    groups = [(n, g) for n in fit for g in sorted(tab[(n, None)])]

    def objective(rule, left_out=None):
        return np.mean([tab[(n, rule)][g] for n, g in groups if (n, g) != left_out])

    label = lambda rule: "first merge alone" if rule is None else f"ratio {rule[0]}, floor {rule[1]}"  # noqa: E731
    print(f"criterion: the {criterion} of the boundaries' mean concave bending\n")
    print("| rule | " + " | ".join(names) + " | objective (the 30 groups) |")
    print("|---|" + "---:|" * (len(names) + 1))
    for rule in [None] + sorted(grid[1:], key=objective)[:6]:
        cells = " | ".join(f"{np.mean(list(tab[(n, rule)].values())):.4f}" for n in names)
        print(f"| {label(rule)} | {cells} | {objective(rule):.4f} |")
    chosen = min(grid, key=objective)
    print(f"\nchosen on all 30 groups: {label(chosen)}\n")
    print("| data | group | rule chosen without it | held out | first merge alone | change |")
    print("|---|---|---|---:|---:|---:|")
    held = collections.defaultdict(list)
    for n, g in groups:
        rule = min(grid, key=lambda r: objective(r, (n, g)))
        a, b = tab[(n, rule)][g], tab[(n, None)][g]
        held[n].append((a, b))
        print(f"| {n} | {g} | {label(rule)} | {a:.3f} | {b:.3f} | {a - b:+.3f} |")
    for n in fit:
        a, b = np.mean(held[n], axis=0)
        print(f"| {n} | **all, held out** | | **{a:.4f}** | {b:.4f} | {a - b:+.4f} |")
    for n in names[2:]:
        print(f"\n{n}, with the rule chosen on all 30 groups ({label(chosen)}):\n")
        print("| group | chosen rule | first merge alone | change |\n|---|---:|---:|---:|")
        for g in sorted(tab[(n, None)]):
            a, b = tab[(n, chosen)][g], tab[(n, None)][g]
            print(f"| {g} | {a:.3f} | {b:.3f} | {a - b:+.3f} |")
        a, b = np.mean(list(tab[(n, chosen)].values())), np.mean(list(tab[(n, None)].values()))
        print(f"| **all** | **{a:.4f}** | {b:.4f} | {a - b:+.4f} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--collect", metavar="SOURCE", help="'psb' or a procedural corpus folder")
    ap.add_argument("--out", type=Path)
    ap.add_argument("--coarse-faces", type=int, default=4000)
    ap.add_argument("--no-graphcut", action="store_true", help="judge the merged labels before the graph cut")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--report", nargs="+", type=Path, help="pickles: the PSB's, the fitted corpus's, then others")
    ap.add_argument("--criterion", choices=["least", "mean"], default="least")
    a = ap.parse_args()
    if a.collect:
        collect(a.collect, a.out, a.coarse_faces, not a.no_graphcut, a.workers)
    if a.report:
        report(a.report, a.criterion)


if __name__ == "__main__":
    main()
