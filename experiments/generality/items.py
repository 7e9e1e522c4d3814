"""The part-labelled shapes the segmentation's rules are chosen on: the labelled PSB meshes (a
group per category) and the procedural corpus (a group per family, datasets_scripts/
make_parts_corpus.py), as one list of :class:`Item`."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class Item:
    """One labelled shape: ``key`` unique ("psb:12", "corpus:stepped_shaft_003"), ``group`` its
    category or family, ``kind`` "psb", "organic" or "mechanical", ``truths`` the paths of its
    part labellings (one .seg per human, or the corpus' one truth)."""

    key: str
    group: str
    kind: str
    mesh_path: Path
    truths: tuple = field(default_factory=tuple)

    @property
    def source(self) -> str:
        return self.key.split(":", 1)[0]


def psb_items(root=None) -> list[Item]:
    from torchakvf.evaluate import psb as P

    root = P.default_psb_root() if root is None else Path(root)
    return [Item(f"psb:{e.mesh_id}", e.category, "psb", Path(e.mesh_path), tuple(Path(s) for s in e.seg_paths))
            for e in P.find_psb_meshes(root) if e.has_gt]


def corpus_items(root) -> list[Item]:
    root = Path(root)
    index = json.loads((root / "index.json").read_text())
    shapes = index["shapes"] if isinstance(index, dict) else index
    out = []
    for s in shapes:
        stem = root / s["family"] / s["name"]
        out.append(Item(f"corpus:{s['name']}", s["family"], s["kind"], stem.with_suffix(".off"),
                        (stem.with_suffix(".seg"),)))
    return out


def read_truth(path: Path) -> np.ndarray:
    from torchakvf.evaluate import psb as P

    return np.asarray(P.read_seg(path), dtype=np.int64)


def items(psb: bool = True, corpus=None) -> list[Item]:
    out = psb_items() if psb else []
    if corpus:
        out += corpus_items(corpus)
    return out
