"""Command-line arguments shared by the CLI's commands (``segment``, ``features``, ``eval``,
``bench``): the options they have in common and the checks of their values.

Numeric options are parsed here, not by argparse, so that a bad value is one line
(:class:`~torchakvf.errors.TorchAKVFError`, printed by the CLI as ``torchakvf: error: ...``).
"""
from __future__ import annotations

import argparse

from ..errors import TorchAKVFError
from ..fields.akvf import KRYLOV_MIN_EDGES, SOLVERS

__all__ = ["MAX_SEED", "parse_int", "parse_float", "parse_seed", "parse_device", "parse_remedy",
           "positive_int", "add_solver_argument", "add_batched_argument", "add_graph_cut_argument",
           "add_method_argument", "add_second_merge_argument", "add_sheet_rule_argument", "merge_overrides",
           "register_command"]

#: Largest ``--seed``: every generator the package seeds (torch.Generator, numpy) takes it,
#: and it fits the int64 a seed may be stored in.
MAX_SEED = 2**63 - 1


def parse_int(text, flag: str, minimum: int | None = None, maximum: int | None = None) -> int:
    """``text`` as an integer in [minimum, maximum]; a one-line error naming ``flag`` otherwise."""
    try:
        value = int(str(text).strip())
    except ValueError:
        raise TorchAKVFError(f"{flag} must be an integer, got {text!r}") from None
    if minimum is not None and value < minimum:
        raise TorchAKVFError(f"{flag} must be an integer >= {minimum}, got {value}")
    if maximum is not None and value > maximum:
        raise TorchAKVFError(f"{flag} must be an integer <= {maximum}, got {value}")
    return value


def parse_float(text, flag: str, minimum: float | None = None, maximum: float | None = None,
                why: str = "") -> float:
    """``text`` as a number in [minimum, maximum] (``why`` explains the maximum in the error)."""
    try:
        value = float(str(text).strip())
    except ValueError:
        raise TorchAKVFError(f"{flag} must be a number, got {text!r}") from None
    if value != value or (minimum is not None and value < minimum):
        raise TorchAKVFError(f"{flag} must be a number >= {minimum}, got {text!r}")
    if maximum is not None and value > maximum:
        raise TorchAKVFError(f"{flag} must be a number <= {maximum}{why}, got {text!r}")
    return value


def parse_seed(text) -> int:
    """``--seed``: an integer in [0, :data:`MAX_SEED`]."""
    return parse_int(text, "--seed", 0, MAX_SEED)


def parse_device(text: str, check_available: bool = True) -> str:
    """``--device`` as a torch device string (:func:`torchakvf.devices.resolve_device`: one-line
    errors for an unknown type, CUDA absent here, an index beyond the GPUs present)."""
    from ..devices import resolve_device

    return str(resolve_device(text, what="--device", check_available=check_available))


def parse_remedy(text: str) -> str:
    """``--remedy``: one of :data:`torchakvf.operators.killing.REMEDIES`."""
    from ..operators.killing import REMEDIES

    if text not in REMEDIES:
        raise TorchAKVFError(f"--remedy must be one of {', '.join(REMEDIES)}, got {text!r}")
    return text


def positive_int(text: str) -> int:
    """An argparse ``type=``: an integer >= 1 (argparse's own error otherwise)."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {v}")
    return v


def add_graph_cut_argument(p: argparse.ArgumentParser) -> None:
    """``--graph-cut on|off``: method merge's boundary graph cut (segment, eval, bench)."""
    p.add_argument("--graph-cut", default="on", choices=["on", "off"],
                   help="method merge: re-decide the part boundaries by an alpha-expansion graph "
                        "cut on the dual graph after merging (default on, cross-validated on the PSB)")


def add_second_merge_argument(p: argparse.ArgumentParser) -> None:
    """``--second-merge on|off``: method merge's second merge by the hand-set cost, kept where
    its boundaries lie on concave creases (segment, eval, bench)."""
    p.add_argument("--second-merge", default="on", choices=["on", "off"],
                   help="method merge: also merge the pieces by the hand-set cost and keep those parts "
                        "where their flattest boundary is far more concave (default on; off: about 10%% "
                        "less time, the learned merge alone)")


def add_sheet_rule_argument(p: argparse.ArgumentParser) -> None:
    """``--sheet-rule on|off``: where a merge of method merge leaves a flat part (a socket's
    floor, a tube's end face) among its k parts, the pieces are merged again with it first
    (segment, eval, bench)."""
    p.add_argument("--sheet-rule", default="on", choices=["on", "off"],
                   help="method merge: where a merge leaves a part whose faces nearly all face one way "
                        "(flatness above 0.9: the floor of a socket, the end face of a tube), merge the "
                        "pieces again with it first (default on; off: the merges by their cost alone)")


def merge_overrides(args) -> dict:
    """The SegmentOptions changes ``--second-merge`` and ``--sheet-rule`` ask for (none at
    their defaults): ``merge_choice`` None, and the merges' weights without the sheet rule."""
    from ..merge_options import ConcaveChoice, MergeWeights

    given = {}
    if args.sheet_rule == "off":
        given["merge"] = MergeWeights(sheet_flatness=None)
        given["merge_choice"] = ConcaveChoice(weights=MergeWeights.hand_set(sheet_flatness=None))
    if args.second_merge == "off":
        given["merge_choice"] = None
    return given


def add_solver_argument(p: argparse.ArgumentParser, default) -> None:
    """``--solver``, its choices those of :func:`torchakvf.akvf` (one list for every command)."""
    p.add_argument("--solver", default=default, choices=list(SOLVERS),
                   help="eigensolver of the AKVFs (default auto: on CPU ARPACK Lanczos below "
                        f"{KRYLOV_MIN_EDGES} edges and block Krylov above, both on a CHOLMOD "
                        "factor; LOBPCG on a GPU)")


def add_batched_argument(p: argparse.ArgumentParser) -> None:
    """``--batched``: solve each batch as one, the accelerator's path (segment, features, eval,
    bench); True when given, else None (the device's way)."""
    p.add_argument("--batched", action="store_const", const=True, default=None,
                   help="solve each batch as one (one operator, the batched LOBPCG on one "
                        "block-diagonal factor), fed by host worker processes: the default on a "
                        "GPU; on the CPU it runs the accelerator's path there (slower than the "
                        "per-mesh solvers, for testing it)")


def add_method_argument(p: argparse.ArgumentParser, default, methods) -> None:
    """``--method``: the segmentation method (``methods``: its choices)."""
    p.add_argument("--method", default=default, choices=list(methods),
                   help="segmentation method: merge (default: over-segment, then merge adjacent "
                        "parts by symmetry and concavity) or paper (Solomon et al. 2011)")


def register_command(subparsers, name: str, summary: str, description: str, add_arguments, run) -> None:
    """Add command ``name`` to an argparse ``add_subparsers()`` object: its options from
    ``add_arguments(parser)``, ``run(args) -> exit code`` as its ``func``."""
    p = subparsers.add_parser(name, help=summary, description=description)
    add_arguments(p)
    p.set_defaults(func=run)
