"""Whitney interpolation (torchakvf.operators.whitney): exact on gradients, the CPU's sparse
product against the gathered einsum."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from helpers.eigen_checks import mesh_of

import torchakvf as ta
from torchakvf import shapes
from torchakvf.operators import batch_geometry, d0, whitney_face_vectors

pytestmark = pytest.mark.usefixtures("one_torch_thread")   # one intra-op thread (see conftest)


def test_whitney_of_exact_form_is_the_gradient():
    batch = ta.MeshBatch.from_meshes([mesh_of(shapes.icosphere(3)), mesh_of(shapes.flat_disk()),
                                      mesh_of(shapes.torus(n_major=36))])
    geo = batch_geometry(batch)
    p = geo.points
    rng = np.random.default_rng(1)
    a = torch.tensor(rng.standard_normal((4, 3)))
    f = p @ a.T + torch.tensor(rng.standard_normal(4))            # [V, 4] linear functions
    w = torch.sparse.mm(d0(batch), f)                             # exact 1-forms d0 f
    x = whitney_face_vectors(batch, geo, w)                       # [F, 4, 3]
    nrm = geo.normal
    expected = a[None] - (nrm @ a.T)[:, :, None] * nrm[:, None, :]   # tangential gradient
    assert x.shape == (len(batch.faces), 4, 3)
    torch.testing.assert_close(x, expected, rtol=0, atol=1e-11)
    # a non-exact form (random) is not reproduced by any gradient: sanity check of the check
    xr = whitney_face_vectors(batch, geo, torch.randn(len(batch.edges), 1, dtype=torch.float64))
    assert (xr - expected[:, :1]).abs().max() > 1e-3


def test_whitney_sparse_product_equals_the_gathered_einsum():
    """The CPU's sparse product (one [3F, E] matrix times the forms) against the einsum over the
    gathered face-edge values that other devices (and a form needing gradients) run: the same
    three products per entry, summed in another order, so equal to round-off (1e-15 relative),
    in float64 and float32, on a column slice (not contiguous) of the forms."""
    batch = ta.MeshBatch.from_meshes([mesh_of(shapes.icosphere(2)), mesh_of(shapes.flat_disk())])
    geo = batch_geometry(batch)
    gen = torch.Generator().manual_seed(3)
    forms = torch.randn(len(batch.edges), 9, generator=gen, dtype=torch.float64)[:, ::2]
    sparse = whitney_face_vectors(batch, geo, forms)
    einsum = whitney_face_vectors(batch, geo, forms.clone().requires_grad_(True)).detach()
    assert sparse.shape == einsum.shape == (len(batch.faces), 5, 3)
    scale = float(einsum.abs().max())
    assert float((sparse - einsum).abs().max()) <= 1e-14 * scale
    single = whitney_face_vectors(batch, geo, forms.to(torch.float32))
    assert single.dtype == torch.float32
    assert float((single.double() - einsum).abs().max()) <= 1e-6 * scale
    # an empty batch of forms (n = 0) keeps its shape
    assert whitney_face_vectors(batch, geo, forms[:, :0]).shape == (len(batch.faces), 0, 3)
    # geometry needing gradients (vertex positions being optimized) takes the einsum too, and
    # its gradient arrives
    moving = dataclasses.replace(geo, grad_bary=geo.grad_bary.clone().requires_grad_(True))
    out = whitney_face_vectors(batch, moving, forms)
    assert float((out.detach() - einsum).abs().max()) <= 1e-14 * scale
    out.sum().backward()
    assert moving.grad_bary.grad is not None and bool(moving.grad_bary.grad.abs().sum() > 0)
