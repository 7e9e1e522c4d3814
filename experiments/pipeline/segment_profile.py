"""Where the time of a segmentation goes, by stage, for two versions of the code side by side.

One run profiles (cProfile on process CPU time, one thread) the work of each mesh with the code
imported, and writes each stage's seconds as JSON:

* ``--coarse-faces 0 --ks 5``: ``ta.segment(batch, k=5, seed=0)`` at full resolution;
* ``--coarse-faces 4000 --ks 3,4,5,7``: the eval's path (the mesh loaded, cleaned and
  decimated to 4000 faces, ``solve_akvfs`` for the eval's 36 AKVFs, ``segment_rounds`` over k's).

Stages are the cumulative times of the functions that do them (the same names in both versions,
or the version's own name where one moved): operator (assembly, and the remedy decision under
"auto"), decision (the remedy decision alone), interior factor, Krylov, AKVFs in all
(``solve_akvfs``), load + clean + decimate + surface map (``MeshBatch.from_meshes``), untangling,
k-means, cutting the parts (``cut_parts``), and the total. ``--report`` interleaves: it runs the
script for each ``--code`` directory in turn (``--rounds`` times, alternating which goes first),
keeps each stage's best round and writes a table.

    python3 experiments/pipeline/segment_profile.py --code /path/to/old /path/to/new --rounds 2 \\
        --report experiments/results/segment_profile.md
"""
from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import subprocess
import sys
import time
from pathlib import Path

STAGES = {
    "operator": [("operators/killing.py", "killing_operator"), ("solvers/remedy.py", "auto_operator")],
    "decision": [("remedy_choice.py", "choose_remedies"), ("solvers/remedy.py", "check_paper_operator")],
    "interior factor": [("solvers/factor.py", "interior_factor")],
    "Krylov": [("solvers/krylov.py", "block_krylov")],
    "AKVFs in all": [("parts/solve.py", "solve_akvfs")],
    "load + clean + decimate + map": [("mesh/batch.py", "from_meshes"), ("io/load.py", "load_mesh")],
    "untangling": [("parts/rounds.py", "_round_untangled")],
    "k-means": [("parts/rounds.py", "_round_kmeans")],
    "cutting the parts": [("parts/cut.py", "cut_parts")],
}
PROFILE = [("full resolution, ta.segment(k=5)", 0, "5", "1,21,121,181,201,301"),
           ("eval path, 4000 faces, k = 3,4,5,7", 4000, "3,4,5,7", "2,22,62,122,162,202")]


def profile(ids: list[int], coarse: int, ks: list[int], psb: Path) -> dict:
    """{stage: CPU seconds} of the work on ``ids`` with the code imported."""
    import torch

    import torchakvf as ta
    from torchakvf.io import load_mesh
    from torchakvf.options import SegmentOptions
    from torchakvf.parts.rounds import segment_rounds
    from torchakvf.parts.solve import solve_akvfs

    torch.set_num_threads(1)
    opts = SegmentOptions()
    path = lambda i: psb / "meshes" / f"{i}.off.gz"                       # noqa: E731
    full = {i: load_mesh(path(i)) for i in ids} if not coarse else {}

    def run(i):
        if not coarse:
            ta.segment(ta.MeshBatch.from_meshes([full[i]]), k=ks[0], seed=0)
            return
        mb = ta.MeshBatch.from_meshes([load_mesh(path(i))], coarse_faces=coarse)
        fields, _ = solve_akvfs(mb, 36, opts)
        for _ in segment_rounds(fields, [ks], opts):
            pass

    run(ids[0])                                                   # warm-up, untimed
    prof = cProfile.Profile(time.process_time)
    t0 = time.process_time()
    prof.enable()
    for i in ids:
        run(i)
    prof.disable()
    total = time.process_time() - t0
    stats = pstats.Stats(prof).stats
    out = {}
    for stage, names in STAGES.items():
        out[stage] = sum(ct for (file, _, func), (_, _, _, ct, _) in stats.items()
                         if any(file.endswith(f) and func == fn for f, fn in names))
    out["total"] = total
    out["code"] = os.path.dirname(os.path.dirname(ta.__file__))
    return out


def report(codes: list[Path], rounds: int, psb: Path, out: Path) -> None:
    best: dict = {}
    for label, coarse, ks, ids in PROFILE:
        for r in range(rounds):
            for code in (codes if r % 2 == 0 else codes[::-1]):
                run = subprocess.run([sys.executable, __file__, "--ids", ids, "--coarse-faces", str(coarse),
                                      "--ks", ks, "--psb", str(psb)], capture_output=True, text=True, check=True,
                                     env={**os.environ, "PYTHONPATH": str(code), "OMP_NUM_THREADS": "1"})
                got = json.loads(run.stdout.strip().splitlines()[-1])
                key = (label, str(code))
                best[key] = {s: min(best.get(key, {}).get(s, float("inf")), v) for s, v in got.items()
                             if s != "code"}
                print(label, code, got, flush=True)
    names = [c.name or str(c) for c in codes]
    lines = ["# Where a segmentation's time goes, by stage: two versions side by side", "",
             f"- versions: {', '.join(f'`{c}`' for c in codes)}; {rounds} rounds, alternating which goes first, "
             "each stage's best round; process CPU seconds (cProfile on process time, one thread), summed over "
             "the meshes (`experiments/pipeline/segment_profile.py`)",
             "- a stage is the cumulative time of the functions doing it; 'operator' includes the remedy "
             "decision, 'AKVFs in all' the operator, factors and solve, and the stages nest, so they do not add up", ""]
    for label, coarse, ks, ids in PROFILE:
        lines += [f"## {label}: PSB {ids}", "",
                  "| stage | " + " | ".join(names) + " | " + " / ".join(names) + " |",
                  "|---|" + "---:|" * (len(codes) + 1)]
        for stage in list(STAGES) + ["total"]:
            vals = [best[(label, str(c))][stage] for c in codes]
            ratio = f"{vals[0] / vals[-1]:.2f}" if vals[-1] > 0 else "-"
            lines.append(f"| {stage} | " + " | ".join(f"{v:.2f}" for v in vals) + f" | {ratio} |")
        lines.append("")
    out.write_text("\n".join(lines))
    print("\n".join(lines))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--psb", type=Path, default=Path(os.environ.get("TORCHAKVF_PSB", "../shared/psb")))
    p.add_argument("--ids", help="profile these meshes with the code imported (prints JSON)")
    p.add_argument("--coarse-faces", type=int, default=0)
    p.add_argument("--ks", default="5")
    p.add_argument("--code", type=Path, nargs="+", help="checkouts to compare (with --report)")
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--report", type=Path)
    a = p.parse_args()
    if a.report:
        report(a.code, a.rounds, a.psb.resolve(), a.report)
    else:
        print(json.dumps(profile([int(i) for i in a.ids.split(",")], a.coarse_faces,
                                 [int(k) for k in a.ks.split(",")], a.psb)))


if __name__ == "__main__":
    main()
