"""train.models.fast_predict: the one-sample float64 numpy path gives each method's own prediction (torch
for the networks) to 1e-6 relative, from the saved and reloaded model, and never imports torch."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from train.data.dataset import Dataset
from train.models.fast_predict import NumpyPredictor, PredictorError
from train.models.registry import load_model, make_model

JOINTS = ("joint1", "joint2", "joint4")
# every built-in effect: the scalar ones and the two that go through the rigid-body dynamics
ALL_EFFECTS = [("coulomb", "joint1", None), ("coulomb-asym", "joint2", None), ("viscous", None, None),
               ("stribeck", "joint4", {"stribeck_velocity": 0.1}), ("stiction", "joint2",
                                                                   {"stiction_velocity": 0.02}),
               ("offset", "joint1", None), ("spring", "joint4", {"rest_angle": 0.25}),
               ("rotor-inertia", "joint4", None), ("cogging", "joint1", {"cycles_per_rev": 6.0}),
               ("backlash", "joint2", {"reversal_velocity": 0.05}), ("payload", None, None),
               ("torque-constant-error", "joint4", None)]


def _states(n, seed, joints=JOINTS):
    from crane_io.physics.dynamics import ArmDynamics

    rng = np.random.default_rng(seed)
    q, dq, ddq = rng.uniform(-1, 1, (n, 3)), rng.uniform(-2, 2, (n, 3)), rng.uniform(-10, 10, (n, 3))
    dq[::7, 1] = 0.0  # exact zeros: sign(0) = 0 must match
    tau = ArmDynamics(joints=joints).inverse_dynamics(q, dq, ddq) + 0.2 * np.sign(dq) + 0.05 * dq
    moving = rng.random((n, 3)) < 0.8
    return Dataset(joints, np.arange(n) * 0.02, q, dq, ddq, tau, moving, 50.0)


def _fit_save_load(method, tmp_path, joints=JOINTS, **options):
    if method != "rigid-body":
        options.update(epochs=3, hidden=16)
    ds = _states(400, 1, joints)
    model = make_model(method, joints, **options).fit(ds, ds)
    return load_model(model.save(tmp_path / method))


def _assert_same(model, joints=JOINTS):
    fast = NumpyPredictor.from_model(model)
    test = _states(200, 2, joints)
    expected = model.predict(test.q, test.dq, test.ddq)
    got = np.array([fast.predict_one(q, dq, ddq).copy() for q, dq, ddq in zip(test.q, test.dq, test.ddq)])
    scale = np.abs(expected).max(axis=0)  # 1e-6 of each joint's torque range
    assert np.all(np.abs(got - expected) <= 1e-6 * np.maximum(np.abs(expected), scale)), \
        np.abs(got - expected).max()
    out = np.empty(len(joints))
    assert fast.predict_one(test.q[0], test.dq[0], test.ddq[0], out=out) is out
    assert out == pytest.approx(expected[0], rel=1e-6, abs=1e-6 * scale.max())


@pytest.mark.parametrize("method", ["mlp-mse", "mlp-masked"])
def test_network_path_equals_torch(method, tmp_path):
    _assert_same(_fit_save_load(method, tmp_path))


def test_rigid_body_path_without_effects(tmp_path):
    model = _fit_save_load("rigid-body", tmp_path)
    assert not NumpyPredictor.from_model(model).paths[0].generic_terms
    _assert_same(model)


def test_rigid_body_path_with_every_builtin_effect(tmp_path):
    model = _fit_save_load("rigid-body", tmp_path, effects=ALL_EFFECTS)
    path = NumpyPredictor.from_model(model).paths[0]
    assert {t[0].name for t in path.generic_terms} == {"payload", "torque-constant-error"}
    _assert_same(model)


def test_rigid_body_path_in_another_joint_order_and_locked_joints(tmp_path):
    joints = ("joint4", "joint1", "joint2")
    model = _fit_save_load("rigid-body", tmp_path, joints, effects=[("coulomb", None, None)],
                           locked={"joint3": 0.3})
    _assert_same(model, joints)


def test_hybrid_path(tmp_path):
    effects = [["viscous", None, None], ["stribeck", "joint2", {"stribeck_velocity": 0.05}]]
    _assert_same(_fit_save_load("hybrid", tmp_path, effects=effects))


def test_a_model_not_fitted_is_refused():
    with pytest.raises(PredictorError, match="not been fitted"):
        NumpyPredictor.from_model(make_model("mlp-masked", JOINTS))
    with pytest.raises(PredictorError, match="not been fitted"):
        NumpyPredictor.from_model(make_model("rigid-body", JOINTS))


def test_the_numpy_path_imports_no_torch():
    code = ("import sys, train.models.fast_predict, crane_io.physics.dynamics; "
            "print('torch' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "False"
