"""``torchakvf segment`` and ``torchakvf features``: the corpus commands of the CLI.

Each command function returns the exit code (0: every mesh ok, 1: some failed) and raises
:class:`~torchakvf.errors.TorchAKVFError` for user errors, which the CLI prints as one line
(exit 2); the values are checked by :mod:`.arguments`.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

from ..errors import TorchAKVFError
from ..options import DEFAULT_METHOD, METHODS
from .arguments import (
    add_batched_argument,
    add_graph_cut_argument,
    add_method_argument,
    add_second_merge_argument,
    add_sheet_rule_argument,
    add_solver_argument,
    merge_overrides,
    parse_device,
    parse_float,
    parse_int,
    parse_remedy,
    parse_seed,
)

log = logging.getLogger("torchakvf")


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("inputs", nargs="+", metavar="DIR_OR_GLOB_OR_FILE",
                   help="mesh files (.off .obj .ply .stl, optionally .gz), folders (recursive) or globs")
    p.add_argument("--out", required=True, help="output folder (created; manifest.jsonl goes there)")
    p.add_argument("--seed", default="0", help="random seed of solver starts, untangling and k-means (default 0)")
    p.add_argument("--device", default="cpu", help="torch device, e.g. cpu or cuda (default cpu)")
    p.add_argument("--batch-faces", default=None, metavar="N",
                   help="face budget per batch, meshes sorted by size (default 20000 on cpu; a batch solved "
                        "as one, on cuda or with --batched, is sized by its memory, capped at 1000000)")
    p.add_argument("--remedy", default=None, help="mesh-quality remedy of the Killing operator "
                                                    "(default: the segmenter's, 'auto': the paper's operator on each "
                                                    "mesh that has no spurious mode, 'smooth' on the others)")
    p.add_argument("--force", action="store_true",
                   help="recompute every mesh, even those the manifest records as done")
    p.add_argument("--ray-workers", default="0", metavar="N",
                   help="run the batches on N Ray actors (pip install 'torchakvf[ray]'; joins the "
                        "cluster of RAY_ADDRESS or `ray start`, else a local one; with --device cuda "
                        "one GPU each). Default 0: no Ray")
    p.add_argument("--workers", default=None, metavar="W",
                   help="with --batched (or on cuda): processes in all, one solving, the others loading, "
                        "cutting and writing meshes meanwhile (default: one per CPU core, at most 16); "
                        "otherwise processes running batches side by side, one thread each (default 1)")
    add_batched_argument(p)


def _ray_workers(args) -> int:
    return parse_int(args.ray_workers, "--ray-workers", 0)


def _workers(args) -> int | None:
    return parse_int(args.workers, "--workers", 1) if args.workers is not None else None


def _run(args, task, device: str) -> int:
    from .batches import default_batch_faces
    from .inputs import discover_inputs
    from .outdir import check_output_dir
    from .runner import failure_text, run_corpus

    out = Path(args.out)
    ray_workers = _ray_workers(args)
    if ray_workers:
        import importlib.util

        if importlib.util.find_spec("ray") is None:
            raise TorchAKVFError("--ray-workers needs ray: pip install 'torchakvf[ray]'")
    batch_faces = (parse_int(args.batch_faces, "--batch-faces", 1) if args.batch_faces is not None
                   else default_batch_faces(device, batched=args.batched))
    paths = discover_inputs(args.inputs, exclude=out)
    check_output_dir(out)   # before any work: an unwritable --out is one line, not N failures
    log.info("%s: %d meshes -> %s (device %s, batches of <= %d faces)", task.name, len(paths), out,
             device, batch_faces)
    if ray_workers:
        from .ray_runner import run_corpus_ray

        summary = run_corpus_ray(paths, out, task, batch_faces=batch_faces, device=device, seed=task.seed,
                                 resume=not args.force, workers=ray_workers)
    else:
        summary = run_corpus(paths, out, task, batch_faces=batch_faces, device=device,
                             seed=task.seed, resume=not args.force, workers=_workers(args))
    print(summary.line(task.name))
    if summary.failed:
        shown = summary.failures[:5]
        for path, err in shown:
            print(f"  failed: {failure_text(path, err)}")
        if summary.failed > len(shown):
            print(f"  ... and {summary.failed - len(shown)} more (see {summary.manifest})")
    return summary.exit_code


# ---- segment ------------------------------------------------------------------------------

def _add_segment(sub) -> None:
    from ..io import OUTPUT_FORMATS
    from ..mesh.coarse import DEFAULT_COARSE_FACES

    p = sub.add_parser("segment", help="segment meshes into k parts (writes <stem>.seg .npz .ply .png)",
                       description="Segment every mesh into k parts; one .seg (PSB format: a label "
                                   "per input face) and optional .npz/.ply/.png per mesh.")
    _common(p)
    p.add_argument("-k", required=True, help="parts per mesh (integer >= 1), or 'auto': chosen per mesh from "
                                             "--k-range by the merge costs (the manifest records each mesh's k)")
    p.add_argument("--k-range", default="2,10", metavar="LO,HI", help="k's tried with -k auto (default 2,10)")
    p.add_argument("--eps", default="0", help="connecting-region width (0 = plain k-segmentation)")
    p.add_argument("--n-fields", default=None, help="AKVFs untangled per mesh (default 2k clamped to [16, 32])")
    p.add_argument("--formats", default=",".join(OUTPUT_FORMATS),
                   help=f"outputs per mesh, comma separated (default {','.join(OUTPUT_FORMATS)}; "
                        "png is the slowest on big meshes)")
    p.add_argument("--coarse-faces", default=None, metavar="N",
                   help=f"solve on meshes decimated to about N faces and cut the parts on the "
                        f"originals (default {DEFAULT_COARSE_FACES}, measured on the PSB; 0: full "
                        "resolution)")
    p.add_argument("--subdivide", action="store_true",
                   help="subdivide a mesh with too few edges for its fields (a 12-face cube at -k 5) "
                        "at its edge midpoints until it has enough; labels stay one per face of the file")
    add_solver_argument(p, default="auto")
    add_graph_cut_argument(p)
    add_second_merge_argument(p)
    add_sheet_rule_argument(p)
    add_method_argument(p, DEFAULT_METHOD, METHODS)
    p.set_defaults(func=run_segment)


def run_segment(args) -> int:
    from ..mesh.coarse import DEFAULT_COARSE_FACES
    from ..options import DEFAULT_REMEDY, SegmentOptions
    from ..parts.k_auto import is_auto, scan_overseg
    from .segment_task import SegmentTask, parse_formats

    auto = is_auto(args.k)
    k = "auto" if auto else parse_int(args.k, "-k", 1)
    try:
        lo, hi = (int(v) for v in args.k_range.split(","))
    except ValueError:
        raise TorchAKVFError(f"--k-range must be LO,HI, got {args.k_range!r}") from None
    n_fields = parse_int(args.n_fields, "--n-fields", 1) if args.n_fields is not None else None
    coarse = (DEFAULT_COARSE_FACES if args.coarse_faces is None
              else parse_int(args.coarse_faces, "--coarse-faces", 0))
    eps = parse_float(args.eps, "--eps", 0.0, 2.0, " (a cosine distance never exceeds 2)")
    options = SegmentOptions(eps=eps, seed=parse_seed(args.seed),
                             remedy=parse_remedy(args.remedy or DEFAULT_REMEDY), solver=args.solver,
                             method=args.method, graphcut=args.graph_cut == "on", batched=args.batched,
                             **merge_overrides(args),
                             **({"overseg": scan_overseg(None)} if auto else {}))
    task = SegmentTask(k, options, n_fields=n_fields, coarse_faces=coarse or None,
                       formats=parse_formats(args.formats), subdivide=args.subdivide, k_range=(lo, hi))
    return _run(args, task, parse_device(args.device, check_available=not _ray_workers(args)))


# ---- features -----------------------------------------------------------------------------

def _add_features(sub) -> None:
    p = sub.add_parser("features", help="per-face AKVF features, one .npz per mesh",
                       description="Compute the n AKVFs of every mesh and their untangled per-face "
                                   "norms; one <stem>.npz per mesh (see torchakvf.data.FeatureDataset).")
    _common(p)
    p.add_argument("--n", default="32", help="AKVFs per mesh (default 32)")
    p.add_argument("--face-vectors", action="store_true",
                   help="also store the untangled face vectors [F, n, 3] (large)")
    p.add_argument("--no-part-descriptors", dest="part_descriptors", action="store_false",
                   help="leave the part descriptors (cut distances from 18 segmentations, about 1 s "
                        "a mesh of 4000 faces) out of the descriptors")
    p.add_argument("--cache", default=None, metavar="DIR",
                   help="content cache: a mesh seen before (same bytes, params, version) is copied, not recomputed")
    p.add_argument("--coarse-faces", default="0", metavar="N",
                   help="solve meshes of more than 1.25 N faces decimated to about N faces; each input "
                        "face takes its coarse face's values (default 0: full resolution)")
    p.add_argument("--max-faces", default=None, metavar="N",
                   help="refuse a mesh with more than N faces to solve (default: refuse only meshes "
                        "whose estimated memory exceeds this machine's)")
    p.set_defaults(func=run_features)


def run_features(args) -> int:
    from ..options import DEFAULT_REMEDY
    from .features import FeaturesTask

    n = parse_int(args.n, "--n", 1)
    seed = parse_seed(args.seed)
    remedy = parse_remedy(args.remedy or DEFAULT_REMEDY)
    coarse = parse_int(args.coarse_faces, "--coarse-faces", 0) or None
    max_faces = parse_int(args.max_faces, "--max-faces", 1) if args.max_faces is not None else None
    device = parse_device(args.device, check_available=not _ray_workers(args))
    task = FeaturesTask(n, seed=seed, remedy=remedy, face_vectors=args.face_vectors, cache_dir=args.cache,
                        coarse_faces=coarse, max_faces=max_faces, batched=args.batched, device=device,
                        part_descriptors=args.part_descriptors)
    return _run(args, task, device)


# ---- registration -------------------------------------------------------------------------

def add_corpus_commands(subparsers) -> None:
    """Register ``segment`` and ``features`` on the CLI's subparsers (``bench`` is
    :func:`torchakvf.bench.command.add_bench_command`)."""
    _add_segment(subparsers)
    _add_features(subparsers)
