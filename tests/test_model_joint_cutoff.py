"""A learned model's loop filters per joint ([controller.jointN] model_cutoff; collect/loop_models.py,
collect/model_reaction.py; docs/collect.md "A velocity floor for heavy poses"): a joint with its own
cutoff has its applied torque and its model inputs filtered, two lags, at that cutoff; the others keep
controller.model_cutoff or, without it, the model's training cutoffs; 0 everywhere (the default) is the
path without the option."""

from __future__ import annotations

import numpy as np
import pytest

from collect.config import load_config
from collect.loop_models import ArmModel, reaction_factories
from collect.model_reaction import ModelReaction
from crane_io.description import default_arm
from crane_io.errors import ConfigError
from train.data.filters import lowpass, pseudo_diff

RATE = 500.0
NAMES = ("joint1", "joint2", "joint4")
ARM_NAMES = default_arm().joint_names


class LinearModel:
    """tau = a q + b dq + c ddq per joint (a stand-in for crane_io.physics.loop_model.LoopModel)."""

    def __init__(self, cutoff=25.0, diff=20.0):
        self.joint_names = NAMES
        self.preprocessing = {"cutoff_rad_s": cutoff, "pseudo_diff_rad_s": diff, "zero_phase": False}

    def predict_one(self, q, dq, ddq, out=None):
        return 1.0 * q + 0.5 * dq + 0.1 * ddq


def _signals(n=400, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / RATE
    q = np.sin(2 * np.pi * 0.7 * t)[:, None] * rng.uniform(0.2, 1.0, 3) + rng.normal(0, 1e-3, (n, 3))
    tau = np.cos(2 * np.pi * 0.4 * t)[:, None] * rng.uniform(0.5, 2.0, 3) + rng.normal(0, 0.05, (n, 3))
    return q, tau


def _factory(tmp_path, text):
    path = tmp_path / "c.toml"
    path.write_text(text)
    model = LinearModel()
    make = reaction_factories({"follower": ArmModel("follower", model, np.full(3, 100.0))}, default_arm(),
                              load_config(path))
    return make["follower"]


def _out(reaction, q, tau):
    """The reaction torque (N, 3) for the model joints' q and applied tau (N, 3), given in arm order."""
    n = len(ARM_NAMES)

    def arm(x):
        full = np.zeros(n)
        full[reaction.idx] = x
        return full

    return np.array([reaction.update(arm(q[k]), arm(tau[k - 1] if k else tau[0]))[0].copy()
                     for k in range(len(q))])


def test_a_joint_cutoff_filters_that_joint_alone_at_its_cutoff(tmp_path):
    make = _factory(tmp_path, "[controller]\nmodel_cutoff = 40.0\n[controller.joint2]\nmodel_cutoff = 50.0\n")
    made = make()
    assert made.filters.w == made.filters.g == 40.0  # joints 1 and 4; joint 2 on filters of its own
    [(mask, f, _)] = made._extra
    assert mask.tolist() == [False, True, False] and f.w == f.g == 50.0
    q, tau = _signals()
    got = _out(make(), q, tau)
    for j, c in enumerate((40.0, 50.0, 40.0)):  # per joint: the two-lag path at its own cutoff
        d = pseudo_diff(q[:, j], c, RATE)
        qm = lowpass(lowpass(q[:, j], c, RATE), c, RATE)
        dqm, ddqm = lowpass(d, c, RATE), pseudo_diff(d, c, RATE)
        prev = np.r_[tau[:1, j], tau[:-1, j]]
        want = lowpass(lowpass(prev, c, RATE), c, RATE)[1:] - (qm[:-1] + 0.5 * dqm[:-1] + 0.1 * ddqm[:-1])
        np.testing.assert_allclose(got[1:, j], want, rtol=1e-9, atol=1e-9)
    # joint 1 and joint 4 exactly as with controller.model_cutoff alone; joint 2 not
    alone = _out(ModelReaction(LinearModel(), ARM_NAMES, np.full(3, 100.0), RATE, cutoff=40.0), q, tau)
    assert np.array_equal(got[:, [0, 2]], alone[:, [0, 2]])
    assert not np.allclose(got[:, 1], alone[:, 1], atol=1e-6)


class CoupledModel(LinearModel):
    """Every joint's torque depends on every joint's signals (as a rigid body's does)."""

    def predict_one(self, q, dq, ddq, out=None):
        return q.sum() + 0.5 * dq.sum() + 0.1 * ddq.sum() + 0.2 * q


def test_a_coupled_model_sees_each_joints_inputs_at_that_joints_cutoff(tmp_path):
    """Joint 1's prediction must not take joint 2's inputs at joint 2's cutoff: the model runs once per
    cutoff, and joints 1 and 4 get exactly the reaction of the single-cutoff loop."""
    q, tau = _signals()
    per = ModelReaction(CoupledModel(), ARM_NAMES, np.full(3, 100.0), RATE,
                        cutoff=(np.array([40.0, 50.0, 40.0]), np.array([40.0, 50.0, 40.0])))
    got = _out(per, q, tau)
    at40 = _out(ModelReaction(CoupledModel(), ARM_NAMES, np.full(3, 100.0), RATE, cutoff=40.0), q, tau)
    at50 = _out(ModelReaction(CoupledModel(), ARM_NAMES, np.full(3, 100.0), RATE, cutoff=50.0), q, tau)
    assert np.array_equal(got[:, [0, 2]], at40[:, [0, 2]]) and np.array_equal(got[:, 1], at50[:, 1])


def test_without_controller_model_cutoff_the_other_joints_keep_the_models_own(tmp_path):
    made = _factory(tmp_path, "[controller.joint4]\nmodel_cutoff = 45.0\n")()
    assert (made.filters.w, made.filters.g) == (25.0, 20.0)
    [(mask, f, _)] = made._extra
    assert mask.tolist() == [False, False, True] and f.w == f.g == 45.0


def test_the_default_is_the_path_without_the_option(tmp_path):
    assert all(g.model_cutoff == 0.0 for g in load_config().controller.joints.values())
    q, tau = _signals()
    for text, scalar in (("", None), ("[controller]\nmodel_cutoff = 40.0\n", 40.0)):
        made = _factory(tmp_path, text)()
        assert np.ndim(made.filters.w) == 0  # a scalar cutoff, as before
        ref = ModelReaction(LinearModel(), ARM_NAMES, np.full(3, 100.0), RATE, cutoff=scalar)
        assert np.array_equal(_out(made, q, tau), _out(ref, q, tau))
    path = tmp_path / "bad.toml"
    path.write_text("[controller.joint2]\nmodel_cutoff = -1.0\n")
    with pytest.raises(ConfigError, match="controller.joint2.model_cutoff"):
        load_config(path)
