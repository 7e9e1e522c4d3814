"""`torchakvf eval` of two or more versions of the code, interleaved, on the same meshes: the
time each takes (wall and CPU of the whole process tree) and whether their predictions are the
same files byte for byte.

Each version is a checkout (``--code DIR``, e.g. an export made with ``git archive``); every round
runs ``eval`` once per version, the order alternating between rounds, each into a fresh output
folder with the version's own code on ``PYTHONPATH``. The predictions (``pred/**/*.seg``) of the
first round are compared between the versions named by ``--same`` (all of them by default).

    git archive ad1213a | tar -x -C /tmp/before_merge
    python benchmarks/eval_ab.py --code /tmp/before_merge /path/to/main . --rounds 2 \\
        --ids 1,2,21,22,41,42 --report benchmarks/results/eval_ab.md
"""
from __future__ import annotations

import argparse
import filecmp
import os
import platform
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def run_eval(code: Path, out: Path, args) -> tuple[float, float]:
    """(wall s, CPU s of the process and its workers) of one ``eval`` with ``code``'s package."""
    if out.exists():
        shutil.rmtree(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-c", "from torchakvf.cli import main; main()", "eval", "--psb", str(args.psb),
           "--out", str(out), "--coarse-faces", str(args.coarse_faces), "--workers", str(args.workers), "--quiet"]
    if args.ids:
        cmd += ["--ids", args.ids]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=out.parent, env={**os.environ, "PYTHONPATH": str(code), "OMP_NUM_THREADS": "1"},
                   stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def same_predictions(a: Path, b: Path) -> tuple[int, list[str]]:
    """(prediction files compared, those that differ or are missing in b)."""
    files = sorted(p.relative_to(a) for p in (a / "pred").rglob("*.seg"))
    differ = [str(f) for f in files if not (b / f).exists() or not filecmp.cmp(a / f, b / f, shallow=False)]
    extra = [str(p.relative_to(b)) for p in (b / "pred").rglob("*.seg") if not (a / p.relative_to(b)).exists()]
    return len(files), differ + extra


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--code", type=Path, nargs="+", required=True, help="checkouts to compare")
    p.add_argument("--psb", type=Path, default=Path(os.environ.get("TORCHAKVF_PSB", REPO.parent / "shared" / "psb")))
    p.add_argument("--ids", default=None, help="mesh ids (default: the whole PSB)")
    p.add_argument("--coarse-faces", type=int, default=4000)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--same", type=int, nargs="*", default=None,
                   help="indices into --code whose predictions must agree (default: all)")
    p.add_argument("--work", type=Path, default=Path("/tmp/eval_ab"))
    p.add_argument("--report", type=Path, default=REPO / "benchmarks" / "results" / "eval_ab.md")
    a = p.parse_args(argv)
    codes = [c.resolve() for c in a.code]
    a.psb = a.psb.resolve()
    times = {c: [] for c in codes}
    for r in range(a.rounds):
        for i in (range(len(codes)) if r % 2 == 0 else reversed(range(len(codes)))):
            wall, cpu = run_eval(codes[i], a.work / f"v{i}_r{r}", a)
            times[codes[i]].append((wall, cpu))
            print(f"round {r} {codes[i]}: wall {wall:.1f} s, cpu {cpu:.1f} s", flush=True)
    same = list(range(len(codes))) if a.same is None else a.same
    checks = [(i, j, *same_predictions(a.work / f"v{i}_r0", a.work / f"v{j}_r0"))
              for i in same for j in same if i < j]
    base = codes[0]
    lines = ["# `torchakvf eval` A/B: time and predictions", "",
             f"- {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; python {platform.python_version()}, "
             f"{os.cpu_count()} CPUs; meshes: {a.ids or 'the whole PSB'}; `--coarse-faces {a.coarse_faces} "
             f"--workers {a.workers}`, OMP_NUM_THREADS=1; {a.rounds} rounds, the order alternating "
             "(`benchmarks/eval_ab.py`)",
             "- CPU s: user + system time of eval and its workers; wall s moves with the machine's other load", "",
             "| version | " + " | ".join(f"round {r} wall s / CPU s" for r in range(a.rounds))
             + " | CPU s, sum | CPU / first version's |", "|---|" + "---:|" * (a.rounds + 2)]
    for c in codes:
        cpu = sum(t[1] for t in times[c])
        lines.append(f"| `{c}` | " + " | ".join(f"{w:.1f} / {u:.1f}" for w, u in times[c])
                     + f" | {cpu:.1f} | {cpu / sum(t[1] for t in times[base]):.3f} |")
    lines += ["", "Predictions (first round), byte for byte:", ""]
    for i, j, n, differ in checks:
        lines.append(f"- `{codes[i]}` against `{codes[j]}`: {n} files, **{len(differ)} differ**"
                     + (f" ({', '.join(differ[:10])}{' ...' if len(differ) > 10 else ''})" if differ else ""))
    a.report.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
