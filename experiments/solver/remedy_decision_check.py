"""The remedy decision (``remedy="auto"``) per mesh, to compare two versions of the code: every
built-in shape and every PSB mesh, decimated to 4000 faces as eval solves them and at full
resolution. Run it once per version (each writes a CSV with the code it imported), then compare:

    PYTHONPATH=/path/to/old/checkout nice python3 experiments/solver/remedy_decision_check.py --out /tmp/before.csv
    PYTHONPATH=$PWD nice python3 experiments/solver/remedy_decision_check.py --out /tmp/after.csv
    python3 experiments/solver/remedy_decision_check.py --compare /tmp/before.csv /tmp/after.csv \\
        --report experiments/results/remedy_decision_check.md    # and .csv: every mesh

Each row: the mesh, its resolution, its edges, the remedy "auto" gave it and the process CPU
seconds of building its operator under "auto" (one thread; the machine's load moves them, the
ratio of the two runs' totals is the figure). A version that decides inside the solvers
(``torchakvf.solvers.remedy.auto_operator``) is called there, an older one through
``killing_operator(remedy="auto")``. Each row also carries the decision of the rule itself, computed here
independently of either version's shortcuts: a whole CHOLMOD factorization of the paper's
R + S1 (σ = -1) through cholespy, "smooth" where it fails.
"""
from __future__ import annotations

import argparse
import csv
import os
import time
from pathlib import Path

import torch

import torchakvf as ta
from torchakvf import shapes
from torchakvf.evaluate.psb import category_of, find_psb_meshes
from torchakvf.operators.killing import killing_operator

BUILTIN = {**shapes.BUILTIN_SHAPES, "ellipsoid": shapes.ellipsoid, "icosphere": shapes.icosphere,
           "torus": shapes.torus, "capped_cylinder": shapes.capped_cylinder, "table": shapes.table,
           "mug": shapes.mug, "hemisphere": shapes.hemisphere, "square_patch": shapes.square_patch,
           "flat_disk": shapes.flat_disk}


def auto_remedies(batch) -> list[str]:
    """The remedies "auto" gives the batch's meshes, with the version of the code imported."""
    try:
        from torchakvf.solvers.remedy import auto_operator
    except ImportError:
        return killing_operator(batch, remedy="auto").remedies
    return auto_operator(batch)[0].remedies


def whole_factor_rule(batch) -> str:
    """The rule, by cholespy's own whole factorization (no shortcut of either version)."""
    import cholespy

    system = killing_operator(batch, remedy="none")
    idx, vals = system.stiffness.indices(), system.stiffness.values()
    lower = idx[0] >= idx[1]
    n = len(system.mass)
    diag = torch.arange(n)
    r = torch.cat([idx[0][lower], diag]).to(torch.int32)
    c = torch.cat([idx[1][lower], diag]).to(torch.int32)
    x = torch.cat([vals[lower], system.mass.double()])          # R + S1: σ = -1
    try:
        cholespy.CholeskySolverD(n, r, c, x, cholespy.MatrixType.COO)
    except ValueError:
        return "smooth"
    return "none"


def items(psb: Path):
    for name, fn in BUILTIN.items():
        s = fn()
        yield f"builtin:{name}", "builtin", "own", ta.Mesh(s.vertices, s.faces, name=name), None
    entries = sorted(find_psb_meshes(psb), key=lambda e: e.mesh_id)
    for coarse in (4000, None):
        for e in entries:
            yield str(e.mesh_id), category_of(e.mesh_id), "full" if coarse is None else str(coarse), e.mesh_path, coarse


def run(psb: Path, out: Path) -> None:
    torch.set_num_threads(1)
    rows = []
    for name, category, resolution, src, coarse in items(psb):
        mesh = src if isinstance(src, ta.Mesh) else ta.load_mesh(src)
        batch = ta.MeshBatch.from_meshes([mesh], coarse_faces=coarse)
        t0 = time.process_time()
        remedy = auto_remedies(batch)[0]
        seconds = time.process_time() - t0
        rows.append(dict(mesh=name, category=category, resolution=resolution, edges=len(batch.edges),
                         remedy=remedy, rule=whole_factor_rule(batch), seconds=f"{seconds:.4f}",
                         code=os.path.dirname(os.path.dirname(ta.__file__))))
        print(rows[-1], flush=True)
    with open(out, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader(), w.writerows(rows)


def compare(before: Path, after: Path, report: Path) -> None:
    read = lambda p: {(r["mesh"], r["resolution"]): r for r in csv.DictReader(open(p))}  # noqa: E731
    a, b = read(before), read(after)
    keys = list(a)
    missing = [k for k in keys if k not in b]
    differ = [k for k in keys if k in b and a[k]["remedy"] != b[k]["remedy"]]
    off_rule = [k for k in keys if k in b and b[k]["remedy"] != b[k]["rule"]]
    groups = {}
    for k in keys:
        res = "built-in shapes" if a[k]["category"] == "builtin" else (
            "PSB at full resolution" if k[1] == "full" else f"PSB decimated to {k[1]} faces")
        groups.setdefault(res, []).append(k)
    lines = ["# The remedy decision per mesh: before and after", "",
             f"- before: the code at `{a[keys[0]]['code']}`; after: the code at `{b[keys[0]]['code']}` "
             "(one process each, one thread, on a shared 2-core machine)",
             f"- every mesh's decision, before, after and by the rule: [{report.with_suffix('.csv').name}]"
             f"({report.with_suffix('.csv').name})",
             "- rule: the decision recomputed in the after run by a whole cholespy factorization of the paper's "
             "R + S1 (σ = -1), no shortcut of either version",
             f"- meshes: {len(keys)}; missing after: {len(missing)}; **different decisions: {len(differ)}**; "
             f"after differing from the rule: {len(off_rule)}", "",
             "| meshes | count | smooth before | smooth after | differ | given none (after) | CPU s before | "
             "CPU s after | before / after |", "|---|---:|---:|---:|---:|---|---:|---:|---:|"]
    for res, ks in groups.items():
        sa = sum(float(a[k]["seconds"]) for k in ks)
        sb = sum(float(b[k]["seconds"]) for k in ks if k in b)
        none = [k[0].removeprefix("builtin:") for k in ks if k in b and b[k]["remedy"] == "none"]
        lines.append(f"| {res} | {len(ks)} | {sum(a[k]['remedy'] == 'smooth' for k in ks)} | "
                     f"{sum(b[k]['remedy'] == 'smooth' for k in ks if k in b)} | "
                     f"{sum(k in differ for k in ks)} | {', '.join(none)} | {sa:.1f} | {sb:.1f} | {sa / sb:.2f} |")
    lines += ["", "CPU s: building each mesh's operator under \"auto\" (assembly and decision), summed; the two "
              "runs ran at different times on a shared machine, so the ratio is indicative only (the "
              "benchmarks measure the same change interleaved).", ""]
    if differ or missing or off_rule:
        lines += ["| mesh | resolution | before | after | rule |", "|---|---|---|---|---|"]
        lines += [f"| {k[0]} | {k[1]} | {a[k]['remedy']} | {b[k]['remedy'] if k in b else '-'} | "
                  f"{b[k]['rule'] if k in b else '-'} |" for k in keys if k in differ or k in missing or k in off_rule]
    report.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    # every mesh's decision, before and after, beside the report
    with open(report.with_suffix(".csv"), "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["mesh", "category", "resolution", "edges", "before", "after", "rule"])
        w.writerows([k[0], a[k]["category"], k[1], a[k]["edges"], a[k]["remedy"],
                     b[k]["remedy"] if k in b else "", b[k]["rule"] if k in b else ""] for k in keys)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--psb", type=Path, default=Path(os.environ.get("TORCHAKVF_PSB", "../shared/psb")))
    p.add_argument("--out", type=Path, help="write this version's decisions here (CSV)")
    p.add_argument("--compare", type=Path, nargs=2, metavar=("BEFORE", "AFTER"))
    p.add_argument("--report", type=Path, default=Path("experiments/results/remedy_decision_check.md"))
    a = p.parse_args()
    if a.compare:
        compare(*a.compare, a.report)
    elif a.out:
        run(a.psb, a.out)
    else:
        p.error("pass --out CSV (decide with the code imported) or --compare BEFORE AFTER")


if __name__ == "__main__":
    main()
