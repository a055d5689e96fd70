"""4-channel bilateral controller on ideal numpy plants (no bus): tracking, force balance, observers."""

import numpy as np
import pytest

from collect.config import load_config
from collect.controller import ArmSignals, BilateralController
from crane_io.description import default_arm

DT = 0.002
ARM = default_arm()
BIL = np.array([n in ARM.bilateral_joints for n in ARM.joint_names])


class RigidJoints:
    """Independent rigid joints: J_true ddq = tau_motor + tau_ext - b dq - gravity_load(q)."""

    def __init__(self, inertia, q0, viscous=0.02, gravity=None):
        self.J = np.asarray(inertia, dtype=float)
        self.q = np.array(q0, dtype=float)
        self.dq = np.zeros_like(self.q)
        self.b = viscous
        self.gravity = gravity  # motor torque needed to hold q (callable) or None

    def step(self, tau, tau_ext=0.0, substeps=4):
        h = DT / substeps
        for _ in range(substeps):
            g = self.gravity(self.q) if self.gravity is not None else 0.0
            ddq = (tau + tau_ext - self.b * self.dq - g) / self.J
            self.dq = self.dq + ddq * h
            self.q = self.q + self.dq * h


def _setup(gravity_model="none", inertia_scale=1.1):
    cfg = load_config()
    values = cfg.values
    values["controller"]["gravity_model"] = gravity_model
    values["controller"]["inertia_model"] = "constant"  # the ideal plants have constant inertia
    from collect.config import _build

    cfg = _build(values, "test")
    ctl = BilateralController(cfg, ARM)
    q0 = np.array([0.0, 0.2, 0.0, -1.0, 0, 0, 0, 0])
    return cfg, ctl, q0, ctl.J * inertia_scale  # the true inertia differs from the nominal one


def test_follower_tracks_the_leader_pushed_by_a_hand():
    cfg, ctl, q0, J = _setup()
    lead, foll = RigidJoints(J, q0), RigidJoints(J, q0)
    ql, qf = [], []
    for k in range(int(6 / DT)):
        t = k * DT
        hand = np.where(BIL, 0.6 * np.sin(2 * np.pi * 0.4 * t + np.arange(8)), 0.0)
        cmd = ctl.step(ArmSignals(lead.q.copy()), ArmSignals(foll.q.copy()), DT)
        lead.step(cmd.leader_tau, hand)
        foll.step(cmd.follower_tau)
        ql.append(lead.q[BIL].copy())
        qf.append(foll.q[BIL].copy())
    ql, qf = np.array(ql), np.array(qf)
    motion = ql.max(0) - ql.min(0)
    assert (motion > 0.3).all()  # the hand really moved every bilateral joint
    rms = np.sqrt(((ql - qf) ** 2).mean(0))
    assert (rms < 0.03 * motion).all(), (rms, motion)


def test_reaction_forces_balance_when_the_follower_meets_a_wall():
    cfg, ctl, q0, J = _setup()
    lead, foll = RigidJoints(J, q0, viscous=0.2), RigidJoints(J, q0, viscous=0.2)
    wall_at = q0 + 0.1
    push = np.where(BIL, 0.5, 0.0)
    res_l, res_f, vel = [], [], []
    for k in range(int(6 / DT)):
        cmd = ctl.step(ArmSignals(lead.q.copy()), ArmSignals(foll.q.copy()), DT)
        if k >= int(5 / DT):  # average over the last second
            res_l.append(ctl.leader.tau_res[BIL])
            res_f.append(ctl.follower.tau_res[BIL])
            vel.append(lead.dq[BIL])
        wall = -30.0 * np.maximum(foll.q - wall_at, 0.0)
        lead.step(cmd.leader_tau, push)
        foll.step(cmd.follower_tau, wall)
    res_l, res_f = np.mean(res_l, axis=0), np.mean(res_f, axis=0)
    # the leader's RFOB sees the hand (DOB sign: a positive push reads negative), the follower's the wall
    assert res_l == pytest.approx(-push[BIL], abs=0.08)
    assert res_f == pytest.approx(push[BIL], abs=0.08)
    assert np.abs(np.mean(vel, axis=0)).max() < 0.01  # the hand feels the wall: the leader stopped too
    assert (foll.q[BIL] > wall_at[BIL]).all()


def test_rfob_removes_gravity_with_the_coefficient_model():
    cfg, ctl, q0, J = _setup("coefficients", inertia_scale=1.0)
    grav = ctl.gravity
    assert grav.kind == "coefficients"
    q0 = q0.copy()
    q0[1] = 0.9  # joint2 tilted: a big gravity load
    lead, foll = RigidJoints(J, q0, gravity=grav), RigidJoints(J, q0, gravity=grav)
    for _ in range(int(2 / DT)):
        cmd = ctl.step(ArmSignals(lead.q.copy()), ArmSignals(foll.q.copy()), DT)
        lead.step(cmd.leader_tau)
        foll.step(cmd.follower_tau)
    assert abs(grav(q0)[1]) > 1.0
    assert np.abs(ctl.leader.tau_res[BIL]).max() < 0.05  # no hand, no contact: no reaction force
    assert np.abs(lead.q - q0).max() < 0.01  # and no sag


def test_gravity_model_signs_agree_with_the_dynamics():
    pytest.importorskip("crane_io.physics.dynamics")
    cfg, ctl, _, _ = _setup("dynamics")
    cfg2, ctl2, _, _ = _setup("coefficients")
    q = np.array([0.0, 0.7, 0.0, -0.5, 0, 0, 0, 0])
    g_dyn, g_coef = ctl.gravity(q), ctl2.gravity(q)
    assert np.sign(g_dyn[1]) == np.sign(g_coef[1]) and np.sign(g_dyn[3]) == np.sign(g_coef[3])
    assert g_dyn[[1, 3]] == pytest.approx(g_coef[[1, 3]], rel=0.25)


def test_held_joints_get_no_current_and_pseudo_derivative_tracks_a_ramp():
    cfg, ctl, q0, J = _setup()
    v = 0.5
    for k in range(int(1.0 / DT)):
        q = q0 + v * k * DT
        cmd = ctl.step(ArmSignals(q), ArmSignals(q), DT)
    assert np.all(cmd.leader_current[~BIL] == 0) and np.all(cmd.follower_current[~BIL] == 0)
    assert np.isnan(ctl.leader.tau_dis[~BIL]).all() and np.isfinite(ctl.leader.tau_dis[BIL]).all()
    assert ctl.leader.dq == pytest.approx(np.full(8, v), rel=0.02)
    assert cmd.follower_current[BIL] == pytest.approx(cmd.follower_tau[BIL] / ctl.kt[BIL])


def test_hold_brings_both_arms_to_their_references():
    cfg, ctl, q0, J = _setup()
    lead, foll = RigidJoints(J, q0), RigidJoints(J, q0 + 0.3 * BIL)
    target = q0 - 0.2 * BIL
    zero = np.zeros(8)
    for _ in range(int(5 / DT)):
        cmd = ctl.hold(ArmSignals(lead.q.copy()), ArmSignals(foll.q.copy()), (target, zero), (target, zero),
                       DT)
        lead.step(cmd.leader_tau)
        foll.step(cmd.follower_tau)
    assert lead.q[BIL] == pytest.approx(target[BIL], abs=5e-3)
    assert foll.q[BIL] == pytest.approx(target[BIL], abs=5e-3)


def test_pose_dependent_inertia_follows_the_arm():
    pytest.importorskip("crane_io.physics.dynamics")
    ctl = BilateralController(load_config(), ARM)
    assert ctl.inertia.kind == "dynamics"
    upright = ctl.inertia(np.zeros(8))
    stretched = ctl.inertia(np.array([0, np.pi / 2, 0, 0, 0, 0, 0, 0]))
    assert upright == pytest.approx(ctl.J)  # the configured J is the zero-pose inertia
    i1 = ARM.index("joint1")
    assert stretched[i1] > 10 * upright[i1]  # joint 1 carries the whole outstretched arm
    assert np.all(stretched[~BIL] == upright[~BIL])
