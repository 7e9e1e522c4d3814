"""The package's per-face boundary probability: a small model, fitted on procedural part-labelled
shapes, of whether a part boundary passes within 0.02 (unit-area geodesic) of a face.

Inputs, per face (:data:`INPUT_NAMES`): the 33 field descriptors
(:mod:`torchakvf.fields.descriptors`), the 8 part descriptors
(:mod:`torchakvf.parts.part_descriptors`) and the crease cues (:mod:`torchakvf.parts.boundary_cues`)
of the mesh the fields are solved on. The model: standardization, one ReLU layer, a logistic
output; its weights are the package file ``boundary_weights.json``, written by
``experiments/descriptors/boundary_probability_fit.py`` from the procedural corpus
(:mod:`torchakvf.shapes.procedural`; no PSB mesh or label), read once. Since it reads the crease
cues, it is the package's boundary probability, not a function of the fields alone
(docs/descriptors.md).
"""
from __future__ import annotations

import functools
import json
from importlib.resources import files
from pathlib import Path

import numpy as np

from ..errors import ParameterError
from ..fields.descriptors import descriptor_names
from .boundary_cues import CUE_NAMES
from .part_descriptors import part_descriptor_names

#: The model's input columns, in order: field descriptors at 8, 16, 32 fields, part descriptors, crease cues.
INPUT_NAMES = tuple(descriptor_names((8, 16, 32)) + part_descriptor_names() + list(CUE_NAMES))
#: The column's name among the descriptors.
PROBABILITY_NAME = "boundary_probability"
#: The package's weights file.
PACKAGE_FILE = Path(str(files(__package__) / "boundary_weights.json"))
#: Significant digits the weights file keeps (the fit's own noise is far larger).
DIGITS = 8


def _rounded(a) -> list:
    return np.vectorize(lambda x: float(f"{x:.{DIGITS}g}"), otypes=[float])(np.asarray(a, dtype=np.float64)).tolist()


def weights_record(params: dict, trained_on: str) -> dict:
    """The weights file's content: ``params`` (``mean`` [d], ``scale`` [d], ``layers`` a list of
    (W [out, in], b [out])) rounded to :data:`DIGITS` significant digits, with the input names."""
    return {"trained_on": trained_on, "inputs": list(INPUT_NAMES), "mean": _rounded(params["mean"]),
            "scale": _rounded(params["scale"]),
            "layers": [{"weight": _rounded(w), "bias": _rounded(b)} for w, b in params["layers"]]}


def write_weights(record: dict, path) -> str:
    """Writes ``record`` (:func:`weights_record`) as JSON to ``path``; returns the text (no final newline)."""
    text = json.dumps(record, indent=1)
    Path(path).write_text(text + "\n")
    return text


def model_of_record(record: dict, source: str = "the boundary model") -> dict:
    """{mean, scale, layers} float64 arrays of a weights record (:func:`weights_record`); a
    ParameterError when its inputs are not :data:`INPUT_NAMES`."""
    if tuple(record.get("inputs", ())) != INPUT_NAMES:
        raise ParameterError(f"{source}: the boundary model's inputs are not the package's descriptor columns; "
                             "refit it with experiments/descriptors/boundary_probability_fit.py")
    return {"mean": np.array(record["mean"]), "scale": np.array(record["scale"]),
            "layers": [(np.array(layer["weight"]), np.array(layer["bias"])) for layer in record["layers"]]}


def read_weights(path) -> dict:
    """:func:`model_of_record` of a weights file."""
    return model_of_record(json.loads(Path(path).read_text()), str(path))


@functools.cache
def package_weights() -> dict:
    """The package file's model (:func:`read_weights`), read once."""
    return read_weights(PACKAGE_FILE)


def apply_model(params: dict, x: np.ndarray) -> np.ndarray:
    """[N] float64 probabilities of the model ``params`` (:func:`read_weights`) on inputs x [N, d]."""
    h = (np.asarray(x, dtype=np.float64) - params["mean"]) / params["scale"]
    layers = params["layers"]
    for w, b in layers[:-1]:
        h = np.maximum(h @ w.T + b, 0.0)
    w, b = layers[-1]
    logit = (h @ w.T + b)[:, 0]
    return 0.5 * (1.0 + np.tanh(0.5 * logit))        # the logistic function, without overflow


def boundary_probability(descriptors: np.ndarray, cues: np.ndarray) -> np.ndarray:
    """[F] float64 probability that a part boundary passes within 0.02 of each face, from its
    41 descriptor columns [F, 41] (field then part columns at the default counts) and crease cues
    [F, len(CUE_NAMES)]."""
    x = np.concatenate([np.asarray(descriptors, dtype=np.float64), np.asarray(cues, dtype=np.float64)], axis=1)
    if x.shape[1] != len(INPUT_NAMES):
        raise ParameterError(f"the boundary probability reads {len(INPUT_NAMES)} columns (the default descriptors "
                             f"and crease cues), got {x.shape[1]}")
    return apply_model(package_weights(), x)


__all__ = ["INPUT_NAMES", "PACKAGE_FILE", "PROBABILITY_NAME", "apply_model", "boundary_probability",
           "model_of_record", "package_weights", "read_weights", "weights_record", "write_weights"]
