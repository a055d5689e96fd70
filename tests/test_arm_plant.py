"""ArmPlant: stick-slip that really sticks, gravity when torque is off, repeatable seeded runs,
presets, the Plant protocol, truth kept apart."""

import json

import numpy as np
import pytest

from crane_io.errors import ConfigError
from crane_io.sim.arm_plant import ArmPlant
from crane_io.sim.plant_api import ActuatorCommand, Plant
from crane_io.sim.plant_config import load_plant_config, presets

N = 8
BI = [0, 1, 3]  # joint1, joint2, joint4 in servo order


def command(current=None, enabled=True, mode=0, goal=None, limit=3.2):
    return ActuatorCommand(np.full(N, enabled), np.full(N, mode),
                           np.zeros(N) if current is None else np.asarray(current, float),
                           np.zeros(N) if goal is None else np.asarray(goal, float),
                           np.tile([800, 0, 0], (N, 1)), np.full(N, limit))


def holding_current(plant, extra=(0.0, 0.0, 0.0)):
    cur = np.zeros(N)
    cur[BI] = (plant.dyn.gravity_torque(plant.q) + np.asarray(extra)) / plant.kt[BI]
    return cur


def test_the_plant_satisfies_the_protocol_and_every_preset_loads():
    names = presets()
    assert {"crane-x7", "baseline", "hidden-coulomb", "hidden-viscous", "hidden-stribeck", "hidden-spring",
            "hidden-payload", "hidden-rotor-inertia", "hidden-cogging", "hidden-offset"} <= set(names)
    for name in names:
        cfg = load_plant_config(name)
        plant = ArmPlant(cfg)
        assert isinstance(plant, Plant)
        assert plant.servo_ids == (2, 3, 4, 5, 6, 7, 8, 9)
        if name.startswith("hidden-"):
            assert cfg.hidden is not None
            hidden = (cfg.hidden.effect, cfg.hidden.joint)
            assert hidden not in [(e, j) for e, j, _ in cfg.known]
        else:
            assert cfg.hidden is None


def test_stiction_holds_below_breakaway_and_lets_go_above():
    plant = ArmPlant("baseline", seed=0)
    plant.set_state(q=np.zeros(N))  # upright: joint1's axis is vertical, no gravity on it
    breakaway = 0.21  # baseline joint1
    for torque in np.linspace(0.0, 0.95 * breakaway, 150):  # slow ramp, still below breakaway
        cur = holding_current(plant, (torque, 0.0, 0.0))
        plant.step(command(cur), 0.002)
    q, dq = plant.state()
    assert q[0] == 0.0 and dq[0] == 0.0  # exactly at rest
    for torque in np.linspace(0.95 * breakaway, 1.3 * breakaway, 150):
        cur = holding_current(plant, (torque, 0.0, 0.0))
        plant.step(command(cur), 0.002)
    q, dq = plant.state()
    assert q[0] > 0.005 and dq[0] > 0  # it broke away in the pushed direction


def test_a_moving_joint_stops_and_sticks_when_the_push_ends():
    plant = ArmPlant("baseline", seed=0)
    plant.set_state(q=np.zeros(N), dq=np.array([0.5, 0, 0, 0, 0, 0, 0, 0]))
    for _ in range(200):
        plant.step(command(holding_current(plant)), 0.002)
    q, dq = plant.state()
    assert dq[0] == 0.0
    q_stop = q[0]
    for _ in range(50):
        plant.step(command(holding_current(plant, (0.1, 0, 0))), 0.002)  # below breakaway: stays
    assert plant.state()[0][0] == q_stop


def test_torque_off_lets_joint2_fall_toward_gravity():
    plant = ArmPlant("crane-x7", seed=0)
    plant.set_state(q=np.array([0.0, 0.4, 0, -0.3, 0, 0, 0, 0]))
    for _ in range(100):
        plant.step(command(enabled=False), 0.002)
    q, _ = plant.state()
    assert q[1] > 0.5  # tilted forward, it falls further forward
    plant2 = ArmPlant("crane-x7", seed=0)
    plant2.set_state(q=np.array([0.0, -0.4, 0, -0.3, 0, 0, 0, 0]))
    for _ in range(100):
        plant2.step(command(enabled=False), 0.002)
    assert plant2.state()[0][1] < -0.5


def test_current_mode_torque_follows_the_torque_constant_and_the_sensor_reports_it():
    plant = ArmPlant("baseline", seed=0)
    cur = holding_current(plant)
    plant.step(command(cur), 0.002)
    r = plant.read()
    assert np.allclose(r.current[BI], cur[BI], atol=0.02)
    assert np.allclose(plant.motor_torque, cur[BI] * plant.kt[BI])


def test_seeded_runs_repeat_exactly_and_differ_across_seeds():
    def run(seed):
        plant = ArmPlant("crane-x7", seed=seed)
        out = []
        for i in range(150):
            plant.step(command(holding_current(plant, 0.4 * np.sin(0.05 * i) * np.ones(3))), 0.002)
            r = plant.read()
            out.append(np.concatenate([r.position, r.velocity, r.current]))
        return np.array(out)

    a, b, c = run(3), run(3), run(4)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_held_joints_follow_their_goal_position():
    plant = ArmPlant("crane-x7", seed=0)
    goal = np.zeros(N)
    goal[2] = 0.3  # joint3
    cmd = command(mode=3, goal=goal)
    for _ in range(250):
        plant.step(cmd, 0.002)
    assert plant.state()[0][2] == pytest.approx(0.3, abs=1e-3)


def test_payload_and_hidden_effects_change_the_physics():
    base, heavy = ArmPlant("baseline"), ArmPlant("hidden-payload")
    q = np.array([0.0, 0.8, -0.3])
    assert abs(heavy.dyn.gravity_torque(q)[1]) > abs(base.dyn.gravity_torque(q)[1]) + 0.5


def test_truth_is_only_written_when_asked(tmp_path):
    plant = ArmPlant("hidden-coulomb", seed=5)
    truth = plant.truth()
    assert truth["hidden"] == {"effect": "coulomb", "joint": "joint2", "coulomb": 0.25}
    path = plant.write_truth(tmp_path / "truth.json")
    written = json.loads(path.read_text())
    assert written["hidden"]["effect"] == "coulomb" and written["seed"] == 5  # the seed it runs with


def test_bad_plant_configurations_raise_one_sentence_errors(tmp_path):
    with pytest.raises(ConfigError, match="unknown plant preset 'nope'.*crane-x7"):
        load_plant_config("nope")
    bad = tmp_path / "bad.toml"
    bad.write_text('[[effects]]\neffect = "coulomb"\njoint = "joint3"\n')
    with pytest.raises(ConfigError, match="needs joint"):
        load_plant_config(bad)
    bad.write_text('[[effects]]\neffect = "wobble"\njoint = "joint1"\n')
    with pytest.raises(ConfigError, match="unknown effect 'wobble'"):
        load_plant_config(bad)
    bad.write_text("substep_s = 0.1\n")
    with pytest.raises(ConfigError, match="substep_s"):
        load_plant_config(bad)
    bad.write_text("colour = 3\n")
    with pytest.raises(ConfigError, match="unknown key"):
        load_plant_config(bad)
    with pytest.raises(ConfigError, match="does not exist"):
        load_plant_config(tmp_path / "missing.toml")


# ---- backlash ----------------------------------------------------------------------------------------

def _backlash_plant(tmp_path, width, name="bl"):
    """Baseline, upright (no gravity on joint1), noise off, plus a gear gap on joint1."""
    path = tmp_path / f"{name}.toml"
    path.write_text(
        'base = "baseline"\nname = "bl"\n[initial]\njoint4 = 0.0\n'
        "[sensor]\nposition_noise_probability = 0\ncurrent_noise_lsb = 0\nvelocity_noise_lsb = 0\n"
        + ("" if width is None else
           f'[hidden]\neffect = "backlash"\njoint = "joint1"\nwidth = {width}\nmotor_inertia = 0.01\n'))
    return ArmPlant(load_plant_config(path))


def _push_and_reverse(plant, amps=0.15, cycles=300):
    trace = []
    for k in range(cycles):
        cur = np.zeros(N)
        cur[0] = amps if k < cycles // 3 else -amps
        plant.step(command(cur, mode=np.array([0, 0, 3, 0, 3, 3, 3, 3])), 0.002)
        trace.append((plant.q[0], plant.dq[0], plant.motor_q[0] - plant.q[0]))
    return np.array(trace)


def test_backlash_of_zero_width_is_the_motor_inertia_rigidly_geared(tmp_path):
    rigid = _backlash_plant(tmp_path, None)
    rigid.model.armature[0] += 0.01  # the same motor inertia, no gap
    closed = _backlash_plant(tmp_path, 0.0, "closed")
    a, b = _push_and_reverse(rigid), _push_and_reverse(closed)
    assert np.abs(a[:, 1]).max() > 0.5  # it really moved, both ways
    np.testing.assert_allclose(b[:, :2], a[:, :2], atol=0.01)


def test_backlash_opens_a_gap_at_each_reversal_that_the_link_coasts_through(tmp_path):
    width = 0.01
    gap, rigid = _push_and_reverse(_backlash_plant(tmp_path, width, "gap")), \
        _push_and_reverse(_backlash_plant(tmp_path, 0.0, "closed"))
    # while driven, the motor leads the link by half the gap (plus a tiny contact compression)
    assert gap[99, 2] == pytest.approx(width / 2, abs=2e-4)
    assert gap[-1, 2] == pytest.approx(-width / 2, abs=2e-4)
    # right after the reversal the link only feels its friction: it slows down less than the rigid
    # gear would make it; once the gap has closed it goes the other way like the rigid one
    decel_gap = (gap[104, 1] - gap[100, 1]) / 0.008
    decel_rigid = (rigid[104, 1] - rigid[100, 1]) / 0.008
    assert decel_rigid < 1.3 * decel_gap < 0
    assert gap[-1, 1] < -0.5 and gap[-1, 1] == pytest.approx(rigid[-1, 1], rel=0.1)


def test_a_closed_gap_passes_a_push_below_breakaway_without_moving_the_link(tmp_path):
    plant = _backlash_plant(tmp_path, 0.0044)
    plant.motor_q[0] = plant.q[0] + 0.0022  # gap closed on the positive side, at rest
    cur = np.zeros(N)
    cur[0] = 0.9 * 0.21 / plant.kt[0]  # 90 % of joint1's breakaway torque
    for _ in range(300):
        plant.step(command(cur, mode=np.array([0, 0, 3, 0, 3, 3, 3, 3])), 0.002)
    assert plant.q[0] == 0.0 and plant.dq[0] == 0.0  # stiction still holds through the gear


def test_bad_backlash_configurations_are_refused(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('base = "baseline"\n[hidden]\neffect = "backlash"\njoint = "joint1"\nmotor_inertia = 0\n')
    with pytest.raises(ConfigError, match="motor_inertia > 0"):
        ArmPlant(load_plant_config(bad))
    bad.write_text('[[effects]]\neffect = "backlash"\njoint = "joint2"\n'
                   '[hidden]\neffect = "backlash"\njoint = "joint2"\n')
    with pytest.raises(ConfigError, match="backlash is configured twice for joint2"):
        ArmPlant(load_plant_config(bad))
