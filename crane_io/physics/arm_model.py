"""The project's own rigid-body description of the CRANE-X7, built in code with pinocchio.

Numbers from shared/crane_x7_facts.md section 4 (joint origins, axes, limits, link masses, centres
of mass and inertias; the URDF and RT's link CSV agree on them). No URDF file is read or shipped.

Conventions:
- Every joint origin has rpy = 0; axes are +Z (joints 1, 3, 5, 7) or -Y (joints 2, 4, 6, finger a).
- A link's inertia is given about its centre of mass in a frame rotated by the link's "inertial
  rpy"; for links with rpy = (pi/2, 0, 0) it is rotated into the link frame here (I = R I' R^T).
  The centre of mass is already expressed in the link frame.
- The base (shoulder fixed part) does not move and is attached to the universe.
- Finger b is a mimic of finger a in the URDF; it is lumped into the gripper base at its zero angle.
- A "tool" frame sits on the gripper base 0.08 m along its z axis, roughly between the fingertips
  (own estimate, not from a source); a payload is a point mass there.

`full_model()` is the 8-DOF model (7 arm joints + finger a); `reduced_model(joints, locked)` locks
every other joint at a given angle (default 0 rad) with pin.buildReducedModel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from crane_io.description import default_arm
from crane_io.errors import ConfigError

GRAVITY = 9.80665  # m/s^2
TOOL_FRAME = "tool"
TOOL_OFFSET = np.array([0.0, 0.0, 0.08])  # m, in the gripper base frame (own estimate)
BASE_HEIGHT = 0.005  # m, mounting-plate thickness below the shoulder fixed part

_Z = np.array([0.0, 0.0, 1.0])
_MINUS_Y = np.array([0.0, -1.0, 0.0])
_PLUS_Y = np.array([0.0, 1.0, 0.0])


@dataclass(frozen=True)
class LinkInertial:
    mass: float  # kg
    com: tuple[float, float, float]  # m, link frame
    rpy: tuple[float, float, float]  # inertial frame orientation
    ixx: float
    ixy: float
    ixz: float
    iyy: float
    iyz: float
    izz: float  # kg m^2 about the CoM in the inertial frame

    def inertia(self) -> pin.Inertia:
        i = np.array([[self.ixx, self.ixy, self.ixz], [self.ixy, self.iyy, self.iyz],
                      [self.ixz, self.iyz, self.izz]])
        r = pin.rpy.rpyToMatrix(*self.rpy)
        return pin.Inertia(self.mass, np.array(self.com), r @ i @ r.T)


_HALF_PI = (math.pi / 2, 0.0, 0.0)
_NO_RPY = (0.0, 0.0, 0.0)

# facts section 4, "Link inertials" (kg, m, kg m^2)
LINKS: dict[str, LinkInertial] = {
    "shoulder_fixed_part": LinkInertial(0.388, (-6.73e-3, -1.00e-6, 1.79e-2), _NO_RPY,
                                        3.25e-4, 1.20e-9, -4.71e-5, 4.83e-4, 1.95e-8, 5.86e-4),
    "shoulder_revolute_part": LinkInertial(0.253, (2.43e-4, -1.05e-4, 4.70e-2), _NO_RPY,
                                           1.79e-4, -7.32e-8, 8.89e-7, 1.76e-4, 6.23e-7, 8.96e-5),
    "upper_arm_fixed_part": LinkInertial(0.136, (3.10e-5, 1.90e-5, 3.42e-2), _HALF_PI,
                                         1.68e-4, 2.05e-8, -4.00e-7, 9.62e-5, 6.24e-8, 1.34e-4),
    "upper_arm_revolute_part": LinkInertial(0.321, (-1.37e-2, -8.10e-5, 9.52e-2), _NO_RPY,
                                            1.82e-3, 7.54e-7, -3.73e-5, 1.88e-3, 4.15e-6, 1.59e-4),
    "lower_arm_fixed_part": LinkInertial(0.222, (-9.39e-3, 6.40e-5, 8.04e-2), _HALF_PI,
                                         4.89e-4, -3.90e-6, 8.29e-8, 1.14e-4, 2.82e-6, 5.03e-4),
    "lower_arm_revolute_part": LinkInertial(0.207, (-8.40e-5, 4.62e-4, 6.37e-2), _NO_RPY,
                                            2.90e-4, 1.00e-7, -4.77e-7, 2.57e-4, -1.69e-5, 8.75e-5),
    "wrist": LinkInertial(0.14, (6.10e-3, 8.26e-4, -3.55e-3), _HALF_PI,
                          4.01e-5, -2.91e-6, 6.39e-7, 6.13e-5, -4.90e-7, 7.35e-5),
    "gripper_base": LinkInertial(0.121, (1.08e-4, -1.03e-3, 2.08e-2), _NO_RPY,
                                 3.20e-5, -9.45e-8, 2.61e-7, 4.14e-5, 3.88e-7, 4.29e-5),
    "finger_a": LinkInertial(0.0158, (-2.65e-3, 3.54e-3, 2.69e-2), _HALF_PI,
                             1.01e-5, -1.97e-7, -9.89e-8, 4.95e-6, 5.37e-7, 6.24e-6),
    "finger_b": LinkInertial(0.0139, (3.01e-3, 2.85e-3, 3.09e-2), _HALF_PI,
                             7.48e-6, 3.61e-7, 6.34e-8, 4.09e-6, 2.28e-7, 4.37e-6),
}

# (joint name, parent joint name or None, origin xyz in the parent link frame, axis, child link)
JOINTS: tuple[tuple[str, str | None, tuple[float, float, float], np.ndarray, str], ...] = (
    ("joint1", None, (0.0, 0.0, BASE_HEIGHT + 0.036), _Z, "shoulder_revolute_part"),
    ("joint2", "joint1", (0.0, 0.0, 0.064), _MINUS_Y, "upper_arm_fixed_part"),
    ("joint3", "joint2", (0.0, 0.0, 0.065), _Z, "upper_arm_revolute_part"),
    ("joint4", "joint3", (0.0, 0.0, 0.185), _MINUS_Y, "lower_arm_fixed_part"),
    ("joint5", "joint4", (0.0, 0.0, 0.121), _Z, "lower_arm_revolute_part"),
    ("joint6", "joint5", (0.0, 0.0, 0.129), _MINUS_Y, "wrist"),
    ("joint7", "joint6", (0.0, 0.0, 0.019), _Z, "gripper_base"),
    ("gripper", "joint7", (-0.012, 0.0, 0.024), _MINUS_Y, "finger_a"),
)
FINGER_B_ORIGIN = np.array([0.012, 0.0, 0.024])  # in the gripper base frame

JOINT_NAMES = tuple(j[0] for j in JOINTS)


def _joint_model(axis: np.ndarray):
    if np.allclose(axis, _Z):
        return pin.JointModelRZ()
    return pin.JointModelRevoluteUnaligned(axis.copy())


def full_model(payload_mass: float = 0.0, gravity: float = GRAVITY) -> pin.Model:
    """The 8-DOF CRANE-X7 (joint1..joint7 and the gripper's finger a), base fixed to the world.

    A payload (kg) is a point mass at the tool frame, rigidly attached to joint7's body.
    """
    if not (payload_mass >= 0 and math.isfinite(payload_mass)):
        raise ConfigError(f"the payload mass must be a non-negative number of kg, got {payload_mass}")
    arm = default_arm()
    model = pin.Model()
    model.name = "crane_x7"
    model.gravity.linear = np.array([0.0, 0.0, -gravity])
    model.appendBodyToJoint(0, LINKS["shoulder_fixed_part"].inertia(),
                            pin.SE3(np.eye(3), np.array([0.0, 0.0, BASE_HEIGHT])))
    ids: dict[str | None, int] = {None: 0}
    for name, parent, xyz, axis, link in JOINTS:
        placement = pin.SE3(np.eye(3), np.array(xyz))
        j = arm.joint(name)
        jid = model.addJoint(ids[parent], _joint_model(axis), placement, name,
                             np.array([10.0 if name in ("joint1", "joint2") else 4.0]),
                             np.array([j.velocity_limit]), np.array([j.lower]), np.array([j.upper]))
        model.appendBodyToJoint(jid, LINKS[link].inertia(), pin.SE3.Identity())
        model.addBodyFrame(link, jid, pin.SE3.Identity(), model.addJointFrame(jid))
        ids[name] = jid
    j7 = ids["joint7"]
    # finger b (URDF mimic of finger a) lumped into the gripper base at its zero angle
    model.appendBodyToJoint(j7, LINKS["finger_b"].inertia(), pin.SE3(np.eye(3), FINGER_B_ORIGIN))
    if payload_mass > 0:
        model.appendBodyToJoint(j7, pin.Inertia(payload_mass, TOOL_OFFSET.copy(), np.zeros((3, 3))),
                                pin.SE3.Identity())
    model.addFrame(pin.Frame(TOOL_FRAME, j7, model.getFrameId("gripper_base"),
                             pin.SE3(np.eye(3), TOOL_OFFSET.copy()), pin.FrameType.OP_FRAME))
    return model


def reduced_model(joints=("joint1", "joint2", "joint4"), locked: dict[str, float] | None = None,
                  payload_mass: float = 0.0, gravity: float = GRAVITY) -> pin.Model:
    """The model with only `joints` free; every other joint locked at `locked[name]` (default 0 rad).

    The free joints keep kinematic order in the returned model (joint1 before joint2 ...).
    """
    joints = tuple(joints)
    unknown = [n for n in joints if n not in JOINT_NAMES]
    if unknown or not joints:
        given = ', '.join(map(repr, unknown)) or '(none given)'
        raise ConfigError(f"unknown joint(s) {given} for the dynamics; "
                          f"joints are {', '.join(JOINT_NAMES)}")
    if len(set(joints)) != len(joints):
        raise ConfigError(f"the dynamics joints {joints} name a joint twice")
    locked = dict(locked or {})
    bad = [n for n in locked if n not in JOINT_NAMES]
    if bad:
        raise ConfigError(f"cannot lock unknown joint(s) {', '.join(map(repr, bad))}; joints are "
                          f"{', '.join(JOINT_NAMES)}")
    full = full_model(payload_mass, gravity)
    q_ref = pin.neutral(full)
    for name, value in locked.items():
        if not math.isfinite(float(value)):
            raise ConfigError(f"the locked angle of {name} must be a finite number of rad, got {value}")
        q_ref[full.joints[full.getJointId(name)].idx_q] = float(value)
    to_lock = [full.getJointId(n) for n in JOINT_NAMES if n not in joints]
    return pin.buildReducedModel(full, to_lock, q_ref)
