"""Objects the simulated CRANE-X7 can touch: the contact physics of a plant's [[environment]].

Every object is a unilateral spring-damper (penalty contact). Torques are the torque the WORLD
applies to the plant's integrated joints (`joints`, arm order, n of them; default joint1, joint2,
joint4; N m): positive pushes the joint positive, like an operator's hand (crane_io.sim.arm_plant adds
them to the external torque in every substep, so the stick-slip friction sees them).

- JointWall: a wall in one integrated joint's angle. side "above" stops motion above `angle` (penetration
  p = q - angle > 0), "below" stops motion below it (p = angle - q). The wall pushes back with
  stiffness p + damping x penetration velocity; damping acts only while penetrating and the total is
  clamped to the pushing sign (a wall never pulls).
- Plane: a Cartesian plane in the arm's base frame (a point of it and the normal into free space),
  checked against one frame of the integrated-joint model (default "tool": 0.08 m beyond the gripper
  base, about between the fingertips; on the last integrated joint's body, the joints after it being
  locked). Penetration
  d = -n . (p - p0) > 0; normal force F_n = max(0, stiffness d - damping v_n) with v_n = n . v the
  point's velocity along the normal; tangential friction F_t = -mu F_n tanh(|v_t| / v_s) v_t / |v_t|
  (opposes the sliding velocity v_t, bounded by mu F_n; smoothed, so there is no true sticking on the
  plane). Joint torque = J^T (F_n n + F_t) with the frame's linear Jacobian J (pinocchio,
  LOCAL_WORLD_ALIGNED) over the integrated joints, (3, n).

    env = Environment(config.environment, joints=("joint1", "joint2", "joint4"))
    env.contact_torque(q, dq) -> (n,)                # N m on the integrated joints
    env.in_contact(q) -> bool

Joint walls are plain float arithmetic; the kinematics (forward kinematics, and the Jacobian only
while a plane is penetrated) are computed only when a plane exists.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from crane_io.errors import ConfigError
from crane_io.sim.plant_config import BILATERAL_JOINTS, JointWallSpec, PlaneSpec


class JointWall:
    """A wall in joint `index`'s angle (see the module docstring); `spec` a JointWallSpec."""

    def __init__(self, spec: JointWallSpec, index: int):
        self.spec = spec
        self.index = int(index)
        self.angle = float(spec.angle)
        self.sign = 1.0 if spec.side == "above" else -1.0  # the direction into the wall
        self.stiffness = float(spec.stiffness)
        self.damping = float(spec.damping)

    def penetration(self, q: Sequence[float]) -> float:
        """How far (rad) joint `index` is inside the wall; <= 0 when free."""
        return self.sign * (q[self.index] - self.angle)

    def torque(self, q: Sequence[float], dq: Sequence[float]) -> float:
        """The wall's torque (N m) on its joint: pushes out of the wall, never pulls."""
        p = self.sign * (q[self.index] - self.angle)
        if p <= 0.0:
            return 0.0
        push = self.stiffness * p + self.damping * self.sign * dq[self.index]  # magnitude, outward
        return -self.sign * push if push > 0.0 else 0.0

    def surface(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """For planning a press from pose q (rad): (the pose touching the wall, the unit joint-space
        direction into it, the wall's stiffness along that direction in N m/rad)."""
        q_s = np.array(q, dtype=float)
        q_s[self.index] = self.angle
        direction = np.zeros(len(q_s))
        direction[self.index] = self.sign
        return q_s, direction, self.stiffness


class Plane:
    """A plane against one frame of the arm (see the module docstring); `spec` a PlaneSpec, `model`
    the pinocchio model whose configuration is the integrated joints' angles."""

    def __init__(self, spec: PlaneSpec, model: pin.Model):
        self.spec = spec
        self.model = model
        self.data = model.createData()
        self.frame = model.getFrameId(spec.frame)
        self.point = np.array(spec.point, dtype=float)
        self.normal = np.array(spec.normal, dtype=float)
        self.stiffness = float(spec.stiffness)
        self.damping = float(spec.damping)
        self.friction = float(spec.friction)
        self.friction_velocity = float(spec.friction_velocity)

    def position(self, q) -> np.ndarray:
        """Position (m, base frame) of the contact frame at joint angles q (n,)."""
        pin.forwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        return pin.updateFramePlacement(self.model, self.data, self.frame).translation

    def distance(self, q) -> float:
        """Signed distance (m) of the contact frame from the plane; negative inside."""
        return float(self.normal @ (self.position(q) - self.point))

    def jacobian(self, q) -> np.ndarray:
        """Linear Jacobian (3, n) of the contact frame (LOCAL_WORLD_ALIGNED), m/rad."""
        return pin.computeFrameJacobian(self.model, self.data, np.asarray(q, dtype=float), self.frame,
                                        pin.LOCAL_WORLD_ALIGNED)[:3]

    def force(self, v: np.ndarray, depth: float) -> np.ndarray:
        """Contact force (N, base frame) on the arm at penetration depth (m) and point velocity v (m/s)."""
        n = self.normal
        v_n = float(n @ v)
        f_n = self.stiffness * depth - self.damping * v_n
        if f_n <= 0.0:
            return np.zeros(3)
        force = f_n * n
        v_t = v - v_n * n
        speed = math.sqrt(float(v_t @ v_t))
        if self.friction > 0.0 and speed > 0.0:
            force = force - (self.friction * f_n * math.tanh(speed / self.friction_velocity) / speed) * v_t
        return force

    def torque(self, q, dq) -> np.ndarray | None:
        """The plane's torque (n,) on the joints (N m), or None when the frame is outside the plane."""
        depth = -self.distance(q)
        if depth <= 0.0:
            return None
        jac = self.jacobian(q)
        return jac.T @ self.force(jac @ np.asarray(dq, dtype=float), depth)

    def surface(self, q: np.ndarray, lo=None, hi=None, iterations: int = 30,
                max_step: float = 0.2) -> tuple[np.ndarray, np.ndarray, float] | None:
        """For planning a press from pose q (rad): (a nearby pose whose frame lies on the plane, found
        by minimum-norm Newton steps of at most `max_step` rad kept inside [lo, hi] rad; the unit
        joint-space direction into the plane there; the plane's stiffness along that direction in
        N m/rad), or None if the plane is out of reach."""
        q_s = np.array(q, dtype=float)
        for _ in range(iterations):
            d = self.distance(q_s)
            j_n = self.normal @ self.jacobian(q_s)
            norm2 = float(j_n @ j_n)
            if norm2 < 1e-8:
                return None
            if abs(d) < 1e-6:
                return q_s, -j_n / math.sqrt(norm2), self.stiffness * norm2
            step = j_n * (d / norm2)
            size = math.sqrt(float(step @ step))
            if size > max_step:
                step = step * (max_step / size)
            q_s = q_s - step
            if lo is not None:
                q_s = np.clip(q_s, lo, hi)
        return None


class Environment:
    """Every object of a plant's [[environment]] (a list of JointWallSpec / PlaneSpec) acting on the
    integrated `joints` (arm order, default joint1, joint2, joint4; a wall on another joint ->
    ConfigError). `model`: the pinocchio model of those joints (default: crane_io.physics.dynamics.ArmDynamics
    with the other joints locked at `locked`, rad, default 0); only built when there is a plane."""

    def __init__(self, specs: Sequence[JointWallSpec | PlaneSpec] = (), model: pin.Model | None = None,
                 locked: dict[str, float] | None = None, joints: Sequence[str] = BILATERAL_JOINTS):
        self.specs = list(specs)
        self.joints = tuple(joints)
        for s in self.specs:
            if isinstance(s, JointWallSpec) and s.joint not in self.joints:
                raise ConfigError(f"the joint wall on {s.joint} needs {s.joint} among the integrated joints "
                                  f"({', '.join(self.joints)}); integrate it or remove the wall")
        self.walls = [JointWall(s, self.joints.index(s.joint)) for s in self.specs
                      if isinstance(s, JointWallSpec)]
        plane_specs = [s for s in self.specs if isinstance(s, PlaneSpec)]
        if plane_specs and model is None:
            from crane_io.physics.dynamics import ArmDynamics

            locked = {n: v for n, v in (locked or {}).items() if n not in self.joints}
            model = ArmDynamics(self.joints, locked=locked).model
        self.planes = [Plane(s, model) for s in plane_specs]
        self.objects = [self._object(s) for s in self.specs]  # in the order given

    def _object(self, spec):
        pool = self.walls if isinstance(spec, JointWallSpec) else self.planes
        return next(o for o in pool if o.spec is spec)

    def __len__(self) -> int:
        return len(self.specs)

    def torque_list(self, q: Sequence[float], dq: Sequence[float]) -> list[float]:
        """contact_torque as a list of n floats (the plant's hot path)."""
        out = [0.0] * len(q)
        for wall in self.walls:
            out[wall.index] += wall.torque(q, dq)
        for plane in self.planes:
            t = plane.torque(q, dq)
            if t is not None:
                for i, x in enumerate(t.tolist()):
                    out[i] += x
        return out

    def contact_torque(self, q, dq) -> np.ndarray:
        """(n,) torque (N m) the objects apply to the integrated joints at angles q, velocities dq."""
        return np.array(self.torque_list(np.asarray(q, dtype=float).tolist(),
                                         np.asarray(dq, dtype=float).tolist()))

    def in_contact(self, q) -> bool:
        """True when any object is penetrated at joint angles q (n,)."""
        q = np.asarray(q, dtype=float)
        ql = q.tolist()
        return (any(w.penetration(ql) > 0.0 for w in self.walls)
                or any(p.distance(q) < 0.0 for p in self.planes))
