"""The learned-model reaction torque of collect/model_reaction.py: the loop's causal filters are the
training's (train/data/preprocess.py) sample for sample, the pairing is one cycle back, unusable predictions
fall back per joint, and the controller uses it only on the model's joints."""

from __future__ import annotations

import numpy as np
import pytest

from collect.config import load_config
from collect.controller import ArmSignals, BilateralController
from collect.model_reaction import ModelInputs, ModelReaction
from crane_io.description import default_arm
from train.data.filters import lowpass, pseudo_diff

RATE = 500.0


class LinearModel:
    """A stand-in for crane_io.physics.loop_model.LoopModel: tau = a q + b dq + c ddq per joint."""

    def __init__(self, joint_names, a=1.0, b=0.5, c=0.1, cutoff=25.0, diff=25.0):
        self.joint_names = tuple(joint_names)
        self.preprocessing = {"cutoff_rad_s": cutoff, "pseudo_diff_rad_s": diff, "zero_phase": False}
        self.a, self.b, self.c = a, b, c
        self.calls = []

    def predict_one(self, q, dq, ddq, out=None):
        self.calls.append((q.copy(), dq.copy(), ddq.copy()))
        return self.a * q + self.b * dq + self.c * ddq


def _signals(n=400, j=3, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / RATE
    q = np.sin(2 * np.pi * 0.7 * t)[:, None] * rng.uniform(0.2, 1.0, j) + rng.normal(0, 1e-3, (n, j))
    tau = np.cos(2 * np.pi * 0.4 * t)[:, None] * rng.uniform(0.5, 2.0, j) + rng.normal(0, 0.05, (n, j))
    return q, tau


@pytest.mark.parametrize(("cutoff", "diff"), [(25.0, 25.0), (30.0, 18.0)])
def test_loop_filters_equal_the_training_preprocessing(cutoff, diff):
    q, tau = _signals()
    model = LinearModel(("a", "b", "c"), cutoff=cutoff, diff=diff)
    inputs = ModelInputs(ModelReaction(model, ("a", "b", "c"), np.full(3, 10.0), RATE).filters)
    rows = []
    for k in range(len(q)):
        inputs.push(q[k], tau[k])
        rows.append((inputs.q.copy(), inputs.dq.copy(), inputs.ddq.copy(), inputs.tau.copy()))
    got = [np.array(x) for x in zip(*rows)]
    d = pseudo_diff(q, diff, RATE)
    want = (lowpass(lowpass(q, cutoff, RATE), cutoff, RATE), lowpass(d, cutoff, RATE),
            pseudo_diff(d, diff, RATE), lowpass(lowpass(tau, cutoff, RATE), cutoff, RATE))
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, rtol=1e-9, atol=1e-9)


def test_reaction_pairs_the_previous_cycles_torque_with_its_own_prediction():
    names = ("joint1", "joint2", "joint4")
    q, tau = _signals()
    model = LinearModel(names)
    reaction = ModelReaction(model, names, np.full(3, 100.0), RATE)
    out = [reaction.update(q[k], tau[k - 1] if k else tau[0])[0].copy() for k in range(len(q))]
    # reference: the training's filtered signals, row k-1 of each, through the same model
    d = pseudo_diff(q, 25.0, RATE)
    qm = lowpass(lowpass(q, 25.0, RATE), 25.0, RATE)
    dqm, ddqm = lowpass(d, 25.0, RATE), pseudo_diff(d, 25.0, RATE)
    prev_tau = np.vstack([tau[:1], tau[:-1]])
    taum = lowpass(lowpass(prev_tau, 25.0, RATE), 25.0, RATE)
    want = taum[1:] - (qm[:-1] + 0.5 * dqm[:-1] + 0.1 * ddqm[:-1])
    np.testing.assert_allclose(np.array(out)[1:], want, rtol=1e-9, atol=1e-9)


def test_unusable_prediction_falls_back_for_that_joint_only():
    names = ("joint1", "joint2", "joint4")

    class Broken(LinearModel):
        def predict_one(self, q, dq, ddq, out=None):
            y = super().predict_one(q, dq, ddq)
            y[1] = np.nan if len(self.calls) % 2 else 1e6
            return y

    reaction = ModelReaction(Broken(names), names, np.full(3, 5.0), RATE)
    for _ in range(5):
        res, ok = reaction.update(np.zeros(3), np.zeros(3))
        assert ok.tolist() == [True, False, True]
        assert np.isfinite(res).all()
    assert reaction.fallback_cycles.tolist() == [0, 5, 0]


def _controller(models=None):
    config = load_config()
    return BilateralController(config, default_arm(), models=models), config


def test_controller_uses_the_model_only_on_its_joints_and_keeps_the_nominal_elsewhere():
    arm = default_arm()
    n = len(arm.joints)
    nominal, _ = _controller()
    model = LinearModel(("joint2",), a=0.0, b=0.0, c=0.0)  # says the arm needs no torque at all
    make = {"follower": lambda: ModelReaction(model, arm.joint_names, np.array([50.0]), RATE)}
    learned, _ = _controller(make)
    rng = np.random.default_rng(1)
    q0 = np.zeros(n)
    q0[arm.joint_names.index("joint2")] = 0.4
    for _ in range(200):
        ql = q0 + rng.normal(0, 1e-3, n)
        qf = q0 + rng.normal(0, 1e-3, n)
        for ctl in (nominal, learned):
            ctl.step(ArmSignals(ql), ArmSignals(qf), 1.0 / RATE)
    i2 = arm.joint_names.index("joint2")
    others = [arm.joint_names.index(j) for j in ("joint1", "joint4")]
    # joints 1 and 4 are untouched on both arms (the law is per joint); joint2's reaction differs
    np.testing.assert_array_equal(nominal.leader.tau_res[others], learned.leader.tau_res[others])
    np.testing.assert_array_equal(nominal.follower.tau_res[others], learned.follower.tau_res[others])
    assert abs(nominal.follower.tau_res[i2] - learned.follower.tau_res[i2]) > 0.1  # gravity is not subtracted
    assert learned.model_fallbacks()["follower"].tolist() == [False]
    assert learned.reaction("leader") is None and learned.reaction("follower") is not None


def test_a_joint_inside_the_dead_zone_is_given_zero_velocity():
    names = ("joint1", "joint2", "joint4")
    model = LinearModel(names, a=0.0, b=1.0, c=0.0)
    model.preprocessing["dead_zone_rad_s"] = [0.05, 0.05, 1e9]  # joint4: always inside
    reaction = ModelReaction(model, names, np.full(3, 100.0), RATE)
    t = np.arange(300) / RATE
    for k in range(len(t)):  # joint1 moves at 0.5 rad/s, joint2 creeps at 0.01 rad/s, joint4 moves
        reaction.update(np.array([0.5 * t[k], 0.01 * t[k], 0.5 * t[k]]), np.zeros(3))
    _, dq, _ = model.calls[-1]
    assert dq[0] == pytest.approx(0.5, rel=0.05)  # moving: the filtered velocity as it is
    assert dq[1] == 0.0 and dq[2] == 0.0  # inside the dead zone: standing
    assert reaction.inputs.dq[1] == pytest.approx(0.01, rel=0.05)  # (the filter itself still sees it)


def test_outside_the_training_poses_every_joint_of_the_model_falls_back():
    names = ("joint1", "joint2", "joint4")
    model = LinearModel(names)
    model.preprocessing["input_range"] = {"q_min": [-1.0, -1.0, -2.0], "q_max": [1.0, 1.0, 0.0]}
    reaction = ModelReaction(model, names, np.full(3, 100.0), RATE)
    for _ in range(50):  # joint2 at 1.05 rad: outside the data (1.0) but inside the margin (0.1 rad)
        _, ok = reaction.update(np.array([0.0, 1.05, -1.0]), np.zeros(3))
    assert ok.all() and not reaction.out_of_range
    for _ in range(400):  # lying at -1.6 rad: far outside; the filtered angle gets there after a while
        _, ok = reaction.update(np.array([0.0, -1.6, -1.0]), np.zeros(3))
    assert not ok.any() and reaction.out_of_range
    cycles = reaction.fallback_cycles
    assert cycles.min() > 300  # every joint of the model, from soon after the step on (joint2's own
    # prediction also left its limit for a few cycles during the step: measured 338, 343, 338)


def test_a_late_cycle_is_filtered_for_the_time_that_really_passed():
    """A loop at half its rate (every cycle 4 ms instead of 2): the model's velocity of a ramp is still
    the ramp's slope in rad/s (with the nominal coefficients it would read twice as much), and at the
    nominal period the result is bit for bit the same as without dt."""
    speed = 0.8  # rad/s
    names = ("a", "b", "c")

    def run(dt, given):
        reaction = ModelReaction(LinearModel(names), names, np.full(3, 10.0), RATE)
        for k in range(2000):
            q = np.full(3, speed * k * dt)
            reaction.update(q, np.zeros(3), dt if given else None)
        return reaction.inputs.dq

    assert np.allclose(run(0.004, True), speed, rtol=1e-6)
    assert np.allclose(run(0.004, False), 2 * speed, rtol=1e-6)  # what the fixed coefficients read
    assert np.array_equal(run(1 / RATE, True), run(1 / RATE, False))


def test_the_controllers_coulomb_velocity_reaches_the_model_and_is_checked(tmp_path):
    from collect.config import load_config as load
    from collect.loop_models import ArmModel, reaction_factories
    from crane_io.errors import ConfigError

    class Smoothable(LinearModel):
        coulomb_velocity = 0.0

        def set_coulomb_velocity(self, v0):
            self.coulomb_velocity = v0

    arm = default_arm()
    model = Smoothable(("joint2",))
    assert load().controller.model_coulomb_velocity == 0.0  # off by default
    reaction_factories({"follower": ArmModel("follower", model, np.array([50.0]))}, arm, load())
    assert model.coulomb_velocity == 0.0
    path = tmp_path / "c.toml"
    path.write_text("[controller]\nmodel_coulomb_velocity = 0.1\n")
    reaction_factories({"follower": ArmModel("follower", model, np.array([50.0]))}, arm, load(path))
    assert model.coulomb_velocity == 0.1
    path.write_text("[controller]\nmodel_coulomb_velocity = -0.1\n")
    with pytest.raises(ConfigError, match="controller.model_coulomb_velocity"):
        load(path)


def test_with_the_smooth_coulomb_sign_the_dead_zone_is_not_applied():
    names = ("joint1", "joint2", "joint4")
    runs = {}
    for v0 in (0.0, 0.1):
        model = LinearModel(names, a=0.0, b=1.0, c=0.0)
        model.coulomb_velocity = v0  # as LoopModel.set_coulomb_velocity records it
        model.preprocessing["dead_zone_rad_s"] = [0.05, 0.05, 0.05]
        reaction = ModelReaction(model, names, np.full(3, 100.0), RATE)
        t = np.arange(300) / RATE
        for k in range(len(t)):  # joint2 creeps at 0.01 rad/s, inside the dead zone
            reaction.update(np.array([0.5 * t[k], 0.01 * t[k], 0.0]), np.zeros(3))
        runs[v0] = model.calls[-1][1]
    assert runs[0.0][1] == 0.0  # the dead zone as fitted
    assert runs[0.1][1] == pytest.approx(0.01, rel=0.05)  # the smooth sign: the velocity as it is
    assert runs[0.1][0] == runs[0.0][0]  # a moving joint is not affected


# ---- "observer" filters (`[controller] model_filters = "observer"`): the nominal observer's one lag ----
G = np.array([15.0, 15.0, 20.0])  # the default observer cutoffs of joint1, joint2, joint4


def _columns(fn, x, cutoffs):
    return np.column_stack([fn(x[:, [j]], c, RATE)[:, 0] for j, c in enumerate(cutoffs)])


def test_observer_filters_are_one_lag_of_g_on_the_torque_and_the_training_structure_at_2g_on_the_inputs():
    names = ("joint1", "joint2", "joint4")
    q, tau = _signals()
    model = LinearModel(names)
    reaction = ModelReaction(model, names, np.full(3, 100.0), RATE, one_lag=G)
    out = [reaction.update(q[k], tau[k - 1] if k else tau[0])[0].copy() for k in range(len(q))]
    # reference: the model on the training's filters at 2 g (train.data.filters), row k-1; the applied
    # torque (the previous cycle's) through one first-order low-pass at g
    d = _columns(pseudo_diff, q, 2 * G)
    qm = _columns(lowpass, _columns(lowpass, q, 2 * G), 2 * G)
    dqm, ddqm = _columns(lowpass, d, 2 * G), _columns(pseudo_diff, d, 2 * G)
    prev_tau = np.vstack([tau[:1], tau[:-1]])
    want = _columns(lowpass, prev_tau, G)[1:] - (qm[:-1] + 0.5 * dqm[:-1] + 0.1 * ddqm[:-1])
    np.testing.assert_allclose(np.array(out)[1:], want, rtol=1e-9, atol=1e-9)


def test_observer_filters_pass_a_contact_step_through_one_lag_faster_than_the_training_filters():
    """A step of outside torque at a standstill (the joint pressed against a wall: the applied torque
    steps, the angles stay): with the observer filters tau_res follows the first-order step response
    1 - exp(-g t) of the nominal observer; with the training filters (two lags at 25 rad/s) it lags."""
    names = ("joint1", "joint2", "joint4")
    runs = {}
    for one_lag in (None, G):
        reaction = ModelReaction(LinearModel(names, a=0.0, b=0.0, c=0.0), names, np.full(3, 100.0), RATE,
                                 one_lag=one_lag)
        rows = []
        for k in range(200):
            rows.append(reaction.update(np.zeros(3), np.full(3, 1.0 if k >= 10 else 0.0))[0].copy())
        runs[one_lag is None] = np.array(rows)
    # the torque applied in cycle 9 (passed to cycle 10) steps: tau_res responds from cycle 10 on; the
    # Tustin low-pass of a step is the continuous response half a sample later
    t = (np.arange(200) - 10 + 0.5) / RATE
    after = t > 0.0
    want = 1.0 - np.exp(-G[None, :] * t[after, None])
    np.testing.assert_allclose(runs[False][after], want, atol=0.02)  # Tustin vs continuous: < 2 %
    at = int(np.argmin(np.abs(t - 0.03)))  # 30 ms after the step
    assert (runs[False][at] > 1.8 * runs[True][at]).all(), (runs[False][at], runs[True][at])
    # measured 0.37 / 0.37 / 0.46 against 0.18


def test_the_controllers_model_filters_option_reaches_the_reaction_and_is_checked(tmp_path):
    from collect.config import load_config as load
    from collect.loop_models import ArmModel, reaction_factories
    from crane_io.errors import ConfigError

    arm = default_arm()
    model = LinearModel(("joint1", "joint2", "joint4"))
    assert load().controller.model_filters == "training"  # the default: the model's own filters
    make = reaction_factories({"follower": ArmModel("follower", model, np.full(3, 50.0))}, arm, load())
    assert make["follower"]().one_lag is None
    path = tmp_path / "c.toml"
    path.write_text('[controller]\nmodel_filters = "observer"\n\n[controller.joint4]\ncutoff = 18.0\n')
    make = reaction_factories({"follower": ArmModel("follower", model, np.full(3, 50.0))}, arm, load(path))
    reaction = make["follower"]()
    assert reaction.one_lag.tolist() == [15.0, 15.0, 18.0]  # each joint's observer cutoff g
    assert np.allclose(reaction.filters.w, [30.0, 30.0, 36.0])  # the model's inputs at 2 g
    path.write_text('[controller]\nmodel_filters = "fast"\n')
    with pytest.raises(ConfigError, match="controller.model_filters"):
        load(path)


@pytest.mark.parametrize("one_lag", [None, G])
def test_unusable_prediction_falls_back_with_either_filters(one_lag):
    names = ("joint1", "joint2", "joint4")

    class Broken(LinearModel):
        def predict_one(self, q, dq, ddq, out=None):
            y = super().predict_one(q, dq, ddq)
            y[2] = np.inf
            return y

    reaction = ModelReaction(Broken(names), names, np.full(3, 5.0), RATE, one_lag=one_lag)
    for _ in range(5):
        res, ok = reaction.update(np.zeros(3), np.ones(3))
        assert ok.tolist() == [True, True, False] and np.isfinite(res).all()
    assert reaction.fallback_cycles.tolist() == [0, 0, 5]


def test_observer_filters_follow_a_late_cycle_in_real_time():
    speed = 0.8  # rad/s, a ramp sampled every 4 ms: the model's velocity is still the slope
    names = ("a", "b", "c")
    reaction = ModelReaction(LinearModel(names), names, np.full(3, 10.0), RATE, one_lag=G)
    for k in range(2000):
        reaction.update(np.full(3, speed * k * 0.004), np.ones(3), 0.004)
    assert np.allclose(reaction.inputs.dq, speed, rtol=1e-6)
    assert np.allclose(reaction._u_lag, 1.0)


def test_a_loop_cutoff_replaces_the_training_cutoffs_on_both_sides(tmp_path):
    """`[controller] model_cutoff = c`: the training's filter structure, two lags, at c rad/s for the low-pass
    and the pseudo-derivative alike, on the applied torque and on the model's inputs."""
    from collect.config import load_config as load
    from collect.loop_models import ArmModel, reaction_factories
    from crane_io.errors import ConfigError

    names = ("joint1", "joint2", "joint4")
    q, tau = _signals()
    model = LinearModel(names, cutoff=25.0, diff=20.0)
    path = tmp_path / "c.toml"
    path.write_text("[controller]\nmodel_cutoff = 40.0\n")
    make = reaction_factories({"follower": ArmModel("follower", model, np.full(3, 100.0))}, default_arm(),
                              load(path))
    assert make["follower"]().filters.w == make["follower"]().filters.g == 40.0  # the option reaches it
    reaction = ModelReaction(model, names, np.full(3, 100.0), RATE, cutoff=40.0)
    out = [reaction.update(q[k], tau[k - 1] if k else tau[0])[0].copy() for k in range(len(q))]
    c = 40.0
    d = pseudo_diff(q, c, RATE)
    qm = lowpass(lowpass(q, c, RATE), c, RATE)
    dqm, ddqm = lowpass(d, c, RATE), pseudo_diff(d, c, RATE)
    prev_tau = np.vstack([tau[:1], tau[:-1]])
    want = lowpass(lowpass(prev_tau, c, RATE), c, RATE)[1:] - (qm[:-1] + 0.5 * dqm[:-1] + 0.1 * ddqm[:-1])
    np.testing.assert_allclose(np.array(out)[1:], want, rtol=1e-9, atol=1e-9)
    assert load().controller.model_cutoff == 0.0  # the default: the model's own cutoffs
    assert ModelReaction(model, names, np.full(3, 100.0), RATE).filters.w == 25.0
    path.write_text("[controller]\nmodel_cutoff = -5.0\n")
    with pytest.raises(ConfigError, match="controller.model_cutoff"):
        load(path)
