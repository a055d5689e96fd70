"""An identified arm model file (crane_io/physics/identified_model.py): read as data, checked (physically
consistent bodies, the configuration it was identified for), and used by the dynamics."""

from __future__ import annotations

import numpy as np
import pytest

from crane_io.errors import ConfigError
from crane_io.physics.dynamics import ArmDynamics
from crane_io.physics.identified_model import IdentifiedArm
from crane_io.toml_config import read_toml


@pytest.fixture(scope="module")
def nominal():
    dyn = ArmDynamics()
    phi = dyn.standard_parameters()
    bodies = {n: phi[10 * b:10 * b + 10].copy() for b, n in enumerate(dyn.body_names())}
    locked = {"joint3": 0.0, "joint5": 0.0, "joint6": 0.0, "joint7": 0.0, "gripper": 0.0}
    return dyn, IdentifiedArm(("joint1", "joint2", "joint4"), locked, bodies, 0.0,
                              {"joint2": {"viscous": 0.05, "coulomb": 0.24}})


def test_the_file_round_trips_and_the_nominal_bodies_give_the_nominal_dynamics(nominal, tmp_path):
    dyn, arm = nominal
    path = tmp_path / "arm.toml"
    path.write_text(arm.to_toml())
    back = IdentifiedArm.from_toml(path)
    assert back.free == arm.free and back.friction == arm.friction
    assert all(np.array_equal(back.bodies[n], arm.bodies[n]) for n in arm.free)
    q = np.array([[0.3, 0.8, -1.0], [-0.5, -0.2, -0.4]])
    dq, ddq = np.ones_like(q) * 0.4, np.ones_like(q) * -1.5
    expected = dyn.inverse_dynamics(q, dq, ddq)
    assert np.allclose(ArmDynamics(identified=back).inverse_dynamics(q, dq, ddq), expected)


def test_a_heavier_forearm_changes_the_gravity_torque(nominal):
    dyn, arm = nominal
    heavy = IdentifiedArm(arm.free, arm.locked, {**arm.bodies, "joint4": arm.bodies["joint4"] * 1.5})
    q = np.array([0.0, 0.8, -1.0])
    assert abs(ArmDynamics(identified=heavy).gravity_torque(q)[2]) > 1.4 * abs(dyn.gravity_torque(q)[2])


def test_another_configuration_is_refused_in_one_sentence(nominal):
    _, arm = nominal
    with pytest.raises(ConfigError, match="identified for the free joints joint1, joint2, joint4"):
        ArmDynamics(joints=("joint1", "joint2"), identified=arm)
    with pytest.raises(ConfigError, match="joint3 held at 0 rad, not 0.5 rad"):
        ArmDynamics(locked={"joint3": 0.5}, identified=arm)


@pytest.mark.parametrize(("edit", "message"), [
    (lambda t: t.replace("format_version = 1", "format_version = 9"), "format_version 9"),
    (lambda t: t.replace('free = ["joint1", "joint2", "joint4"]', 'free = ["joint1", "wrist"]'), "`free`"),
    (lambda t: t + "\n[identified.extra]\nx = 1\n", "unknown key 'extra'"),
    (lambda t: t.replace("parameters = [0.253", "parameters = [-0.253"), "not physically consistent"),
    (lambda t: t.replace("viscous = 0.05", "viscous = -0.05"), "non-negative"),
    (lambda t: t.replace("[identified]", "[identified"), "not valid TOML"),
])
def test_a_damaged_file_is_refused_in_one_sentence(nominal, tmp_path, edit, message):
    _, arm = nominal
    text = arm.to_toml()
    path = tmp_path / "arm.toml"
    path.write_text(edit(text))
    assert edit(text) != text
    with pytest.raises(ConfigError, match=message):
        IdentifiedArm.from_toml(path)


def test_the_controller_takes_the_identified_gravity_and_viscous_friction(nominal):
    from collect.config import load_config
    from collect.controller import BilateralController

    dyn, arm = nominal
    config = load_config()
    heavy = IdentifiedArm(arm.free, arm.locked, {**arm.bodies, "joint4": arm.bodies["joint4"] * 1.5},
                          friction={"joint2": {"viscous": 0.123}})
    stock = BilateralController(config, compiled=False)
    ident = BilateralController(config, compiled=False, arm_model=heavy)
    names = stock.arm.joint_names
    q = np.zeros(len(names))
    q[names.index("joint2")], q[names.index("joint4")] = 0.8, -1.0
    j4 = names.index("joint4")
    assert abs(ident.gravity(q)[j4]) > 1.4 * abs(stock.gravity(q)[j4])
    assert ident.D[names.index("joint2")] == 0.123
    assert ident.D[names.index("joint1")] == stock.D[names.index("joint1")]


def test_the_nominal_observers_subtract_the_identified_coulomb_friction_with_a_smooth_sign(nominal):
    from collect.config import load_config
    from collect.controller import NOMINAL_COULOMB_VELOCITY, BilateralController
    from collect.controller_layout import ArmSignals

    _, arm = nominal  # joint2: viscous 0.05, Coulomb 0.24
    config = load_config()
    without = IdentifiedArm(arm.free, arm.locked, arm.bodies, friction={"joint2": {"viscous": 0.05}})
    assert not BilateralController(config, compiled=None, arm_model=arm).compiled  # the compiled one declines
    ctl = {name: BilateralController(config, compiled=False, arm_model=a)
           for name, a in (("coulomb", arm), ("viscous", without))}
    with pytest.raises(ConfigError, match="Coulomb friction"):
        BilateralController(config, compiled=True, arm_model=arm)
    names = ctl["coulomb"].arm.joint_names
    q0 = np.random.default_rng(0).normal(0.0, 0.3, len(names))
    q = q0 + 0.002 * np.arange(1, len(names) + 1)  # a step: the pseudo-derivative velocity is not zero
    for c in ctl.values():
        c.step(ArmSignals(q0.copy()), ArmSignals(q0.copy()), 0.002)  # both observers in the same state
    est = {n: c.observer("follower").update(q, 0.002) for n, c in ctl.items()}  # (w, tau_dis, tau_res)
    j2 = names.index("joint2")
    w = est["coulomb"][0][j2]
    assert abs(w) > 0.1 * NOMINAL_COULOMB_VELOCITY
    diff = est["viscous"][2] - est["coulomb"][2]
    assert diff[j2] == pytest.approx(0.24 * np.tanh(w / NOMINAL_COULOMB_VELOCITY), rel=1e-9)
    assert np.all(np.delete(diff, j2) == 0.0)  # the other joints' friction is the description's


def test_run_records_the_arm_model_and_refuses_a_bad_one(nominal, tmp_path):
    import h5py
    from click.testing import CliRunner

    from collect.cli import main as collect_main

    _, arm = nominal
    path = tmp_path / "arm.toml"
    path.write_text(arm.to_toml())
    out = tmp_path / "s.h5"
    r = CliRunner().invoke(collect_main, ["run", "--sim", "--plant", "simple", "--duration", "0.2",
                                          "-o", str(out), "--arm-model", str(path)])
    assert r.exit_code == 0, r.output
    with h5py.File(out, "r") as f:
        recorded = read_toml(text=f.attrs["arm_model_toml"])["identified"]
    assert IdentifiedArm.from_dict(recorded, "the session's arm model").free == arm.free
    path.write_text(arm.to_toml().replace("parameters = [0.253", "parameters = [-0.253"))
    r = CliRunner().invoke(collect_main, ["run", "--sim", "--plant", "simple", "--duration", "0.2",
                                          "-o", str(tmp_path / "t.h5"), "--arm-model", str(path)])
    assert r.exit_code == 2 and "not physically consistent" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "t.h5").exists()


def test_a_body_just_outside_the_consistent_set_is_brought_in_and_one_far_outside_is_left(nominal):
    from crane_io.physics.identified_model import into_consistent, pseudo_inertia

    _, arm = nominal
    v = arm.bodies["joint2"].copy()
    lowest = np.linalg.eigvalsh(pseudo_inertia(v)).min()
    near = v.copy()
    near[[4, 6, 9]] -= 2 * (lowest + 5e-7)  # J - (lowest + 5e-7) 1: just outside
    assert np.linalg.eigvalsh(pseudo_inertia(near)).min() < -1e-7
    fixed = into_consistent(near)
    assert np.linalg.eigvalsh(pseudo_inertia(fixed)).min() >= 0 and np.abs(fixed - near).max() < 1e-5
    far = v.copy()
    far[0] = -0.1
    assert np.array_equal(into_consistent(far), far)
