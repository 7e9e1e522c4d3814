"""Bridges to the libraries people train with, as optional extras.

* :mod:`torchakvf.interop.pyg` — :class:`~torchakvf.interop.pyg.AKVFFeatures`, a
  ``torch_geometric`` transform (``pip install torchakvf[pyg]``).
* :mod:`torchakvf.interop.pytorch3d` — :func:`~torchakvf.interop.pytorch3d.from_pytorch3d`
  and :func:`~torchakvf.interop.pytorch3d.to_pytorch3d` between pytorch3d ``Meshes`` and
  :class:`~torchakvf.MeshBatch` (``pip install torchakvf[pytorch3d]``, see its install notes).

Nothing here is imported by ``import torchakvf``; each module imports its library when used.
:func:`face_features` is the library-free core both use.
"""
from .features import FaceFeatures, face_features

__all__ = ["FaceFeatures", "face_features"]
