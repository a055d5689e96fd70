"""The simulated operator's free task advances its schedule only in cycles where something happens
(collect/operator.py `_move_rows`: a move ends, a pause ends), pauses included, and gives the bits and
draws of an operator that advances it every cycle."""

from __future__ import annotations

import numpy as np
import pytest

from collect.config import load_config
from collect.operator import SimulatedOperator
from collect.runner import run_arm
from tests.loop_reference import count_advances

_STATE = ("_seg_t0", "_seg_T", "_seg_a", "_seg_b", "_on", "_phase_end")


def _operators(joints, seed, count):
    cfg = load_config()
    if joints is not None:
        cfg = cfg.with_bilateral_joints(joints)
    arm = run_arm(cfg)
    ops = [SimulatedOperator(seed, arm, cfg.loop.rate_hz, cfg) for _ in range(count)]
    q = np.array([0.0, 0.2, 0.0, -1.2, 0.0, 0.0, 0.0, 0.0])
    for op in ops:
        op.start(q, 0.0)
    return ops, q


def _state(op):
    return tuple(getattr(op, name).tobytes() for name in _STATE)


@pytest.mark.parametrize("joints", [None, "all"])
def test_every_advance_of_the_cached_schedule_changes_it(joints):
    """While a joint pauses (its move over, its pause not) torque() does not advance the schedule: each
    advance it makes after the first cycle's starts a move, a pause or a moving phase."""
    (op,), q = _operators(joints, 7, 1)
    calls, idle = count_advances(op, "_advance", _state)
    paused = 0
    for k in range(5000):  # 10 s: every joint pauses now and then
        op.torque(k * 0.002, q, np.zeros(8))
        paused += not op._on.all()
    assert paused > 1000  # the case this is about happened, often
    assert len(calls) > 20 and idle == [0.0]  # the first cycle's: no schedule yet


@pytest.mark.parametrize("joints", [None, "all"])
def test_the_cached_schedule_gives_the_every_cycle_bits_and_draws(joints):
    ops, q = _operators(joints, 11, 2)
    rng = np.random.default_rng(5)
    for k in range(8000):  # 16 s
        t = k * 0.002
        qk, dqk = q + rng.normal(0, 0.3, 8), rng.normal(0, 2.0, 8)
        ops[1]._advance(t)  # every cycle
        got, want = ops[0].torque(t, qk, dqk), ops[1].torque(t, qk, dqk)
        assert got.tobytes() == want.tobytes(), k
        assert _state(ops[0]) == _state(ops[1]), k
    assert ops[0].rng.bit_generator.state == ops[1].rng.bit_generator.state
