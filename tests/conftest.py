"""Shared fixtures: where the PSB lives, and skips with a reason when it or CUDA is absent."""
from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[1]


def psb_root() -> Path | None:
    """The PSB folder: $TORCHAKVF_PSB, else ../shared/psb beside the repository."""
    env = os.environ.get("TORCHAKVF_PSB")
    for cand in ([Path(env)] if env else []) + [REPO.parent / "shared" / "psb"]:
        if (cand / "meshes").is_dir():
            return cand
    return None


@pytest.fixture(scope="session")
def psb() -> Path:
    root = psb_root()
    if root is None:
        pytest.skip("Princeton Segmentation Benchmark not found: set TORCHAKVF_PSB or put it at "
                    "../shared/psb (meshes/N.off.gz, gt/N/N_k.seg.gz)")
    return root


@pytest.fixture(scope="session")
def cuda() -> torch.device:
    if not torch.cuda.is_available():
        pytest.skip("no CUDA device on this machine")
    return torch.device("cuda")
