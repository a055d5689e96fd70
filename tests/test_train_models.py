"""Models of crane-train: RLS rigid-body fit, MLPs (batched and plain), registry, save/load."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from crane_io.errors import CraneError
from train.data.dataset import Dataset
from train.evaluation.metrics import mse, nmse
from train.models.base import ModelFileError
from train.models.batched import MLPSettings, train_mlps, train_plain
from train.models.registry import METHODS, load_model, make_model
from train.models.rigid_body import RigidBodyModel, rls

JOINTS = ("joint1", "joint2", "joint4")
torch.set_num_threads(1)  # tiny nets: threads only add overhead on the shared 2-core machine


def _random_states(n, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(-1, 1, (n, 3)), rng.uniform(-2, 2, (n, 3)), rng.uniform(-10, 10, (n, 3))


@pytest.fixture(scope="module")
def arm():
    from crane_io.physics.dynamics import ArmDynamics
    return ArmDynamics(joints=JOINTS)


def _ds(q, dq, ddq, tau, moving=None):
    moving = np.ones(q.shape, bool) if moving is None else moving
    return Dataset(JOINTS, np.arange(len(q)) * 0.02, q, dq, ddq, tau, moving, 50.0)


def test_rls_equals_least_squares_row_by_row_and_in_blocks():
    rng = np.random.default_rng(1)
    Phi = rng.normal(size=(300, 3, 6)) * np.array([1, 2, 0.5, 1, 1.5, 1])  # the model scales columns
    y = Phi @ rng.normal(size=6) + rng.normal(0, 0.1, (300, 3))
    lstsq = np.linalg.lstsq(Phi.reshape(-1, 6), y.ravel(), rcond=None)[0]
    for block in (1, 7, 64):
        theta, P = rls(Phi, y, block=block)
        assert theta == pytest.approx(lstsq, rel=1e-5, abs=1e-7)  # 1/p0 regularisation
    cov = np.linalg.inv(Phi.reshape(-1, 6).T @ Phi.reshape(-1, 6))
    assert P == pytest.approx(cov, rel=1e-3, abs=1e-3 * np.abs(cov).max())


def test_rigid_body_recovers_base_parameters_from_noiseless_data(arm):
    q, dq, ddq = _random_states(400, 2)
    tau = arm.inverse_dynamics(q, dq, ddq)
    moving = np.ones((400, 3), bool)
    moving[::3, 1] = False  # samples where a joint sticks are left out of the fit
    tau_bad = tau.copy()
    tau_bad[::3] += 5.0  # ... so corrupting them changes nothing
    model = RigidBodyModel(JOINTS).fit(_ds(q, dq, ddq, tau_bad, moving))
    assert model.theta == pytest.approx(arm.base_parameters(), rel=1e-6, abs=1e-9)
    table = model.parameters_table()
    assert [r["name"] for r in table] == arm.base_parameter_names()
    assert all(r["stderr"] < 1e-6 for r in table)
    q2, dq2, ddq2 = _random_states(50, 3)
    assert model.predict(q2, dq2, ddq2) == pytest.approx(arm.inverse_dynamics(q2, dq2, ddq2), abs=1e-8)


def test_rigid_body_with_effects_recovers_friction_and_picks_the_shape(arm):
    q, dq, ddq = _random_states(500, 4)
    tau = arm.inverse_dynamics(q, dq, ddq) + np.array([0.1, 0.2, 0.15]) * np.sign(dq)
    model = RigidBodyModel(JOINTS, effects=[("coulomb", None, None)]).fit(_ds(q, dq, ddq, tau))
    values = {v["joint"]: v["values"]["coulomb"] for v in model.effect_values()}
    assert values == pytest.approx({"joint1": 0.1, "joint2": 0.2, "joint4": 0.15}, abs=1e-6)
    assert len(model.names) == arm.n_base + 3
    with pytest.raises(CraneError, match="not one of the learning joints"):
        RigidBodyModel(JOINTS, effects=[("coulomb", "joint7", None)]).fit(_ds(q, dq, ddq, tau))


def _mlp_data(arm, n=1500, seed=5):
    q, dq, ddq = _random_states(n, seed)
    tau = arm.inverse_dynamics(q, dq, ddq)
    rng = np.random.default_rng(seed)
    moving = rng.random((n, 3)) < 0.75
    tau_obs = np.where(moving, tau, tau + rng.normal(0, 1.0, tau.shape))  # garbage while stuck
    return _ds(q, dq, ddq, tau_obs, moving), tau


def test_batched_m1_matches_a_plain_torch_loop(arm):
    ds, _ = _mlp_data(arm, 600)
    X = np.hstack([ds.q, ds.dq, ds.ddq])
    rows = np.arange(400)
    s = MLPSettings(epochs=8)
    a = train_mlps(X, ds.tau, ds.moving, [rows], X[500:], ds.tau[500:], s, seeds=[11])
    b = train_plain(X, ds.tau, ds.moving, rows, X[500:], ds.tau[500:], s, seed=11)
    assert a.train_loss[:, 0] == pytest.approx(b.train_loss[:, 0], rel=1e-3)
    assert a.val_mse[:, 0] == pytest.approx(b.val_mse[:, 0], rel=1e-3)
    assert a.best_epoch[0] == b.best_epoch[0]


def test_batched_models_of_different_sizes_train_independently(arm):
    ds, _ = _mlp_data(arm, 600)
    X = np.hstack([ds.q, ds.dq, ds.ddq])
    s = MLPSettings(epochs=5)
    rows = [np.arange(100), np.arange(50, 450), np.arange(0, 300, 2)]
    together = train_mlps(X, ds.tau, ds.moving, rows, X[500:], ds.tau[500:], s, seeds=[1, 2, 3])
    alone = train_mlps(X, ds.tau, ds.moving, rows[1:2], X[500:], ds.tau[500:], s, seeds=[2])
    assert together.val_mse[:, 1] == pytest.approx(alone.val_mse[:, 0], rel=1e-3)
    assert together.params["W1"].shape == (3, 9, 64)


def test_masked_mlp_fits_and_beats_mse_on_the_same_samples(arm):
    ds, clean = _mlp_data(arm, 1100)
    train, val, test = ds.subset(np.arange(600)), ds.subset(np.arange(600, 850)), ds.subset(
        np.arange(850, 1100))
    scores = {}
    for method in ("mlp-masked", "mlp-mse"):
        model = make_model(method, JOINTS, epochs=25, seed=0).fit(train, val)
        pred = model.predict_dataset(test)
        scores[method] = nmse(clean[850:], pred).mean()
        assert 0 <= model.history["best_epoch"] < 25
    assert scores["mlp-masked"] < 0.1
    assert scores["mlp-masked"] < scores["mlp-mse"] * 1.2


@pytest.mark.parametrize("method", ["rigid-body", "mlp-masked", "mlp-mse"])
def test_save_load_round_trip_predicts_identically(arm, tmp_path, method):
    ds, _ = _mlp_data(arm, 400)
    options = {"epochs": 3} if method.startswith("mlp") else {"effects": [("viscous", None, None)]}
    model = make_model(method, JOINTS, **options)
    model.fit(ds.subset(np.arange(300)), ds.subset(np.arange(300, 400)))
    model.save(tmp_path / "m")
    loaded = load_model(tmp_path / "m")
    assert loaded.method == method and loaded.joint_names == JOINTS
    assert np.array_equal(loaded.predict(ds.q, ds.dq, ds.ddq), model.predict(ds.q, ds.dq, ds.ddq))
    assert mse(ds.tau, loaded.predict_dataset(ds)).shape == (3,)


def test_registry_errors_are_sentences(tmp_path):
    assert set(METHODS) == {"rigid-body", "mlp-mse", "mlp-masked", "hybrid"}
    with pytest.raises(CraneError, match="unknown model method 'svm'"):
        make_model("svm", JOINTS)
    with pytest.raises(ModelFileError, match="not a crane-x7 model directory"):
        load_model(tmp_path)
    (tmp_path / "model.json").write_text("{broken")
    with pytest.raises(ModelFileError, match="corrupt"):
        load_model(tmp_path)
