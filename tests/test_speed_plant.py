"""The arm plant's fast paths compute what the array forms they replaced computed, bit for bit:
the sensor reading (scalar Python instead of numpy fancy indexing, the position-noise signs read from the
bit generator's raw outputs instead of Generator.integers) and the substep's small linear solves."""

from __future__ import annotations

import random
import struct

import numpy as np
import pytest

from crane_io.dynamixel.units import AMPERE_PER_CURRENT_LSB, RADS_PER_VELOCITY_LSB
from crane_io.sim.arm_plant import _PULSE_SIGNS, ArmPlant
from crane_io.sim.plant_reference import _eliminate, _solve


def _array_read(plant: ArmPlant, rng: np.random.Generator):
    """ArmPlant.read as it was written with arrays (the reference), drawing from `rng`."""
    n = len(plant.servo_ids)
    s = plant.config.sensor
    bi, held = plant._bi, plant._held
    pos, vel, cur = np.empty(n), np.empty(n), np.empty(n)
    pos[bi], pos[held] = plant.q, plant._held_q
    vel[bi], vel[held] = plant.dq, plant._held_dq
    cur[bi], cur[held] = plant.motor_torque / plant.kt[bi], plant._held_current
    flip = rng.random(n) < s.position_noise_probability
    pos = pos + flip * _PULSE_SIGNS.take(rng.integers(0, 2, size=n, dtype=np.int64))
    vel = vel + rng.normal(0.0, s.velocity_noise_lsb * RADS_PER_VELOCITY_LSB, n)
    cur = cur + rng.normal(0.0, s.current_noise_lsb * AMPERE_PER_CURRENT_LSB, n)
    return pos, vel, cur


def test_the_reading_equals_the_array_form_bit_for_bit():
    plant = ArmPlant("crane-x7", seed=7)
    twin = np.random.default_rng(7)
    states = np.random.default_rng(1)
    for k in range(500):
        q = states.normal(0, 0.5, 8)
        dq = states.normal(0, 0.5, 8) * (k % 3 != 0)  # some readings of a joint at rest (signed zeros)
        if k % 5 == 0:
            dq = -0.0 * np.abs(dq)
        plant.set_state(q, dq)
        plant.motor_torque = states.normal(0, 1, 3)
        plant._held_current = states.normal(0, 0.1, 5)
        got = plant.read()
        for a, b in zip((got.position, got.velocity, got.current), _array_read(plant, twin)):
            assert a.tobytes() == b.tobytes()
    assert plant.rng.random() == twin.random()  # the two generators are still in step


@pytest.mark.parametrize("sizes", [[8], [2], [3], [8, 3, 8, 8, 1, 2]])
def test_position_noise_draws_what_random_and_integers_draw(sizes):
    plant = ArmPlant("crane-x7", seed=11)
    twin = np.random.default_rng(11)
    for k in range(300):
        n = sizes[k % len(sizes)]
        flips = twin.random(n).tolist()
        want = _PULSE_SIGNS.take(twin.integers(0, 2, size=n, dtype=np.int64)).tolist()
        assert plant._position_noise(n) == (flips, want)
        assert plant.rng.random() == twin.random()


def test_the_written_out_solves_equal_the_general_loop_signed_zeros_included():
    rnd = random.Random(3)
    special = [0.0, -0.0, 1.0, -1.0, 2.5]

    def value():
        return rnd.choice(special) if rnd.random() < 0.3 else rnd.uniform(-3, 3)

    for n, count in ((1, 20000), (2, 20000), (3, 20000), (4, 3000), (7, 1000)):
        for _ in range(count):
            a = [[value() for _ in range(n)] for _ in range(n)]
            for i in range(n):
                a[i][i] = rnd.uniform(0.5, 3)
            b = [value() for _ in range(n)]
            want = _eliminate(a, b)
            assert struct.pack(f"{n}d", *_solve(a, b)) == struct.pack(f"{n}d", *want)


def test_step_lists_equals_step_with_arrays():
    """The chain hands ArmPlant its commands as lists (step_lists); step (arrays) must do the same, in
    current and position modes, torque off, with overload tracking on."""
    from dataclasses import replace

    from crane_io.sim.plant_api import ActuatorCommand
    from crane_io.sim.plant_config import load_plant_config

    config = load_plant_config("crane-x7")
    config = replace(config, overload=replace(config.overload, enabled=True, time_s=0.05))
    a, b = ArmPlant(config, seed=2), ArmPlant(config, seed=2)
    rng = np.random.default_rng(4)
    for k in range(400):
        enabled = np.ones(8, bool)
        enabled[rng.integers(0, 8)] = k % 50 > 5
        mode = np.array([0, 0, 3, 0, 3, 3, 3, 3]) if k % 100 < 70 else np.full(8, 3)
        current = rng.normal(0, 1.0, 8)
        position = rng.normal(0, 0.2, 8)
        gains = np.tile([800.0, 0.0, 0.0], (8, 1))
        limit = np.full(8, 1.5)
        a.step(ActuatorCommand(enabled, mode, current, position, gains, limit), 0.002)
        b.step_lists(enabled.tolist(), mode.tolist(), current.tolist(), position.tolist(),
                     [tuple(int(g) for g in row) for row in gains], limit.tolist(), 0.002)
        for x, y in zip(a.state() + (a.motor_torque,), b.state() + (b.motor_torque,)):
            assert x.tobytes() == y.tobytes()
        assert a.hardware_errors() == b.hardware_errors()
