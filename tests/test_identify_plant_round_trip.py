"""Identified arm model round trip: identify an arm carrying a payload from exciting data, build the
simulated arm from the arm_model.toml identify writes (plant key `arm_model`), and the simulator's gravity
torque is the identified model's and the true arm's."""

from __future__ import annotations

import numpy as np
import pytest

from crane_io.physics.dynamics import ArmDynamics
from crane_io.sim.arm_plant import ArmPlant
from tests.sessions import write_synthetic_session
from train.identification.identify import identify

JOINTS = ("joint1", "joint2", "joint4")
HELD = {"joint3": 0.2, "joint5": 0.4, "joint6": 0.5, "joint7": 0.6}  # where the synthetic session holds them
PAYLOAD = 0.3  # kg at the tool


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("round")
    truth = ArmDynamics(JOINTS, locked=HELD, payload_mass=PAYLOAD)
    session, _ = write_synthetic_session(tmp / "s.h5", 100.0, rate_hz=100, seed=4,
                                         dynamics=truth.inverse_dynamics)
    result = identify(str(session), scale_to_data=True)
    result.save(tmp / "id")
    plant_toml = tmp / "plant.toml"
    plant_toml.write_text('joints = ["joint1", "joint2", "joint4"]\narm_model = "id/arm_model.toml"\n'
                          + "[locked]\n" + "".join(f"{k} = {v}\n" for k, v in HELD.items()))
    return truth, result, plant_toml


def test_the_simulator_built_from_the_identified_model_has_its_gravity_and_the_payloads(identified):
    truth, result, plant_toml = identified
    plant = ArmPlant(plant_toml)
    rng = np.random.default_rng(1)
    q = rng.uniform([-1.5, -1.4, -2.0], [1.5, 1.4, -0.3], (20, 3))
    g_plant = plant.dyn.gravity_torque(q)
    rest = np.zeros_like(q)
    g_model = result.fit.model.predict(q, rest, rest)  # the identified model at rest: its gravity
    assert np.allclose(g_plant, g_model, atol=1e-6)
    g_true = truth.gravity_torque(q)
    without = ArmDynamics(JOINTS, locked=HELD).gravity_torque(q)
    assert np.abs(g_true - without).max() > 0.5  # N m: the payload matters at these poses
    assert np.abs(g_plant - g_true).max() < 0.1 * np.abs(g_true - without).max()
