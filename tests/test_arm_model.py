"""The code-built CRANE-X7 model matches the facts file's numbers (section 4)."""

import numpy as np
import pinocchio as pin
import pytest

from crane_io.errors import ConfigError
from crane_io.physics.arm_model import JOINT_NAMES, full_model, reduced_model


def test_full_model_has_eight_joints_and_the_urdf_mass():
    m = full_model()
    assert m.nq == 8
    assert [m.names[i] for i in range(1, m.njoints)] == list(JOINT_NAMES)
    assert sum(i.mass for i in m.inertias) == pytest.approx(1.818, abs=1e-3)


def test_zero_pose_joint_heights_match_the_csv_home_positions():
    m = full_model()
    d = m.createData()
    pin.forwardKinematics(m, d, pin.neutral(m))
    z = [d.oMi[m.getJointId(n)].translation[2] for n in JOINT_NAMES]
    assert np.allclose(z, [0.041, 0.105, 0.170, 0.355, 0.476, 0.605, 0.624, 0.648], atol=1e-9)


def test_limits_come_from_the_description():
    m = full_model()
    j4 = m.joints[m.getJointId("joint4")].idx_q
    assert m.lowerPositionLimit[j4] == pytest.approx(np.deg2rad(-159))
    assert m.upperPositionLimit[j4] == pytest.approx(np.deg2rad(0.001))


def test_reduced_model_keeps_the_chosen_joints_and_locks_the_rest():
    m = reduced_model(("joint1", "joint2", "joint4"))
    assert [m.names[i] for i in range(1, m.njoints)] == ["joint1", "joint2", "joint4"]
    # locking joint3 at 90 deg turns the elbow axis: a bent forearm then swings sideways and no
    # longer loads joint2
    d = m.createData()
    m3 = reduced_model(("joint1", "joint2", "joint4"), locked={"joint3": np.pi / 2})
    d3 = m3.createData()
    q = np.array([0.0, 0.0, -np.pi / 2])
    g0 = pin.computeGeneralizedGravity(m, d, q)
    g3 = pin.computeGeneralizedGravity(m3, d3, q)
    assert abs(g0[1]) > 1.0 and abs(g3[1]) < 0.06


def test_bad_joint_names_raise_config_errors():
    with pytest.raises(ConfigError, match="unknown joint"):
        reduced_model(("joint1", "elbow"))
    with pytest.raises(ConfigError, match="cannot lock"):
        reduced_model(locked={"wrist": 0.1})
    with pytest.raises(ConfigError, match="payload"):
        full_model(payload_mass=-1)
