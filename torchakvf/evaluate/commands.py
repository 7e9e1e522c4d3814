"""``torchakvf eval``: the benchmark evaluation from the command line.

::

    torchakvf eval --psb ../shared/psb --out eval/            # whole benchmark, by-segmentation
    torchakvf eval --psb DIR --categories Human,Octopus --protocol by-model --out eval/
    torchakvf eval --per-category 2 -k auto --out eval_auto/
"""
from __future__ import annotations

import os
from pathlib import Path

from ..errors import TorchAKVFError

__all__ = ["add_eval_command", "default_psb_arg"]


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


def add_eval_command(subparsers) -> None:
    """Register ``eval`` on an argparse ``add_subparsers()`` object."""
    from .harness import DEFAULT_K_NO_GT, METRIC_GROUPS, PROTOCOLS

    p = subparsers.add_parser(
        "eval", help="evaluate on the Princeton Segmentation Benchmark (resumable)",
        description="Segment PSB meshes, score them against the human segmentations and write "
                    "pred/<id>/<id>_k<k>.seg, scores.csv, summary.md and rand_index.png to --out. "
                    "Re-running with the same --out skips predictions already written.")
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
                   help="'auto': choose the number of parts per mesh (k-means cost elbow); one "
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
                   help="fields untangled per mesh (default 2k in [16, 32])")
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
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run_eval)


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
    from ..mesh.coarse import DEFAULT_COARSE_FACES

    coarse = DEFAULT_COARSE_FACES if args.coarse_faces is None else args.coarse_faces
    if coarse < 0:
        raise TorchAKVFError(f"--coarse-faces must be >= 0, got {coarse}")
    if coarse:
        seg_kwargs["coarse_faces"] = coarse
    from ..pipeline.parallel import default_workers

    summary = evaluate_psb(psb_root, args.out, categories=categories, protocol=args.protocol,
                           ids=args.ids, per_category=args.per_category, seed=args.seed,
                           remedy=args.remedy, n_fields=args.n_fields, batch_faces=args.batch_faces,
                           k_mode=args.k, k_range=k_range, progress=not args.quiet,
                           metrics=args.metrics, default_k=args.default_k,
                           workers=args.workers or default_workers("cpu"), **seg_kwargs)
    n_ok = sum(r.scored for r in summary.rows)
    print(f"{n_ok} meshes scored, overall 1-RI {summary.rand_index_error:.4f}; "
          f"wrote {Path(args.out) / 'summary.md'}, scores.csv, rand_index.png")
    return 0
