"""Command line: ``torchakvf segment | demo | features | eval | bench``.

Every error a user can cause prints one line ``torchakvf: error: ...`` and exits non-zero,
without a traceback.
"""
from __future__ import annotations

import argparse
import logging
import sys

from . import __version__
from .errors import TorchAKVFError

log = logging.getLogger("torchakvf")


def _add_demo(sub) -> None:
    p = sub.add_parser("demo", help="segment the built-in composite shapes (no input needed)")
    p.add_argument("--out", default="demo", help="output folder (default: demo/)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--eps", type=float, default=0.0, help="connecting-region width (default 0)")
    p.set_defaults(func=_run_demo)


def _run_demo(args) -> int:
    import numpy as np

    from . import shapes
    from .evaluate.metrics import matched_agreement
    from .io import OUTPUT_FORMATS, write_segmentation
    from .io.render import contact_sheet
    from .mesh import Mesh, MeshBatch
    from .parts import segment

    names = list(shapes.BUILTIN_SHAPES)
    built = [shapes.BUILTIN_SHAPES[n]() for n in names]
    batch = MeshBatch.from_meshes([Mesh(s.vertices, s.faces, name=n) for n, s in zip(names, built)])
    seg = segment(batch, k=[s.n_parts for s in built], eps=args.eps, seed=args.seed)
    sheet = []
    for b, (name, shape, ms) in enumerate(zip(names, built, seg.meshes)):
        write_segmentation(ms, shape.vertices, shape.faces, args.out, name, face_vectors=seg.face_vectors(b))
        sheet.append((shape.vertices, shape.faces, ms.labels, f"{name} (k={ms.k})",
                      (seg.face_vectors(b), ms.generators)))
        gens = ", ".join(f"part {p}: {len(g)} fields" for p, g in enumerate(ms.generators))
        print(f"{name:24s} faces={len(shape.faces):6d} k={ms.k}  "
              f"true parts matched on {100 * matched_agreement(ms.labels, shape.part_labels):.1f}% of faces  "
              f"λ·area[:4]={np.round(ms.eigenvalues[:4], 3).tolist()}  generators: {gens}")
    contact_sheet(f"{args.out}/contact_sheet.png", sheet)
    print(f"wrote {len(names)} shapes ({' '.join('.' + f for f in OUTPUT_FORMATS)}) and "
          f"contact_sheet.png to {str(args.out).rstrip('/')}/")
    unconverged = [ms.name for ms in seg.meshes if not ms.converged]
    if unconverged:   # results are written, but flagged: the exit code says something failed
        log.error("eigensolve did not converge (residual above tolerance) on: %s", ", ".join(unconverged))
        return 1
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="torchakvf", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"torchakvf {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _add_demo(sub)
    from .bench.command import add_bench_command
    from .evaluate.commands import add_eval_command
    from .pipeline.commands import add_corpus_commands
    add_corpus_commands(sub)
    add_eval_command(sub)
    add_bench_command(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except TorchAKVFError as exc:
        print(f"torchakvf: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("torchakvf: interrupted; finished results are kept", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
