"""A simulated arm built from an identified arm model (plant TOML key `arm_model`): its bodies are the
model's on both steppers, its friction joins the plant's effects, and a file that does not fit the plant
is one sentence."""

from __future__ import annotations

import numpy as np
import pytest

from crane_io.errors import ConfigError
from crane_io.physics.dynamics import ArmDynamics
from crane_io.physics.identified_model import IdentifiedArm
from crane_io.sim.arm_plant import ArmPlant
from crane_io.sim.plant_api import ActuatorCommand
from crane_io.sim.plant_config import load_plant_config

N = 8
BI = [0, 1, 3]  # joint1, joint2, joint4 in servo order
LOCKED = {"joint3": 0.0, "joint5": 0.0, "joint6": 0.0, "joint7": 0.0}
PLAIN = """joints = ["joint1", "joint2", "joint4"]
arm_model = "model/arm_model.toml"
[sensor]
position_noise_probability = 0.0
current_noise_lsb = 0.0
velocity_noise_lsb = 0.0
"""


def _point_mass(m: float, c) -> np.ndarray:
    """The ten standard parameters of a point mass m (kg) at c (m) in its joint's frame."""
    c = np.asarray(c, dtype=float)
    i = m * (c @ c * np.eye(3) - np.outer(c, c))
    return np.array([m, *(m * c), i[0, 0], i[0, 1], i[1, 1], i[0, 2], i[1, 2], i[2, 2]])


def _heavy_forearm(friction=None) -> IdentifiedArm:
    dyn = ArmDynamics()
    phi = dyn.standard_parameters()
    bodies = {n: phi[10 * b:10 * b + 10].copy() for b, n in enumerate(dyn.body_names())}
    bodies["joint4"] = bodies["joint4"] + _point_mass(0.5, (0.05, 0.0, 0.15))  # a heavier forearm
    bodies["joint2"] = bodies["joint2"] * 1.2
    return IdentifiedArm(("joint1", "joint2", "joint4"), dict(LOCKED), bodies, 0.0, friction or {})


def _plant_file(tmp_path, arm: IdentifiedArm, text: str = PLAIN):
    (tmp_path / "model").mkdir(exist_ok=True)
    (tmp_path / "model" / "arm_model.toml").write_text(arm.to_toml())
    path = tmp_path / "plant.toml"
    path.write_text(text)
    return path


def _idle(plant, dt):
    cmd = ActuatorCommand(np.full(N, True), np.zeros(N, dtype=int), np.zeros(N), np.zeros(N),
                          np.tile([800, 0, 0], (N, 1)), np.full(N, 3.2))
    plant.step(cmd, dt)


@pytest.mark.parametrize("kernel", [False, True])
def test_one_step_of_the_plant_follows_the_arm_models_forward_dynamics(tmp_path, kernel):
    arm = _heavy_forearm()
    plant = ArmPlant(_plant_file(tmp_path, arm), kernel=kernel)
    assert plant.kernel is kernel
    q = np.array([0.3, 0.8, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0])
    plant.set_state(q=q, dq=np.zeros(N))
    h = plant.config.substep_s
    _idle(plant, h)  # one substep, no motor torque: the arm falls under gravity
    _, dq = plant.state()
    expected = ArmDynamics(locked=LOCKED, identified=arm).forward_dynamics(q[BI], np.zeros(3), np.zeros(3))
    stock = ArmDynamics(locked=LOCKED).forward_dynamics(q[BI], np.zeros(3), np.zeros(3))
    assert np.abs(expected - stock).max() > 1.0  # rad/s^2: the two arms fall differently
    assert np.allclose(dq[BI] / h, expected, rtol=1e-6, atol=1e-6)


def test_the_models_friction_joins_the_plants_effects_and_the_truth_names_the_file(tmp_path):
    arm = _heavy_forearm({"joint2": {"viscous": 0.07, "coulomb": 0.2}})
    cfg = load_plant_config(_plant_file(tmp_path, arm))
    assert [(e.effect, e.joint, e.values) for e in cfg.effects] == [
        ("viscous", "joint2", {"viscous": 0.07}), ("coulomb", "joint2", {"coulomb": 0.2})]
    assert cfg.truth()["arm_model"] == str(tmp_path / "model" / "arm_model.toml")
    plant = ArmPlant(cfg)
    assert plant.terms.viscous[1] == pytest.approx(0.07) and plant.terms.coulomb_pos[1] == pytest.approx(0.2)


@pytest.mark.parametrize(("extra", "message"), [
    ('\n[[effects]]\neffect = "payload"\nmass = 0.2\n', "holds the identified payload"),
    ('\n[[effects]]\neffect = "stiction"\njoint = "joint2"\n', "gives the friction of joint2"),
    ('\n[locked]\njoint3 = 0.4\n', "joint3 held at 0 rad, not 0.4 rad"),
])
def test_a_plant_that_does_not_fit_its_arm_model_is_one_sentence(tmp_path, extra, message):
    arm = _heavy_forearm({"joint2": {"viscous": 0.07, "coulomb": 0.2}})
    text = PLAIN.replace("[sensor]", extra.strip() + "\n[sensor]") if extra.startswith("\n[locked]") \
        else PLAIN + extra
    with pytest.raises(ConfigError, match=message):
        load_plant_config(_plant_file(tmp_path, arm, text))


def test_another_joint_set_and_a_bad_file_are_one_sentence(tmp_path):
    arm = _heavy_forearm()
    path = _plant_file(tmp_path, arm, PLAIN.replace('"joint1", "joint2", "joint4"', '"joint1", "joint2"'))
    with pytest.raises(ConfigError, match="identified for the free joints joint1, joint2, joint4"):
        load_plant_config(path)
    path.write_text(PLAIN)
    (tmp_path / "model" / "arm_model.toml").write_text("[identified\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_plant_config(path)
    (tmp_path / "plant.toml").write_text(PLAIN.replace("model/arm_model.toml", "missing.toml"))
    with pytest.raises(ConfigError, match="missing.toml"):
        load_plant_config(tmp_path / "plant.toml")
    (tmp_path / "plant.toml").write_text(PLAIN.replace('"model/arm_model.toml"', "3"))
    with pytest.raises(ConfigError, match="arm_model must be the path"):
        load_plant_config(tmp_path / "plant.toml")
