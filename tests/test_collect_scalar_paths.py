"""The per-cycle scalar paths of the simulated operator and the safety monitor give the same bits as the
array formulas they stand in for (collect/operator.py, collect/safety.py): soft zones, stops, guards,
NaN and signed zeros included."""

from __future__ import annotations

import numpy as np
import pytest

from collect.config import load_config
from collect.operator import SimulatedOperator, minimum_jerk
from collect.runner import run_arm
from collect.safety import SafetyMonitor


def _setup(joints):
    cfg = load_config()
    if joints is not None:
        cfg = cfg.with_bilateral_joints(joints)
    return cfg, run_arm(cfg)


def _array_reference(op: SimulatedOperator, t: float):
    """What reference(t) computed before (the segments as they stand after advancing to t)."""
    tau = (t - op._seg_t0) / op._seg_T
    s, ds = minimum_jerk(tau)
    d = op._seg_b - op._seg_a
    return op._seg_a + d * s, d * ds / op._seg_T


def _array_check(m: SafetyMonitor, q, dq) -> tuple[str, int] | None:
    bad = (q > m.stop_upper) | (q < m.stop_lower)
    if bad.any():
        return "joint_limit", int(np.flatnonzero(bad)[0])
    if dq is not None and (np.abs(dq) > m.vmax).any():
        return "velocity", int(np.flatnonzero(np.abs(dq) > m.vmax)[0])
    return None


@pytest.mark.parametrize("joints", [None, "all"])
def test_operator_reference_and_torque_match_the_array_formulas(joints):
    cfg, arm = _setup(joints)
    op = SimulatedOperator(3, arm, cfg.loop.rate_hz, cfg)
    rng = np.random.default_rng(0)
    q = np.array([0.0, 0.2, 0.0, -1.2, 0.0, 0.0, 0.0, 0.0])
    op.start(q, 0.0)
    o = cfg.operator
    for k in range(3000):  # 6 s: moves, pauses and segment ends
        t = k * 0.002
        qk = q + rng.normal(0, 0.3, 8)
        dqk = rng.normal(0, 2.0, 8) * (k % 5 != 0)  # zeros now and then
        got = op.torque(t, qk, dqk)
        q_ref, dq_ref = _array_reference(op, t)
        want = np.zeros(8)
        want[op.idx] = np.clip(o.stiffness * (q_ref - qk[op.idx]) + o.damping * (dq_ref - dqk[op.idx]),
                               -o.max_torque, o.max_torque)
        assert got.dtype == want.dtype and got.shape == (8,)
        assert got.tobytes() == want.tobytes()
        r_q, r_dq = op.reference(t)
        assert r_q.tobytes() == q_ref.tobytes() and r_dq.tobytes() == dq_ref.tobytes()


def test_operator_torque_passes_nan_through_like_the_arrays():
    cfg, arm = _setup(None)
    op = SimulatedOperator(0, arm, cfg.loop.rate_hz, cfg)
    op.start(np.zeros(8), 0.0)
    q = np.zeros(8)
    q[op.idx[0]] = np.nan
    out = op.torque(0.01, q, np.zeros(8))
    assert np.isnan(out[op.idx[0]]) and np.isfinite(np.delete(out, op.idx[0])).all()


@pytest.mark.parametrize("joints", [None, "all"])
def test_safety_fast_paths_match_the_array_code(joints):
    cfg, arm = _setup(joints)
    m = SafetyMonitor(cfg, arm)
    rng = np.random.default_rng(1)
    mid = 0.5 * (m.lower + m.upper)
    half = 0.5 * (m.upper - m.lower)
    for k in range(4000):
        # mostly inside, now and then in a soft zone, past a stop, at exact bounds, NaN, -0.0
        q = mid + half * rng.uniform(-1.0, 1.0, 8) * (0.9 if k % 3 else 1.05)
        if k % 17 == 0:
            q[k % 8] = m.soft_upper[k % 8]
        if k % 19 == 0:
            q[k % 8] = m.stop_lower[k % 8]
        if k % 23 == 0:
            q[k % 8] = np.nan
        tau = rng.normal(0, 5.0, 8)
        if k % 7 == 0:
            tau[:] = -0.0
        dq = rng.normal(0, 3.0, 8)
        if k % 29 == 0:
            dq[k % 8] = m.vmax[k % 8]
        if k % 31 == 0:
            dq[(k + 1) % 8] = np.nan
        for spring in (True, False):
            got = m.limit_torque(q, tau, dq, spring=spring)
            want = m.limit_torque_arrays(q, tau, dq, spring)
            assert got.tobytes() == want.tobytes(), (k, spring)
        for d in (dq, None):
            b = m.check("leader", q, d)
            want = _array_check(m, q, d)
            assert (None if b is None else (b.kind, m.names.index(b.joint))) == want, k


def test_safety_takes_lists_and_other_shapes_the_old_way():
    cfg, arm = _setup(None)
    m = SafetyMonitor(cfg, arm)
    q = [0.0, 0.2, 0.0, -1.2, 0.0, 0.0, 0.0, 0.1]
    out = m.limit_torque(np.array(q), np.ones(8))
    assert out.tobytes() == m.limit_torque_arrays(np.array(q), np.ones(8), None).tobytes()
    assert m.check("leader", np.array(q), None) is None
    b = m.check("follower", np.array(q) + np.where(np.arange(8) == 1, 3.0, 0.0), None)
    assert b is not None and b.kind == "joint_limit" and b.joint == m.names[1]


# ---- the operator's cached schedule and its compiled hand ------------------------------------------------
@pytest.mark.parametrize("joints", [None, "all"])
def test_operator_torque_skips_only_cycles_where_no_move_ends(joints):
    """torque() advances the schedule only from the earliest end of a move on: the schedule, the draws and
    the torques are those of an operator that advances it every cycle."""
    cfg, arm = _setup(joints)
    ops = [SimulatedOperator(5, arm, cfg.loop.rate_hz, cfg) for _ in range(2)]
    q = np.array([0.0, 0.2, 0.0, -1.2, 0.0, 0.0, 0.0, 0.0])
    rng = np.random.default_rng(3)
    for op in ops:
        op.start(q, 0.0)
    for k in range(6000):  # 12 s: many moves, pauses and resumptions
        t = k * 0.002
        qk, dqk = q + rng.normal(0, 0.3, 8), rng.normal(0, 2.0, 8)
        ops[1]._advance(t)  # every cycle, as before
        got, want = ops[0].torque(t, qk, dqk), ops[1].torque(t, qk, dqk)
        assert got.tobytes() == want.tobytes(), k
        for name in ("_seg_t0", "_seg_T", "_seg_a", "_seg_b", "_on", "_phase_end"):
            assert getattr(ops[0], name).tobytes() == getattr(ops[1], name).tobytes(), (k, name)
    assert ops[0].rng.bit_generator.state == ops[1].rng.bit_generator.state


@pytest.mark.parametrize("joints", [None, "all"])
def test_the_compiled_hand_gives_the_python_floats_bits(joints):
    pytest.importorskip("numba")
    cfg, arm = _setup(joints)
    ops = [SimulatedOperator(2, arm, cfg.loop.rate_hz, cfg, compiled=c) for c in (True, False)]
    assert ops[0]._hand.compiled and not ops[1]._hand.compiled
    q = np.array([0.0, 0.2, 0.0, -1.2, 0.0, 0.0, 0.0, 0.0])
    rng = np.random.default_rng(4)
    for op in ops:
        op.start(q, 0.0)
    for k in range(5000):
        t = k * 0.002
        qk, dqk = q + rng.normal(0, 0.5, 8), rng.normal(0, 3.0, 8)
        if k % 17 == 0:
            qk[k % 8] = np.nan
        if k % 13 == 0:
            dqk[:] = -0.0
        got, want = ops[0].torque(t, qk, dqk), ops[1].torque(t, qk, dqk)
        assert got.dtype == want.dtype and got.tobytes() == want.tobytes(), k
    # an array of another type goes the Python way
    assert ops[0].torque(10.0, q.astype(np.float32), np.zeros(8)).tobytes() == ops[1].torque(
        10.0, q.astype(np.float32), np.zeros(8)).tobytes()
