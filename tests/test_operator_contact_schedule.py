"""The contact task's simulated operator advances its schedule only in cycles where something happens
(collect/operator.py `_contact_rows`: a stage, a move, a pause or the free phase ends) and gives the bits,
phases and draws of an operator that advances it every cycle, on a wall and on a table."""

from __future__ import annotations

import numpy as np
import pytest

from collect.config import load_config
from collect.operator import SimulatedOperator
from crane_io.sim.arm_plant import ArmPlant
from tests.loop_reference import count_advances

_STATE = ("_seg_t0", "_seg_T", "_seg_a", "_seg_b", "_on", "_phase_end")


def _operators(tmp_path, preset, seed, count, joints=None):
    path = tmp_path / "op.toml"
    path.write_text('[operator]\ntask = "contact"\npress_min_s = 0.4\npress_max_s = 0.8\n'
                    'press_fraction = 0.4\n')
    cfg = load_config(path)
    if joints is not None:
        cfg = cfg.with_bilateral_joints(joints)
    env = ArmPlant(preset).environment
    ops = [SimulatedOperator(seed, config=cfg, environment=env) for _ in range(count)]
    q = np.array([cfg.operator.start.get(n, 0.0) for n in ops[0].arm.joint_names])
    for op in ops:
        op.start(q, 0.0)
    return ops, q


def _state(op):
    return tuple(getattr(op, name).tobytes() for name in _STATE) + (op._free_end, op.phase, op.pressing,
                                                                      len(op._episode))


@pytest.mark.parametrize("preset", ["contact-wall", "contact-table"])
def test_the_cached_contact_schedule_gives_the_every_cycle_bits_phases_and_draws(tmp_path, preset):
    ops, q = _operators(tmp_path, preset, 4, 2)
    rng = np.random.default_rng(8)
    phases = set()
    for k in range(6000):  # 12 s: free phases, presses, withdrawals
        t = k * 0.002
        qk, dqk = q + rng.normal(0, 0.1, 8), rng.normal(0, 1.0, 8)
        ops[1]._moves = None  # torque() advances it every cycle, once (as before the cache)
        got, want = ops[0].torque(t, qk, dqk), ops[1].torque(t, qk, dqk)
        assert got.tobytes() == want.tobytes(), k
        assert _state(ops[0]) == _state(ops[1]), k
        phases.add(ops[0].phase)
    assert phases == {"free", "approach", "ramp", "hold", "withdraw"}
    assert ops[0].rng.bit_generator.state == ops[1].rng.bit_generator.state


def test_every_advance_of_the_cached_contact_schedule_changes_it(tmp_path):
    (op,), q = _operators(tmp_path, "contact-wall", 6, 1)
    calls, idle = count_advances(op, "_advance_contact", _state)
    for k in range(6000):
        op.torque(k * 0.002, q, np.zeros(8))
    assert len(calls) > 8
    assert idle == [0.0]  # the first cycle's: no schedule yet
