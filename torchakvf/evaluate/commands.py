"""``torchakvf eval`` and ``torchakvf bench``: the benchmark evaluation and throughput bench
from the command line.

::

    torchakvf eval --psb ../shared/psb --out eval/            # whole benchmark, by-segmentation
    torchakvf eval --psb DIR --categories Human,Octopus --protocol by-model --out eval/
    torchakvf eval --per-category 2 -k auto --out eval_auto/
"""
from __future__ import annotations

import os
from pathlib import Path

from ..errors import TorchAKVFError
from ..mesh.coarse import DEFAULT_COARSE_FACES
from ..parts.engine import METHODS
from ..pipeline.commands import _device as parse_device
from ..pipeline.commands import add_graph_cut_argument, add_solver_argument
from ..pipeline.commands import _int as parse_int
from ..pipeline.parallel import default_workers
from .bench import DEFAULT_BASELINE_EVERY

__all__ = ["add_eval_command", "add_bench_command", "run_eval", "run_bench_command",
           "default_psb_arg"]


def default_psb_arg() -> str:
    """$TORCHAKVF_PSB, else <repo>/../shared/psb (whether or not it exists)."""
    env = os.environ.get("TORCHAKVF_PSB")
    if env:
        return env
    return str(Path(__file__).resolve().parents[2].parent / "shared" / "psb")


def _positive_int(text: str) -> int:
    import argparse

    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {v}")
    return v


def _register(subparsers, name: str, summary: str, description: str, add_arguments, run) -> None:
    p = subparsers.add_parser(name, help=summary, description=description)
    add_arguments(p)
    p.set_defaults(func=run)


def add_eval_command(subparsers) -> None:
    """Register ``eval`` on an argparse ``add_subparsers()`` object."""
    _register(subparsers, "eval", "evaluate on the Princeton Segmentation Benchmark (resumable)",
              "Segment PSB meshes, score them against the human segmentations and write "
              "pred/<id>/<id>_k<k>.seg, scores.csv, summary.md and rand_index.png to --out. "
              "Re-running with the same --out skips predictions already written. Exits 1 when a "
              "mesh failed or an input file was left out (each is listed).",
              add_eval_arguments, run_eval)


def add_eval_arguments(p) -> None:
    """The options of ``torchakvf eval``."""
    from .harness import DEFAULT_K_NO_GT, METRIC_GROUPS, PROTOCOLS

    p.add_argument("--psb", default=None, metavar="DIR",
                   help="PSB folder with meshes/ and gt/ (default: $TORCHAKVF_PSB, else "
                        "<repo>/../shared/psb)")
    p.add_argument("--out", default="eval", metavar="DIR", help="output folder (default: eval/)")
    p.add_argument("--categories", default=None, metavar="A,B",
                   help="comma-separated category names (default: all)")
    p.add_argument("--protocol", default="by-segmentation", choices=PROTOCOLS,
                   help="by-segmentation: k = each human's segment count, compared with that "
                        "human only (default); by-model: k = the most common human count")
    p.add_argument("-k", dest="k", default=None, choices=["auto"],
                   help="'auto': choose the number of parts per mesh (merge costs: stop where the cheapest merge is expensive); one "
                        "prediction per mesh, compared with every human (--protocol is ignored)")
    p.add_argument("--k-range", default="2,10", metavar="LO,HI",
                   help="k's tried with -k auto (default 2,10)")
    p.add_argument("--per-category", type=_positive_int, default=None, metavar="N",
                   help="only the first N meshes of each category (quick runs)")
    p.add_argument("--ids", default=None, metavar="LIST", help="mesh ids, e.g. 1,5,21-23")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--remedy", default=None,
                   help="mesh-quality remedy of the Killing operator (default: the package's)")
    p.add_argument("--n-fields", type=_positive_int, default=None,
                   help="fields untangled per mesh (default for method merge 3 max(k, 8) rounded up to a multiple of 8, in [16, 32]; the paper's 2k for paper)")
    p.add_argument("--metrics", default=",".join(METRIC_GROUPS), metavar="LIST",
                   help=f"metric groups to compute (default: {','.join(METRIC_GROUPS)})")
    p.add_argument("--boundary", default=None, choices=["isoline", "faces"],
                   help="part boundaries (default: segment's)")
    p.add_argument("--min-part-fraction", type=float, default=None,
                   help="pieces below this fraction of the area are merged (default: segment's)")
    p.add_argument("--coarse-faces", type=int, default=None, metavar="N",
                   help="solve on meshes decimated to about N faces, cut the parts on the "
                        "originals (default 4000, measured on the PSB; 0: full resolution)")
    p.add_argument("--workers", type=_positive_int, default=None, metavar="W",
                   help="processes predicting side by side, one thread each (default: one per "
                        "CPU core, at most 8)")
    p.add_argument("--batch-faces", type=_positive_int, default=None,
                   help="faces per batch, meshes sorted by size (default 20000: on CPU about one "
                        "PSB mesh a batch, measured fastest)")
    p.add_argument("--default-k", type=_positive_int, default=DEFAULT_K_NO_GT,
                   help=f"parts for meshes without human segmentations (default {DEFAULT_K_NO_GT})")
    add_solver_argument(p, default=None)
    add_graph_cut_argument(p)
    p.add_argument("--method", default=None, choices=list(METHODS),
                   help="segmentation method: merge (default: over-segment, then merge adjacent "
                        "parts by symmetry and concavity) or paper (Solomon et al. 2011)")
    p.add_argument("--device", default="cpu",
                   help="torch device of the predictions, e.g. cpu or cuda (default cpu; one "
                        "worker on a GPU)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def run_eval(args) -> int:
    from .harness import evaluate_psb
    from .psb import CATEGORIES

    psb_root = Path(args.psb or default_psb_arg())
    if not (psb_root / "meshes").is_dir():
        raise TorchAKVFError(f"no PSB data at {psb_root} (expected meshes/N.off.gz and "
                             f"gt/N/N_k.seg.gz); pass --psb DIR or set TORCHAKVF_PSB")
    categories = None
    if args.categories:
        categories = [c.strip() for c in args.categories.split(",") if c.strip()]
        known = {c.lower() for c in CATEGORIES}
        bad = [c for c in categories if c.lower() not in known]
        if bad:
            raise TorchAKVFError(f"unknown category {', '.join(map(repr, bad))}; choose from "
                                 f"{', '.join(CATEGORIES)}")
    k_range = None
    if args.k == "auto":
        try:
            k_range = tuple(int(v) for v in args.k_range.split(","))
        except ValueError:
            raise TorchAKVFError(f"--k-range must be LO,HI, got {args.k_range!r}") from None
    seg_kwargs = {}
    if args.boundary is not None:
        seg_kwargs["boundary"] = args.boundary
    if args.min_part_fraction is not None:
        seg_kwargs["min_part_fraction"] = args.min_part_fraction
    coarse = DEFAULT_COARSE_FACES if args.coarse_faces is None else args.coarse_faces
    if coarse < 0:
        raise TorchAKVFError(f"--coarse-faces must be >= 0, got {coarse}")
    if coarse:
        seg_kwargs["coarse_faces"] = coarse
    for name in ("solver", "method"):   # only when given: a folder's settings stay comparable
        if getattr(args, name) is not None:
            seg_kwargs[name] = getattr(args, name)
    if args.graph_cut == "off":
        seg_kwargs["graphcut"] = None
    device = parse_device(args.device)
    summary = evaluate_psb(psb_root, args.out, categories=categories, protocol=args.protocol,
                           ids=args.ids, per_category=args.per_category, seed=args.seed,
                           remedy=args.remedy, n_fields=args.n_fields, batch_faces=args.batch_faces,
                           k_mode=args.k, k_range=k_range, progress=not args.quiet,
                           metrics=args.metrics, default_k=args.default_k, device=device,
                           workers=args.workers or default_workers(device), **seg_kwargs)
    n_ok = sum(r.scored for r in summary.rows)
    n_failed = sum(r.status.startswith("failed") for r in summary.rows)
    print(f"{n_ok} meshes scored, {n_failed} failed, overall 1-RI {summary.rand_index_error:.4f}; "
          f"wrote {Path(args.out) / 'summary.md'}, scores.csv, rand_index.png")
    for r in summary.rows:
        if r.status.startswith("failed"):
            print(f"  failed: mesh {r.mesh_id}: {r.status[len('failed: '):]}")
    for line in summary.problems:
        print(f"  problem: {line}")
    return 1 if summary.failed else 0


# ---- bench ----------------------------------------------------------------------------------

def add_bench_command(subparsers) -> None:
    """Register ``bench`` on an argparse ``add_subparsers()`` object."""
    _register(subparsers, "bench", "throughput on the PSB: batched vs one mesh at a time vs scipy",
              "Segment PSB meshes at every protocol k and write report.md and report.json to "
              "--out: meshes/s, faces/s, seconds per stage, peak memory, and baseline/torchakvf "
              "time ratios measured in the same run.", add_bench_arguments, run_bench_command)


def add_bench_arguments(p) -> None:
    """The options of ``torchakvf bench`` (values are checked in :func:`run_bench_command`)."""
    p.add_argument("--psb", default=None, metavar="DIR",
                   help="PSB folder with meshes/ and gt/ (default: $TORCHAKVF_PSB, else "
                        "<repo>/../shared/psb)")
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
    add_graph_cut_argument(p)
    p.add_argument("--method", default=None, choices=list(METHODS),
                   help="segmentation method: merge (default: over-segment, then merge adjacent "
                        "parts by symmetry and concavity) or paper (Solomon et al. 2011)")


def run_bench_command(args) -> int:
    """``torchakvf bench``: 0 when every mesh finished in every torchakvf run and no input was
    left out, else 1."""
    from .bench import run_bench
    from .bench_report import summary_lines
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
    segment_kwargs = {"coarse_faces": coarse} if coarse else {}
    for name in ("solver", "method"):
        if getattr(args, name) is not None:
            segment_kwargs[name] = getattr(args, name)
    if args.graph_cut == "off":
        segment_kwargs["graphcut"] = None
    report = run_bench(Path(args.psb or default_psb_arg()), out, limit=limit, baseline_every=every,
                       device=device, seed=seed, categories=categories, batch_faces=batch_faces,
                       segment_kwargs=segment_kwargs, workers=workers, budgets=args.budgets,
                       repeats=parse_int(args.repeats, "--repeats", 1),
                       options={k: v for k, v in vars(args).items() if k not in ("func", "command")})
    for line in summary_lines(report, out):
        print(line)
    failed = any(r.get("failed") for r in report["runs"].values() if r.get("kind") == "torchakvf")
    return 1 if failed or report.get("problems") else 0
