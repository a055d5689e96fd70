"""ArmDynamics: gravity and inertia match the facts file, regressors reproduce RNEA, forward
dynamics inverts inverse dynamics."""

import numpy as np
import pytest

from crane_io.errors import ConfigError
from crane_io.physics.dynamics import ArmDynamics


@pytest.fixture(scope="module")
def dyn():
    return ArmDynamics()


@pytest.fixture(scope="module")
def states():
    rng = np.random.default_rng(1)
    n = 200
    q = np.column_stack([rng.uniform(-2.7, 2.7, n), rng.uniform(-1.57, 1.57, n), rng.uniform(-2.7, 0, n)])
    return q, rng.normal(0, 1.5, (n, 3)), rng.normal(0, 8, (n, 3))


def test_gravity_matches_the_facts_formulas_and_is_the_motor_torque(dyn):
    rng = np.random.default_rng(0)
    q = np.column_stack([rng.uniform(-3, 3, 300), rng.uniform(-1.57, 1.57, 300), rng.uniform(-2.8, 0, 300)])
    g = dyn.gravity_torque(q)
    q2, q4 = q[:, 1], q[:, 2]
    load_j2 = 2.327 * np.sin(q2) + 1.314 * np.sin(q2 + q4)
    load_j4 = 1.326 * np.sin(q2 + q4)
    # the motor must supply the negative of the gravity load
    assert np.abs(g[:, 1] + load_j2).max() < 0.055
    assert np.abs(g[:, 2] + load_j4).max() < 0.055
    assert np.abs(g[:, 0]).max() < 1e-9  # joint1's axis is vertical
    horizontal = dyn.gravity_torque(np.array([0.0, np.pi / 2, 0.0]))
    assert horizontal[1] == pytest.approx(-3.64, abs=0.01)
    assert horizontal[2] == pytest.approx(-1.33, abs=0.01)


def test_mass_matrix_matches_the_facts_inertias(dyn):
    upright = dyn.mass_matrix(np.zeros(3))
    assert np.diag(upright) == pytest.approx([0.00075, 0.154, 0.0312], abs=5e-4)
    bent = dyn.mass_matrix(np.array([0.0, 0.0, -np.pi / 2]))
    assert np.diag(bent) == pytest.approx([0.0315, 0.0872, 0.0312], abs=5e-4)
    out = dyn.mass_matrix(np.array([0.0, np.pi / 2, 0.0]))
    assert out[0, 0] == pytest.approx(0.154, abs=5e-4)
    assert np.allclose(upright, upright.T)


def test_regressor_times_standard_parameters_is_rnea(dyn, states):
    q, dq, ddq = states
    tau = dyn.inverse_dynamics(q, dq, ddq)
    y = dyn.regressor(q, dq, ddq)
    assert y.shape == (len(q), 3, 30)
    assert np.allclose(y @ dyn.standard_parameters(), tau, atol=1e-10)
    assert len(dyn.standard_parameter_names()) == 30


def test_base_regressor_times_base_parameters_is_rnea(dyn, states):
    q, dq, ddq = states
    tau = dyn.inverse_dynamics(q, dq, ddq)
    yb = dyn.base_regressor(q, dq, ddq)
    b = dyn.base_parameters()
    assert yb.shape == (len(q), 3, len(b))
    assert np.allclose(yb @ b, tau, atol=1e-10)
    # full column rank: the base parameters are identifiable
    assert np.linalg.matrix_rank(yb.reshape(-1, len(b))) == len(b) < 30
    assert len(dyn.base_parameter_names()) == len(b) == len(dyn.base_parameter_expressions())


def test_forward_dynamics_inverts_inverse_dynamics(dyn, states):
    q, dq, ddq = states
    tau = dyn.inverse_dynamics(q, dq, ddq)
    assert np.allclose(dyn.forward_dynamics(q, dq, tau), ddq, atol=1e-8)


def test_single_sample_and_joint_order(dyn, states):
    q, dq, ddq = states
    tau = dyn.inverse_dynamics(q, dq, ddq)
    assert np.allclose(dyn.inverse_dynamics(q[3], dq[3], ddq[3]), tau[3])
    perm = [2, 0, 1]
    other = ArmDynamics(joints=("joint4", "joint1", "joint2"))
    assert other.joint_names == ("joint4", "joint1", "joint2")
    assert np.allclose(other.inverse_dynamics(q[:, perm], dq[:, perm], ddq[:, perm]), tau[:, perm])
    assert np.allclose(other.mass_matrix(q[5, perm]), dyn.mass_matrix(q[5])[np.ix_(perm, perm)])
    assert np.allclose(other.base_regressor(q[:, perm], dq[:, perm], ddq[:, perm]) @ other.base_parameters(),
                       tau[:, perm])


def test_payload_is_linear_in_mass_and_matches_a_model_with_the_mass(dyn, states):
    q, dq, ddq = states
    heavy = ArmDynamics(payload_mass=0.35)
    extra = heavy.inverse_dynamics(q, dq, ddq) - dyn.inverse_dynamics(q, dq, ddq)
    assert np.allclose(dyn.payload_torque(q, dq, ddq, 0.35), extra, atol=1e-10)
    # held straight out horizontally, a 0.35 kg mass 0.6 m from joint2 needs about 2 N m more
    out = dyn.payload_torque(np.array([0.0, np.pi / 2, 0.0]), np.zeros(3), np.zeros(3), 0.35)
    assert out[1] == pytest.approx(-0.35 * 9.80665 * (0.105 - 0.105 + 0.624 - 0.105 + 0.08), abs=1e-6)


def test_bad_inputs_raise_config_errors(dyn):
    with pytest.raises(ConfigError, match="shape"):
        dyn.inverse_dynamics(np.zeros((4, 2)), np.zeros((4, 2)), np.zeros((4, 2)))
    with pytest.raises(ConfigError, match="NaN"):
        dyn.gravity_torque(np.array([0.0, np.nan, 0.0]))
    with pytest.raises(ConfigError, match="both free and locked"):
        ArmDynamics(locked={"joint2": 0.0})
