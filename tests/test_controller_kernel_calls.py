"""BilateralController.control on the compiled backend (collect/controller_kernel.py): the safety limits it
keeps between calls are those of the monitor it is given each call, and its commands (made from the
compiled call's output rows when read) are the numpy backend's, bit for bit; the compiled hand's guard."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("numba")

from collect.config import _build, load_config  # noqa: E402
from collect.controller import ArmSignals, BilateralController, Commands  # noqa: E402
from collect.runner import run_arm  # noqa: E402
from collect.safety import SafetyMonitor  # noqa: E402
from tests.loop_reference import control_reference  # noqa: E402

DT = 0.002
FIELDS = ("leader_tau", "follower_tau", "leader_current", "follower_current")


def _config(joints=None, **safety):
    cfg = load_config()
    if joints is not None:
        cfg = cfg.with_bilateral_joints(joints)
    values = cfg.values
    values["safety"].update(safety)
    return _build(values, "the test")


@pytest.mark.parametrize("joints", [None, "all"])
def test_control_uses_the_limits_of_the_monitor_it_is_given_each_call(joints):
    """Two monitors with other current clamps, given in turn: each call clamps with its own monitor's."""
    cfg = _config(joints)
    arm = run_arm(cfg)
    monitors = [SafetyMonitor(_config(joints, current_fraction=f), arm) for f in (0.8, 0.05)]
    assert not np.array_equal(monitors[0].tau_max, monitors[1].tau_max)
    ref = BilateralController(cfg, arm, compiled=False)
    new = BilateralController(cfg, arm, compiled=True)
    assert new.compiled
    rng = np.random.default_rng(3)
    q0 = np.array([0.0, 0.3, 0.0, -1.0, 0.0, 0.2, 0.0, 0.0])
    clamped = 0
    for k in range(600):
        safety = monitors[(k // 3) % 2]
        ql = q0 + 0.2 * np.sin(0.02 * k + np.arange(8))
        qf = ql + rng.normal(0, 0.02, 8)
        a, b = ArmSignals(ql, rng.normal(0, 0.5, 8)), ArmSignals(qf, rng.normal(0, 0.5, 8))
        want = control_reference(ref, safety, a, b, DT)
        got = new.control(a, b, DT, safety)
        for x, y in ((want[1], got[1]), (want[2], got[2])):
            assert x.tobytes() == y.tobytes(), k
        assert (want[3] is None) == (got[3] is None), k
        clamped += bool((np.abs(want[1]) == safety.tau_max).any())
    assert clamped > 50  # the small clamp did cut torques


def test_control_refuses_a_monitor_of_another_arm_after_one_of_its_own():
    cfg = _config()
    arm = run_arm(cfg)
    ctl = BilateralController(cfg, arm, compiled=True)
    q = np.array([0.0, 0.3, 0.0, -1.0, 0.0, 0.2, 0.0, 0.0])
    ctl.control(ArmSignals(q), ArmSignals(q), DT, SafetyMonitor(cfg, arm))

    class Other(SafetyMonitor):
        def kernel_constants(self):
            return super().kernel_constants()[:, :5].copy()

    with pytest.raises(ValueError, match="joints"):
        ctl.control(ArmSignals(q), ArmSignals(q), DT, Other(cfg, arm))


@pytest.mark.parametrize("joints", [None, "all"])
def test_the_compiled_control_commands_read_as_the_numpy_ones(joints):
    cfg = _config(joints)
    arm = run_arm(cfg)
    ref = BilateralController(cfg, arm, compiled=False)
    new = BilateralController(cfg, arm, compiled=True)
    safety = SafetyMonitor(cfg, arm)
    rng = np.random.default_rng(9)
    q0 = np.array([0.0, 0.3, 0.0, -1.0, 0.0, 0.2, 0.0, 0.0])
    kept = []
    for k in range(200):
        ql, qf = q0 + rng.normal(0, 0.05, 8), q0 + rng.normal(0, 0.05, 8)
        a, b = ArmSignals(ql, rng.normal(0, 0.5, 8)), ArmSignals(qf, rng.normal(0, 0.5, 8))
        want = control_reference(ref, safety, a, b, DT)[0]
        got = new.control(a, b, DT, safety)[0]
        assert isinstance(got, Commands)
        assert [f.name for f in dataclasses.fields(got)] == list(FIELDS)
        for name in FIELDS:
            x, y = getattr(want, name), getattr(got, name)
            assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), (k, name)
        kept.append((got, [getattr(want, name).copy() for name in FIELDS]))
    changed = dataclasses.replace(got, leader_tau=np.ones(8))
    assert changed.leader_tau.tobytes() == np.ones(8).tobytes()
    assert changed.follower_current.tobytes() == got.follower_current.tobytes()
    # each cycle's commands are its own: the later cycles did not change the earlier ones
    for got, want in kept:
        assert all(getattr(got, name).tobytes() == w.tobytes() for name, w in zip(FIELDS, want))


def test_the_compiled_hand_refuses_angles_of_another_length():
    from collect.operator_kernel import CompiledHand, compiled

    hand = CompiledHand(compiled(), 8, 100.0, 2.0, 5.0)
    moves = hand.moves([(7, 0.0, 1.0, 0.0, 0.5)])
    with pytest.raises(ValueError, match="8 joint"):
        hand.torque(0.5, moves, np.zeros(4), np.zeros(8))
    out = hand.torque(0.5, moves, np.zeros(8), np.zeros(8))
    assert out[7] > 0.0 and not out[:7].any()
