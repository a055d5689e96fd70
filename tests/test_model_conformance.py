"""Every model class follows the same conventions (scikit-learn's, where they fit): parameters only in
the constructor (`get_params()` rebuilds an unfitted copy), `fit` returns the model and leaves its
parameters alone, `is_fitted`, one-sentence NotFittedError before fitting, SI arrays in and out, and a
save/load round trip that predicts identically."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from train.data.dataset import Dataset
from train.models.base import NotFittedError
from train.models.registry import METHODS, load_model, make_model

JOINTS = ("joint1", "joint2", "joint4")
PRE = {"rate_hz": 50.0, "cutoff_rad_s": 25.0, "pseudo_diff_rad_s": 25.0, "zero_phase": False}
OPTIONS = {"rigid-body": {"effects": [["viscous", None, None]]},
           "mlp-mse": {"epochs": 2, "seed": 1}, "mlp-masked": {"epochs": 2, "seed": 1},
           "hybrid": {"effects": [["coulomb", "joint2", None]], "epochs": 2, "seed": 1}}
torch.set_num_threads(1)


@pytest.fixture(scope="module")
def data():
    from crane_io.physics.dynamics import ArmDynamics

    rng = np.random.default_rng(7)
    n = 600
    q, dq, ddq = rng.uniform(-1, 1, (n, 3)), rng.uniform(-2, 2, (n, 3)), rng.uniform(-10, 10, (n, 3))
    tau = ArmDynamics(joints=JOINTS).inverse_dynamics(q, dq, ddq) + 0.1 * np.sign(dq)
    moving = rng.random((n, 3)) < 0.8
    ds = Dataset(JOINTS, np.arange(n) * 0.02, q, dq, ddq, tau, moving, 50.0)
    return ds.subset(np.arange(450)), ds.subset(np.arange(450, n))


def test_every_method_is_covered():
    assert set(OPTIONS) == set(METHODS)


@pytest.mark.parametrize("method", sorted(METHODS))
def test_a_model_follows_the_conventions(method, data, tmp_path):
    train, val = data
    model = make_model(method, JOINTS, preprocessing=PRE, **OPTIONS[method])
    params = model.get_params()
    assert not model.is_fitted
    with pytest.raises(NotFittedError, match=f"the {method} model has not been fitted") as info:
        model.predict(train.q, train.dq, train.ddq)
    assert "\n" not in str(info.value)

    copy = type(model)(**params)  # the parameters are all it takes to rebuild it
    assert copy.get_params() == params and copy.method == method and not copy.is_fitted

    assert model.fit(train, val) is model
    assert model.is_fitted and model.get_params() == params  # fit learns, it does not re-parameterise
    pred = model.predict(val.q, val.dq, val.ddq)
    assert pred.shape == val.tau.shape and pred.dtype == np.float64 and np.isfinite(pred).all()

    model.save(tmp_path / "m")
    loaded = load_model(tmp_path / "m")
    assert loaded.is_fitted and loaded.get_params() == params
    np.testing.assert_array_equal(loaded.predict(val.q, val.dq, val.ddq), pred)
