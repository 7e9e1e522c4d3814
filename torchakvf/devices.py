"""Which torch device a computation runs on, checked once where it enters the package.

Every public entry point that takes ``device=`` (``MeshBatch.from_meshes`` / ``.to`` and so
``akvf``, ``segment``, ``segment_each_k``; the corpus runner; ``evaluate_psb``; the bench; the
CLI's ``--device``) resolves it here, so that a device this machine cannot use is one
:class:`~torchakvf.errors.ParameterError` naming the problem and the fix, not torch's
"Torch not compiled with CUDA enabled" AssertionError from deep inside a batch.
"""
from __future__ import annotations

import torch

from .errors import ParameterError

__all__ = ["resolve_device", "SUPPORTED_DEVICE_TYPES"]

#: Device types the pipeline is written and tested for (tests/test_cuda.py).
SUPPORTED_DEVICE_TYPES = ("cpu", "cuda")


def resolve_device(device=None, *, what: str = "device", check_available: bool = True) -> torch.device:
    """``device`` (a str such as "cpu", "cuda", "cuda:1", a :class:`torch.device`, an int N for
    cuda:N as torch reads it, or None for "cpu") as a :class:`torch.device` this machine can run on.

    what : how the value is named in the error (the CLI passes "--device")
    check_available : also check that CUDA exists here and the index is in range (False: only
        the syntax and type, e.g. on a Ray driver whose workers have the GPUs)

    Raises :class:`~torchakvf.errors.ParameterError` for a value that is not a torch device,
    a device type other than cpu and cuda, CUDA on a machine without it, or a CUDA index
    beyond the devices present.
    """
    if device is None:
        return torch.device("cpu")
    if isinstance(device, torch.device):
        dev = device
    elif isinstance(device, int) and not isinstance(device, bool) and device >= 0:
        dev = torch.device("cuda", device)          # torch's meaning of a bare index
    elif isinstance(device, str):
        try:
            dev = torch.device(device.strip())
        except (RuntimeError, ValueError):
            raise ParameterError(f"{what} {device!r} is not a torch device (use cpu, cuda or "
                                 "cuda:N)") from None
    else:
        raise ParameterError(f"{what} must be a str or torch.device such as 'cpu' or 'cuda', "
                             f"got {type(device).__name__} {device!r}")
    if dev.type not in SUPPORTED_DEVICE_TYPES:
        raise ParameterError(f"{what} {str(dev)!r}: only {' and '.join(SUPPORTED_DEVICE_TYPES)} "
                             "are supported")
    fix = "use --device cpu" if what.startswith("--") else "use device='cpu'"
    if dev.type == "cuda" and check_available:
        if not torch.cuda.is_available():
            why = ("this torch build has no CUDA" if torch.version.cuda is None
                   else f"torch {torch.__version__} (CUDA {torch.version.cuda}) sees no GPU")
            raise ParameterError(f"{what} {str(dev)!r}: CUDA is not available on this machine "
                                 f"({why}); {fix}")
        count = torch.cuda.device_count()
        if dev.index is not None and dev.index >= count:
            raise ParameterError(f"{what} {str(dev)!r}: this machine has {count} CUDA device(s), "
                                 f"cuda:0 to cuda:{count - 1}")
    return dev
