"""``torchakvf bench`` from the command line: its options and the run."""
from __future__ import annotations

from pathlib import Path

from ..errors import TorchAKVFError
from ..evaluate.commands import psb_folder
from ..mesh.coarse import DEFAULT_COARSE_FACES
from ..options import METHODS
from ..pipeline.arguments import (
    add_batched_argument,
    add_graph_cut_argument,
    add_method_argument,
    add_second_merge_argument,
    add_sheet_rule_argument,
    add_solver_argument,
    merge_overrides,
    parse_device,
    parse_int,
    register_command,
)
from .run import DEFAULT_BASELINE_EVERY

__all__ = ["add_bench_command", "add_bench_arguments", "run_bench_command"]


def add_bench_command(subparsers) -> None:
    """Register ``bench`` on an argparse ``add_subparsers()`` object."""
    register_command(subparsers, "bench", "throughput on the PSB: batched vs one mesh at a time vs scipy",
              "Segment PSB meshes at every protocol k and write report.md and report.json to "
              "--out: meshes/s, faces/s, seconds per stage, peak memory, and baseline/torchakvf "
              "time ratios measured in the same run.", add_bench_arguments, run_bench_command)


def add_bench_arguments(p) -> None:
    """The options of ``torchakvf bench`` (values are checked in :func:`run_bench_command`)."""
    p.add_argument("--psb", default=None, metavar="DIR",
                   help="PSB folder with meshes/ and gt/ (default: $TORCHAKVF_PSB)")
    p.add_argument("--out", default="bench", metavar="DIR",
                   help="output folder for report.md and report.json (default: bench/)")
    p.add_argument("--limit", default=None, metavar="N", help="only the first N meshes by id (default: all)")
    p.add_argument("--baseline-every", default=str(DEFAULT_BASELINE_EVERY), metavar="M",
                   help="run the one-at-a-time and scipy baselines on every M-th mesh of the "
                        f"selection (default {DEFAULT_BASELINE_EVERY}; 0: none)")
    p.add_argument("--device", default="cpu", help="torch device, e.g. cpu or cuda (default cpu)")
    p.add_argument("--budgets", default=None, metavar="B1,B2",
                   help="also time batched against one mesh at a time at these face budgets "
                        "(e.g. 4000,20000,80000), on the baseline subset (every mesh with "
                        "--baseline-every 0); default: no sweep")
    p.add_argument("--repeats", default="1", metavar="R",
                   help="with --budgets: run the sweep R times, interleaved, and time each run by "
                        "its fastest repetition (default 1)")
    p.add_argument("--seed", default="0", help="random seed (default 0)")
    p.add_argument("--categories", default=None, metavar="A,B",
                   help="comma-separated PSB category names (default: all)")
    p.add_argument("--batch-faces", default=None, metavar="N",
                   help="face budget per batch of the batched runs (default: the harness's, "
                        "as torchakvf eval)")
    p.add_argument("--coarse-faces", default=None, metavar="N",
                   help=f"solve on meshes decimated to about N faces, as torchakvf eval does "
                        f"(default {DEFAULT_COARSE_FACES}; 0: full resolution)")
    p.add_argument("--workers", default=None, metavar="W",
                   help="processes of the torchakvf runs, one thread each (default: one per CPU "
                        "core on CPU, at most 8; 1 on a GPU)")
    add_solver_argument(p, default=None)
    add_batched_argument(p)
    add_graph_cut_argument(p)
    add_second_merge_argument(p)
    add_sheet_rule_argument(p)
    add_method_argument(p, None, METHODS)


def run_bench_command(args) -> int:
    """``torchakvf bench``: 0 when every mesh finished in every torchakvf run and no input was
    left out, else 1."""
    from ..evaluate.settings import eval_segment_options
    from .report import summary_lines
    from .run import BenchSettings, run_bench

    limit = parse_int(args.limit, "--limit", 1) if args.limit is not None else None
    every = parse_int(args.baseline_every, "--baseline-every", 0)
    seed = parse_int(args.seed, "--seed", 0)
    batch_faces = parse_int(args.batch_faces, "--batch-faces", 1) if args.batch_faces is not None else None
    coarse = DEFAULT_COARSE_FACES if args.coarse_faces is None else parse_int(args.coarse_faces, "--coarse-faces", 0)
    workers = parse_int(args.workers, "--workers", 1) if args.workers is not None else None
    categories = None
    if args.categories is not None:
        categories = [c.strip() for c in args.categories.split(",") if c.strip()]
        if not categories:
            raise TorchAKVFError("--categories: name at least one PSB category")
    device = parse_device(args.device)
    out = Path(args.out)
    given = {"seed": seed, "solver": args.solver, "method": args.method, "batched": args.batched}
    given = {k: v for k, v in given.items() if v is not None}
    if args.graph_cut == "off":
        given["graphcut"] = None
    given.update(merge_overrides(args))
    settings = BenchSettings(limit=limit, baseline_every=every, categories=categories,
                             coarse_faces=coarse or None, batch_faces=batch_faces, workers=workers,
                             device=device, budgets=args.budgets,
                             repeats=parse_int(args.repeats, "--repeats", 1))
    report = run_bench(psb_folder(args.psb), out, eval_segment_options(None, given), settings,
                       command_line={k: v for k, v in vars(args).items() if k not in ("func", "command")})
    for line in summary_lines(report, out):
        print(line)
    failed = any(r.get("failed") for r in report["runs"].values() if r.get("kind") == "torchakvf")
    return 1 if failed or report.get("problems") else 0
