"""A torch Dataset over the ``.npz`` files of ``torchakvf features``, and a packed collate.

    ds = torchakvf.data.FeatureDataset("feats/")
    loader = torch.utils.data.DataLoader(ds, batch_size=8, collate_fn=torchakvf.data.collate_packed)

Files are read with ``np.load(..., allow_pickle=False)``: a feature file can hold plain arrays
only, never code.
"""
from __future__ import annotations

import json
import zipfile
import zlib
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from ..errors import TorchAKVFError
from ..io.manifest import MANIFEST, read_manifest
from ..mesh.batch import owner_index

#: Per-face arrays of a feature file, packed along faces by :func:`collate_packed`.
FACE_KEYS = ("features", "akvf_norms", "descriptors", "face_vectors")


#: Arrays every feature file holds (``face_vectors`` only with ``--face-vectors``).
REQUIRED_KEYS = ("faces_input_count", "vertices", "faces", "akvf_norms", "features", "eigenvalues",
                 "residuals")


def load_feature_file(path) -> dict:
    """The arrays of one feature .npz as numpy (``allow_pickle=False``), checked whole.

    Raises :class:`TorchAKVFError` naming the file when it cannot be read (truncated, not an
    npz, an object array), lacks an array, or its arrays disagree in shape (e.g. features
    [10, 32] beside faces [192, 3]): every per-face array has the file's F rows, F equals
    ``faces_input_count``, the n fields agree, and face indices are within the vertices.
    """
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise TorchAKVFError(f"{path}: feature file not found") from None
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as exc:
        raise TorchAKVFError(f"{path}: not a readable feature file ({type(exc).__name__}: {exc}); "
                             "delete it and run torchakvf features again") from None
    problem = _shape_problem(arrays)
    if problem:
        raise TorchAKVFError(f"{path}: corrupt feature file: {problem}; delete it and run "
                             "torchakvf features again")
    return arrays


def _shape_problem(z: dict) -> str | None:
    missing = [k for k in REQUIRED_KEYS if k not in z]
    if missing:
        return f"missing array(s) {', '.join(missing)}"
    v, f = z["vertices"], z["faces"]
    if v.ndim != 2 or v.shape[1] != 3:
        return f"vertices have shape {list(v.shape)}, expected [V, 3]"
    if f.ndim != 2 or f.shape[1] != 3:
        return f"faces have shape {list(f.shape)}, expected [F, 3]"
    if z["faces_input_count"].shape != () or int(z["faces_input_count"]) != len(f):
        return f"faces_input_count {z['faces_input_count'].tolist()} but faces has {len(f)} rows"
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        return f"face indices outside the {len(v)} vertices"
    n = z["eigenvalues"].shape[0] if z["eigenvalues"].ndim == 1 else None
    if n is None:
        return f"eigenvalues have shape {list(z['eigenvalues'].shape)}, expected [n]"
    expected = {"features": (len(f), n), "akvf_norms": (len(f), n), "residuals": (n,),
                "face_vectors": (len(f), n, 3)}
    for key, shape in expected.items():
        if key in z and z[key].shape != shape:
            return f"{key} has shape {list(z[key].shape)} beside faces {list(f.shape)} and {n} fields " \
                   f"(expected {list(shape)})"
    d = z.get("descriptors")
    if d is not None and (d.ndim != 2 or d.shape[0] != len(f)):
        return f"descriptors have shape {list(d.shape)} beside faces {list(f.shape)} (expected [{len(f)}, d])"
    if d is not None and "descriptor_names" in z and z["descriptor_names"].shape != (d.shape[1],):
        return f"{z['descriptor_names'].size} descriptor names for {d.shape[1]} descriptor columns"
    return None


class FeatureDataset(Dataset):
    """Feature files under ``root``: those its ``manifest.jsonl`` records as ``ok`` for the
    features task (when there is a manifest), else every ``*.npz`` in it; sorted by name.

    Item ``i`` is a dict: ``vertices`` [V, 3] float32, ``faces`` [F, 3] int64, ``features``
    [F, n] float32, ``akvf_norms`` [F, n] float32, ``eigenvalues`` [n] float64, ``residuals``
    [n] float64, ``descriptors`` [F, d] float32 and ``descriptor_names`` (list of d) when the
    file has them (files written by ``features`` since it writes them; docs/descriptors.md),
    ``face_vectors`` [F, n, 3] (when the file has them), ``name`` (the stem), and ``params``
    (dict).
    """

    def __init__(self, root, *, transform=None):
        self.root = Path(root)
        if not self.root.is_dir():
            raise TorchAKVFError(f"{root}: not a folder of feature files")
        self.transform = transform
        self.files = self._list_files()

    def _list_files(self) -> list[Path]:
        if (self.root / MANIFEST).exists():   # a manifest, even one with only torn lines, decides
            last = read_manifest(self.root)
            stems = sorted({r["stem"] for r in last.values()
                            if r.get("status") == "ok" and r.get("task", "features") == "features"})
            files = [self.root / f"{s}.npz" for s in stems]
            return [f for f in files if f.exists()]
        return sorted(self.root.glob("*.npz"))

    def __len__(self) -> int:
        return len(self.files)

    def __getitem__(self, i: int) -> dict:
        path = self.files[i]
        z = load_feature_file(path)
        item = {
            "vertices": torch.from_numpy(np.ascontiguousarray(z["vertices"], dtype=np.float32)),
            "faces": torch.from_numpy(np.ascontiguousarray(z["faces"], dtype=np.int64)),
            "features": torch.from_numpy(np.ascontiguousarray(z["features"], dtype=np.float32)),
            "akvf_norms": torch.from_numpy(np.ascontiguousarray(z["akvf_norms"], dtype=np.float32)),
            "eigenvalues": torch.from_numpy(np.ascontiguousarray(z["eigenvalues"], dtype=np.float64)),
            "residuals": torch.from_numpy(np.ascontiguousarray(z["residuals"], dtype=np.float64)),
            "name": path.stem,
            "params": _params(path, z),
        }
        if "descriptors" in z:
            item["descriptors"] = torch.from_numpy(np.ascontiguousarray(z["descriptors"], dtype=np.float32))
            item["descriptor_names"] = [str(c) for c in z["descriptor_names"]] if "descriptor_names" in z else []
        if "face_vectors" in z:
            item["face_vectors"] = torch.from_numpy(np.ascontiguousarray(z["face_vectors"], dtype=np.float32))
        return self.transform(item) if self.transform is not None else item


def _params(path, z: dict) -> dict:
    if "params_json" not in z:
        return {}
    try:
        return json.loads(str(z["params_json"]))
    except ValueError:
        raise TorchAKVFError(f"{path}: corrupt feature file: params_json is not JSON") from None


def collate_packed(items: list[dict]) -> dict:
    """Pack a list of items into one batch (the packed layout of :class:`torchakvf.MeshBatch`):

    ``vertices`` [ΣV, 3], ``faces`` [ΣF, 3] with *global* vertex indices (mesh b's shifted by
    ``vert_ptr[b]``), ``features``/``akvf_norms`` [ΣF, n] (``descriptors`` [ΣF, d] and
    ``face_vectors`` [ΣF, n, 3] when every item has them), ``vert_ptr``/``face_ptr`` [B+1] int64
    offsets, ``face_to_mesh`` [ΣF], ``eigenvalues``/``residuals`` [B, n], ``names`` list of B.
    """
    if not items:
        raise ValueError("collate_packed needs at least one item")
    ns = {int(it["features"].shape[1]) for it in items}
    if len(ns) != 1:
        raise ValueError(f"items have different numbers of fields {sorted(ns)}; they cannot share a batch")
    nv = torch.tensor([len(it["vertices"]) for it in items], dtype=torch.int64)
    nf = torch.tensor([len(it["faces"]) for it in items], dtype=torch.int64)
    vert_ptr = torch.cat([torch.zeros(1, dtype=torch.int64), torch.cumsum(nv, 0)])
    face_ptr = torch.cat([torch.zeros(1, dtype=torch.int64), torch.cumsum(nf, 0)])
    out = {
        "vertices": torch.cat([it["vertices"] for it in items]),
        "faces": torch.cat([it["faces"].to(torch.int64) + vert_ptr[b] for b, it in enumerate(items)]),
        "vert_ptr": vert_ptr,
        "face_ptr": face_ptr,
        "face_to_mesh": owner_index(face_ptr),
        "eigenvalues": torch.stack([it["eigenvalues"] for it in items]),
        "residuals": torch.stack([it["residuals"] for it in items]),
        "names": [it["name"] for it in items],
    }
    for key in FACE_KEYS:
        if all(key in it for it in items):
            out[key] = torch.cat([it[key] for it in items])
    return out
