"""One torch intra-op thread for a whole test module: ``from threads import one_torch_thread``.

Small meshes run many tiny kernels and sparse solves: on a busy 2-core machine intra-op
threads spin-waiting on each other made such tests 10-100x slower (measured: 0.4 s vs 40 s
for the runner's corpus), while one thread is as fast on an idle machine.
"""
from __future__ import annotations

import pytest
import torch


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)
