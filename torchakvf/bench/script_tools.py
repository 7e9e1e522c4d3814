"""What the scripts in ``benchmarks/`` and ``experiments/`` share: the fastest of repeated
calls, writing a report, the PSB check of a one-thread AKVF benchmark, and comparing two AKVF
results. A package module, so a script imports it wherever it lives (no ``sys.path`` edits)."""
from __future__ import annotations

import time
import warnings
from pathlib import Path


def psb_parser(description: str, ids, out: Path):
    """The full-resolution benchmarks' common command line: --psb, --ids, --n, --repeat, --out."""
    import argparse

    from torchakvf.evaluate.psb import default_psb_root

    p = argparse.ArgumentParser(description=description)
    root = default_psb_root()
    p.add_argument("--psb", type=Path, default=root, required=root is None,
                   help="the PSB folder (default: $TORCHAKVF_PSB)")
    p.add_argument("--ids", type=int, nargs="+", default=list(ids))
    p.add_argument("--n", type=int, default=32)
    p.add_argument("--repeat", type=int, default=2, help="rounds, best kept (default 2)")
    p.add_argument("--out", type=Path, default=out)
    return p


def best_of(fn, repeat: int, clock=time.perf_counter):
    """(seconds of the fastest of ``repeat`` calls of ``fn()`` on ``clock``, the last call's
    result). ``clock=time.process_time`` times this process's CPU alone, which the other jobs
    of a shared machine disturb less than wall time."""
    best, out = float("inf"), None
    for _ in range(max(int(repeat), 1)):
        t = clock()
        out = fn()
        best = min(best, clock() - t)
    return best, out


def write_report(text: str, out: Path | str | None) -> None:
    """Print a report and, given a path, write it there (its folder made if missing)."""
    print(text)
    if out:
        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text)


def one_thread_on_psb(parser, args) -> None:
    """Stop with a usage error unless ``args.psb`` holds the PSB meshes; then one torch thread
    (the AKVF benchmarks time process CPU time, one thread a side) and no warnings (a mesh that
    does not converge is reported in the table, not on stderr)."""
    import torch

    if args.psb is None or not (args.psb / "meshes").is_dir():
        parser.error(f"no PSB meshes at {args.psb}: pass --psb or set TORCHAKVF_PSB")
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")


def akvf_agreement(a, b) -> tuple[float, float]:
    """(largest |λ_a − λ_b| / max(|λ_a|, 1), sine of the largest principal angle between the
    spans of the two results' forms) of two :class:`~torchakvf.AKVFResult` of the same mesh. The
    angle is Euclidean: small where the two agree as subspaces, even when their vectors differ by
    a rotation among close eigenvalues."""
    import torch

    dlam = float(((a.eigenvalues - b.eigenvalues).abs() / a.eigenvalues.abs().clamp(min=1)).max())
    qa, qb = torch.linalg.qr(a.forms)[0], torch.linalg.qr(b.forms)[0]
    span = float(torch.linalg.svdvals(qa.T @ qb).min().clamp(max=1).arccos().sin())
    return dlam, span
