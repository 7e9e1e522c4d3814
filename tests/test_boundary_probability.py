"""torchakvf.parts.boundary_probability: the learned per-face boundary probability."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from torchakvf.errors import ParameterError
from torchakvf.parts import boundary_probability as bp

FIT_SCRIPT = Path(__file__).resolve().parents[1] / "experiments" / "descriptors" / "boundary_probability_fit.py"


def fit_script():
    spec = importlib.util.spec_from_file_location("boundary_probability_fit", FIT_SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_package_model_is_a_small_network_on_the_descriptor_inputs():
    record = json.loads(bp.PACKAGE_FILE.read_text())
    assert tuple(record["inputs"]) == bp.INPUT_NAMES and len(bp.INPUT_NAMES) == 47
    assert bp.INPUT_NAMES[0] == "share1@8" and bp.INPUT_NAMES[33] == "cut_distance@2"
    assert bp.INPUT_NAMES[41] == "concave_edge" and "PSB" not in record["trained_on"]
    w = bp.package_weights()
    assert w is bp.package_weights()                                  # read once
    assert w["layers"][0][0].shape[1] == 47 and w["layers"][-1][0].shape[0] == 1
    assert (w["scale"] > 0).all()


def test_the_model_is_the_torch_network_it_was_fitted_as():
    """apply_model against the same network built in torch (standardize, ReLU layers, sigmoid)."""
    w = bp.package_weights()
    x = np.random.default_rng(0).normal(size=(500, 47)) * w["scale"] + w["mean"]
    layers = []
    for weight, bias in w["layers"]:
        lin = torch.nn.Linear(weight.shape[1], weight.shape[0]).double()
        lin.weight.data, lin.bias.data = torch.as_tensor(weight), torch.as_tensor(bias)
        layers += [lin, torch.nn.ReLU()]
    net = torch.nn.Sequential(*layers[:-1])
    want = torch.sigmoid(net(torch.as_tensor((x - w["mean"]) / w["scale"])))[:, 0].detach().numpy()
    got = bp.boundary_probability(x[:, :41], x[:, 41:])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
    assert ((got > 0) & (got < 1)).all() and got.std() > 0.01
    # far outside the training range the logistic saturates without overflow
    assert np.isfinite(bp.apply_model(w, x * 1e6)).all()


def test_the_fit_script_writes_the_package_file_and_fits_the_same_bits_twice(tmp_path):
    fit = fit_script()
    record = json.loads(bp.PACKAGE_FILE.read_text())
    params = bp.read_weights(bp.PACKAGE_FILE)
    again = bp.weights_record(params, record["trained_on"])
    assert again == record
    assert bp.write_weights(again, tmp_path / "w.json") + "\n" == bp.PACKAGE_FILE.read_text()
    assert (tmp_path / "w.json").read_text() == bp.PACKAGE_FILE.read_text()
    assert Path(str(fit.PACKAGE_FILE)).resolve() == Path(str(bp.PACKAGE_FILE)).resolve()
    rng = np.random.default_rng(1)
    x = rng.normal(size=(3000, 47))
    y = (x[:, 0] + 0.5 * x[:, 41] + 0.3 * rng.normal(size=3000) > 1.0).astype(np.float64)
    fit.STEPS = 300
    a, b = fit.fit(x, y, (16,)), fit.fit(x, y, (16,))
    for (wa, ba), (wb, bb) in zip(a["layers"], b["layers"]):
        np.testing.assert_array_equal(wa, wb)
        np.testing.assert_array_equal(ba, bb)
    # a model that learned the rule ranks its positives first
    p = bp.apply_model(bp.model_of_record(bp.weights_record(a, "test")), x)
    assert p[y > 0].mean() > p[y == 0].mean() + 0.3


def test_a_file_for_other_columns_or_other_inputs_is_refused(tmp_path):
    record = json.loads(bp.PACKAGE_FILE.read_text())
    record["inputs"] = record["inputs"][:-1]
    (tmp_path / "w.json").write_text(json.dumps(record))
    with pytest.raises(ParameterError, match="refit"):
        bp.read_weights(tmp_path / "w.json")
    with pytest.raises(ParameterError, match="47 columns"):
        bp.boundary_probability(np.zeros((3, 33)), np.zeros((3, 6)))
