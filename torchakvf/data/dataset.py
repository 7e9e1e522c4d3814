"""A torch Dataset over the ``.npz`` files of ``torchakvf features``, and a packed collate.

    ds = torchakvf.data.FeatureDataset("feats/")
    loader = torch.utils.data.DataLoader(ds, batch_size=8, collate_fn=torchakvf.data.collate_packed)

Files are read with ``np.load(..., allow_pickle=False)``: a feature file can hold plain arrays
only, never code.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

#: Per-face arrays of a feature file, packed along faces by :func:`collate_packed`.
FACE_KEYS = ("features", "akvf_norms", "face_vectors")


def load_feature_file(path) -> dict:
    """The arrays of one feature .npz as numpy (``allow_pickle=False``)."""
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


class FeatureDataset(Dataset):
    """Feature files under ``root``: those its ``manifest.jsonl`` records as ``ok`` for the
    features task (when there is a manifest), else every ``*.npz`` in it; sorted by name.

    Item ``i`` is a dict: ``vertices`` [V, 3] float32, ``faces`` [F, 3] int64, ``features``
    [F, n] float32, ``akvf_norms`` [F, n] float32, ``eigenvalues`` [n] float64, ``residuals``
    [n] float64, ``face_vectors`` [F, n, 3] (when the file has them), ``name`` (the stem), and
    ``params`` (dict).
    """

    def __init__(self, root, *, transform=None):
        self.root = Path(root)
        if not self.root.is_dir():
            from ..errors import TorchAKVFError

            raise TorchAKVFError(f"{root}: not a folder of feature files")
        self.transform = transform
        self.files = self._list_files()

    def _list_files(self) -> list[Path]:
        manifest = self.root / "manifest.jsonl"
        if manifest.exists():
            last: dict[str, dict] = {}
            for line in manifest.read_bytes().splitlines():
                try:
                    rec = json.loads(line)
                except ValueError:
                    continue
                if isinstance(rec, dict) and "path" in rec:
                    last[str(rec["path"])] = rec
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
            "params": json.loads(str(z["params_json"])) if "params_json" in z else {},
        }
        if "face_vectors" in z:
            item["face_vectors"] = torch.from_numpy(np.ascontiguousarray(z["face_vectors"], dtype=np.float32))
        return self.transform(item) if self.transform is not None else item


def collate_packed(items: list[dict]) -> dict:
    """Pack a list of items into one batch (the packed layout of :class:`torchakvf.MeshBatch`):

    ``vertices`` [ΣV, 3], ``faces`` [ΣF, 3] with *global* vertex indices (mesh b's shifted by
    ``vert_ptr[b]``), ``features``/``akvf_norms`` [ΣF, n] (``face_vectors`` [ΣF, n, 3] when
    every item has them), ``vert_ptr``/``face_ptr`` [B+1] int64 offsets, ``face_to_mesh`` [ΣF],
    ``eigenvalues``/``residuals`` [B, n], ``names`` list of B.
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
        "face_to_mesh": torch.repeat_interleave(torch.arange(len(items)), nf),
        "eigenvalues": torch.stack([it["eigenvalues"] for it in items]),
        "residuals": torch.stack([it["residuals"] for it in items]),
        "names": [it["name"] for it in items],
    }
    for key in FACE_KEYS:
        if all(key in it for it in items):
            out[key] = torch.cat([it[key] for it in items])
    return out
