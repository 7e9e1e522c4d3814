"""``torchakvf eval``: the benchmark evaluation from the command line.

::

    torchakvf eval --psb DIR --out eval/                      # whole benchmark, by-segmentation
    torchakvf eval --psb DIR --categories Human,Octopus --protocol by-model --out eval/
    torchakvf eval --per-category 2 -k auto --out eval_auto/
"""
from __future__ import annotations

import os
from pathlib import Path

from ..errors import TorchAKVFError
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
    positive_int,
    register_command,
)
from ..pipeline.parallel import default_workers

__all__ = ["add_eval_command", "add_eval_arguments", "run_eval", "default_psb_arg", "psb_folder"]


def default_psb_arg() -> str | None:
    """``$TORCHAKVF_PSB`` (None where it is not set)."""
    from .psb import PSB_ENV

    return os.environ.get(PSB_ENV) or None


def psb_folder(given) -> Path:
    """The PSB folder of a command: ``--psb`` (``given``), else ``$TORCHAKVF_PSB``; one-line
    errors when neither is given or the folder holds no benchmark."""
    root = given or default_psb_arg()
    if not root:
        raise TorchAKVFError("no PSB folder given: pass --psb DIR (the folder with meshes/ and gt/) "
                             "or set TORCHAKVF_PSB")
    root = Path(root)
    if not (root / "meshes").is_dir():
        raise TorchAKVFError(f"no PSB data at {root} (expected meshes/N.off.gz and "
                             f"gt/N/N_k.seg.gz); pass --psb DIR or set TORCHAKVF_PSB")
    return root


def add_eval_command(subparsers) -> None:
    """Register ``eval`` on an argparse ``add_subparsers()`` object."""
    register_command(subparsers, "eval", "evaluate on the Princeton Segmentation Benchmark (resumable)",
              "Segment PSB meshes, score them against the human segmentations and write "
              "pred/<id>/<id>_k<k>.seg, scores.csv, summary.md and rand_index.png to --out. "
              "Re-running with the same --out skips predictions already written. Exits 1 when a "
              "mesh failed or an input file was left out (each is listed).",
              add_eval_arguments, run_eval)


def add_eval_arguments(p) -> None:
    """The options of ``torchakvf eval``."""
    from .harness import DEFAULT_K_NO_GT, METRIC_GROUPS, PROTOCOLS

    p.add_argument("--psb", default=None, metavar="DIR",
                   help="PSB folder with meshes/ and gt/ (default: $TORCHAKVF_PSB)")
    p.add_argument("--out", default="eval", metavar="DIR", help="output folder (default: eval/)")
    p.add_argument("--categories", default=None, metavar="A,B",
                   help="comma-separated category names (default: all)")
    p.add_argument("--protocol", default="by-segmentation", choices=PROTOCOLS,
                   help="by-segmentation: k = each human's segment count, compared with that "
                        "human only (default); by-model: k = the most common human count")
    p.add_argument("-k", dest="k", default=None, choices=["auto"],
                   help="'auto': choose the number of parts per mesh (merge costs: stop where the cheapest merge "
                        "is expensive); one prediction per mesh, compared with every human (--protocol is ignored)")
    p.add_argument("--k-range", default="2,10", metavar="LO,HI",
                   help="k's tried with -k auto (default 2,10)")
    p.add_argument("--per-category", type=positive_int, default=None, metavar="N",
                   help="only the first N meshes of each category (quick runs)")
    p.add_argument("--ids", default=None, metavar="LIST", help="mesh ids, e.g. 1,5,21-23")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--remedy", default=None,
                   help="mesh-quality remedy of the Killing operator (default: the package's)")
    p.add_argument("--n-fields", type=positive_int, default=None,
                   help="fields untangled per mesh (default for method merge 3 max(k, 8) rounded up to a multiple "
                        "of 8, in [16, 32]; the paper's 2k for paper)")
    p.add_argument("--metrics", default=",".join(METRIC_GROUPS), metavar="LIST",
                   help=f"metric groups to compute (default: {','.join(METRIC_GROUPS)})")
    p.add_argument("--boundary", default=None, choices=["isoline", "faces"],
                   help="part boundaries (default: segment's)")
    p.add_argument("--min-part-fraction", type=float, default=None,
                   help="pieces below this fraction of the area are merged (default: segment's)")
    p.add_argument("--coarse-faces", type=int, default=None, metavar="N",
                   help="solve on meshes decimated to about N faces, cut the parts on the "
                        f"originals (default {DEFAULT_COARSE_FACES}; 0: full resolution)")
    p.add_argument("--workers", type=positive_int, default=None, metavar="W",
                   help="processes predicting side by side, one thread each (default: one per "
                        "CPU core, at most 8)")
    p.add_argument("--batch-faces", type=positive_int, default=None,
                   help="faces per batch, meshes sorted by size (default: on CPU one decimated "
                        "mesh a batch, 1000000 on cuda)")
    p.add_argument("--batch-bytes", type=positive_int, default=None, metavar="N",
                   help="with --batched: bytes a batch's padded solver arrays may take (default: "
                        "half the GPU's free memory; 268435456 on the CPU)")
    add_batched_argument(p)
    p.add_argument("--ray-workers", type=int, default=0, metavar="N",
                   help="run the batches on N Ray actors (pip install 'torchakvf[ray]'; with --device "
                        "cuda one GPU each). Default 0: no Ray")
    p.add_argument("--default-k", type=positive_int, default=DEFAULT_K_NO_GT,
                   help=f"parts for meshes without human segmentations (default {DEFAULT_K_NO_GT})")
    add_solver_argument(p, default=None)
    add_graph_cut_argument(p)
    add_second_merge_argument(p)
    add_sheet_rule_argument(p)
    add_method_argument(p, None, METHODS)
    p.add_argument("--device", default="cpu",
                   help="torch device of the predictions, e.g. cpu or cuda (default cpu; one "
                        "worker on a GPU)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def _segment_overrides(args) -> dict:
    """The segmentation options given on the command line (the others keep their defaults)."""
    given = {"seed": args.seed, "remedy": args.remedy, "boundary": args.boundary,
             "min_part_fraction": args.min_part_fraction, "solver": args.solver, "method": args.method,
             "batched": args.batched}
    given = {k: v for k, v in given.items() if v is not None}
    if args.graph_cut == "off":
        given["graphcut"] = None
    given.update(merge_overrides(args))
    return given


def run_eval(args) -> int:
    from .harness import evaluate_psb
    from .psb import CATEGORIES
    from .settings import EvalSettings, eval_segment_options

    psb_root = psb_folder(args.psb)
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
    coarse = DEFAULT_COARSE_FACES if args.coarse_faces is None else args.coarse_faces
    if coarse < 0:
        raise TorchAKVFError(f"--coarse-faces must be >= 0, got {coarse}")
    device = parse_device(args.device)
    # the batched path's processes (a solving one and host workers) serve given k's; k auto
    # predicts in --workers processes that each solve, one per GPU
    batched = (args.batched if args.batched is not None else not device.startswith("cpu")) and args.k != "auto"
    settings = EvalSettings(protocol=args.protocol, categories=categories, ids=args.ids,
                            per_category=args.per_category, k_mode=args.k, k_range=k_range,
                            default_k=args.default_k, n_fields=args.n_fields, coarse_faces=coarse or None,
                            metrics=args.metrics, batch_faces=args.batch_faces, batch_bytes=args.batch_bytes,
                            workers=args.workers or default_workers(device, batched=batched), device=device,
                            ray_workers=args.ray_workers)
    if args.ray_workers:
        import importlib.util

        if importlib.util.find_spec("ray") is None:
            raise TorchAKVFError("--ray-workers needs ray: pip install 'torchakvf[ray]'")
    summary = evaluate_psb(psb_root, args.out, eval_segment_options(None, _segment_overrides(args), settings.auto),
                           settings, progress=not args.quiet)
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
