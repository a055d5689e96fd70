"""Test-only effects whose form the effects library lacks, planted (hidden) in simulated plants by the
TOML files beside this one (tests/test_discovery.py): `crane-train diagnose --discover` must find a term
of the right structure for each. Joint indices are the plant's learning joints (joint1, joint2, joint4)."""

import numpy as np

from crane_io.physics.effects import Effect, Param
from crane_io.physics.effects.base import joint_columns

JOINT2 = 1  # column of joint2 among (joint1, joint2, joint4)


class _Fast(Effect):
    """The simulated plant evaluates a user effect on one state per substep (about 10^5 calls per
    simulated minute); this shortcut skips the general checks there, same numbers."""

    def torque(self, q, dq, ddq, joint, values=None):
        if values is None or np.ndim(q) != 2:
            return super().torque(q, dq, ddq, joint, values)
        out = np.zeros(np.shape(q))
        out[:, joint] = self._one(np.asarray(q), np.asarray(dq), joint, values)
        return out


class AngleFriction(_Fast):
    name = "angle-friction-planted"
    title = "friction whose level changes with the angle"
    description = "c sign(dq) (1 + a cos(2 q)): a friction that is larger in some poses."
    signature = "the residual of {joint} steps where its velocity changes sign, by an angle-dependent amount"
    params = (Param("level", "N m", 0.2, "friction at cos(2q) = 0"),
              Param("depth", "1", 1.0, "relative change with cos(2q)", linear=False))
    shape_grid = {"depth": [1.0]}
    friction = True

    def _columns(self, q, dq, ddq, joint, shape):
        v = np.sign(dq[:, joint]) * (1 + shape["depth"] * np.cos(2 * q[:, joint]))
        return joint_columns(len(q), q.shape[1], joint, v)

    def _one(self, q, dq, joint, v):
        return v["level"] * np.sign(dq[:, joint]) * (1 + v["depth"] * np.cos(2 * q[:, joint]))


class CrossVelocity(_Fast):
    name = "cross-velocity-planted"
    title = "drag from joint2's velocity"
    description = "g dq2 on another joint: a cable dragged by joint2's motion."
    signature = "the residual of {joint} follows joint2's velocity"
    params = (Param("gain", "N m s/rad", 0.12, "torque per rad/s of joint2"),)

    def _columns(self, q, dq, ddq, joint, shape):
        return joint_columns(len(q), q.shape[1], joint, dq[:, JOINT2])

    def _one(self, q, dq, joint, v):
        return v["gain"] * dq[:, JOINT2]


class QuadraticDrag(_Fast):
    name = "quadratic-drag-planted"
    title = "quadratic drag"
    description = "d |dq| dq: drag growing with the square of the velocity."
    signature = "the residual of {joint} grows with the square of its velocity"
    params = (Param("drag", "N m s^2/rad^2", 0.1, "torque per (rad/s)^2"),)

    def _columns(self, q, dq, ddq, joint, shape):
        return joint_columns(len(q), q.shape[1], joint, np.abs(dq[:, joint]) * dq[:, joint])

    def _one(self, q, dq, joint, v):
        return v["drag"] * np.abs(dq[:, joint]) * dq[:, joint]


class AngleDamping(_Fast):
    name = "angle-damping-planted"
    title = "damping that changes with the angle"
    description = "b dq sin(q): a seal that drags more on one side of the joint's range."
    signature = "the residual of {joint} follows its velocity times the sine of its angle"
    params = (Param("damping", "N m s/rad", 0.15, "torque per rad/s at sin(q) = 1"),)

    def _columns(self, q, dq, ddq, joint, shape):
        return joint_columns(len(q), q.shape[1], joint, dq[:, joint] * np.sin(q[:, joint]))

    def _one(self, q, dq, joint, v):
        return v["damping"] * dq[:, joint] * np.sin(q[:, joint])
