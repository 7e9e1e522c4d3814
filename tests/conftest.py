"""Shared fixtures: where the PSB lives, and skips with a reason when it or CUDA is absent.

``device`` runs a test on "cpu" always and on "cuda" where there is a GPU (that parameter is
marked ``cuda`` and skipped elsewhere), so the comparison logic of a device test runs in CI too
(CPU against CPU). A test using the ``cuda`` fixture is marked ``cuda`` as well, so
``pytest -m cuda`` (benchmarks/device_check.sh) selects every test that needs a GPU.
"""
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
        pytest.skip(_NO_CUDA)
    return torch.device("cuda")


_NO_CUDA = "no CUDA device on this machine"
#: The devices a ``device`` test runs on: cpu everywhere, cuda where torch sees a GPU.
DEVICES = ["cpu", pytest.param("cuda", marks=[pytest.mark.cuda,
                                               pytest.mark.skipif(not torch.cuda.is_available(),
                                                                  reason=_NO_CUDA)])]


@pytest.fixture(params=DEVICES)
def device(request) -> torch.device:
    """The device under test (compare its result with the CPU's)."""
    return torch.device(request.param)


def pytest_collection_modifyitems(config, items):
    for item in items:
        if "cuda" in getattr(item, "fixturenames", ()) and item.get_closest_marker("cuda") is None:
            item.add_marker(pytest.mark.cuda)
