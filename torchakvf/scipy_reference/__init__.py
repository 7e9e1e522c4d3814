"""Plain numpy/scipy reference implementation of AKVFs and intrinsic-primitive segmentation.

Role
----
This module is the *baseline* that ``torchakvf`` is measured against, in two senses:

* **Test oracle.**  It is written independently of ``torchakvf`` (no torch, no ``torchakvf`` imports) and
  follows ``docs/akvf_operator.md`` section 2 literally: DEC operators d0/d1/star0/star1/star2, angle-defect
  curvature, the weak-form Killing operator

      R = d1^T S2 d1 + 2 D^T S0^{-1} D - 2 S1 diag(K_e) - 2 R_b      (symmetrized)

  with the boundary divergence correction (inside ``D``) and the boundary term ``R_b`` for meshes with boundary.
  Results can be compared edge by edge with other implementations because the edge convention is fixed:
  edges are the unique undirected pairs ``(i, j)`` with ``i < j``, sorted lexicographically, oriented ``i -> j``.

* **Speed baseline.**  It is what a user would write by hand: scipy.sparse assembly and
  ``scipy.sparse.linalg.eigsh`` in shift-invert mode (default SuperLU factorization), numpy for Algorithm 1
  (Horst's quartimax iteration) and for spherical k-means.

Conventions
-----------
* The mesh is scaled to unit total area before anything is assembled, so eigenvalues are ``lambda * area``
  (the ``delta d + 2 d delta - 2K`` scale of docs/akvf_operator.md; the paper's Killing energy is twice that) and the
  default shift ``sigma = -1`` is meaningful regardless of the input units.  The scaled vertices are returned in
  ``meta["V"]``.
* The input must be a consistently oriented, edge-manifold triangle mesh without zero-area faces (checked).
  Unreferenced vertices are tolerated (they have no edges, and get ``star0^{-1} = 0``).
"""
from .operator import akvf_scipy, clamp_mass, killing_operator_scipy, mesh_edges, solve_akvf, whitney_face_vectors_scipy
from .segmentation import features_scipy, segment_scipy, spherical_kmeans_numpy, untangle_numpy

__all__ = ["mesh_edges", "killing_operator_scipy", "whitney_face_vectors_scipy", "akvf_scipy", "clamp_mass",
           "solve_akvf", "untangle_numpy", "spherical_kmeans_numpy", "segment_scipy", "features_scipy"]
