"""Run-time safety for two arms under current control.

In current mode the servos do not enforce their position limits (shared/crane_x7_facts.md section
8), so software does, as RT's rt_manipulators_cpp does:
- inside a soft zone (`limit_margin` from each joint limit) current pushing further out is cut and a
  damped spring (`limit_stiffness`, `limit_damping`) pushes back; beyond the limit plus
  `limit_overshoot` the run stops;
- goal current is clamped to a fraction of each servo's Current Limit;
- a velocity guard per joint stops the run when a joint moves faster than allowed;
- a communication-error budget: too many failed bus cycles in a row or within one second stops;
- hardware-error status is polled every `hardware_poll_cycles` cycles; any bit stops.

`SafetyMonitor.check(...)` and friends return a `Breach` (or None). What to do with one is the
runner's job: a safe stop of both arms (zero current, torque off) and an event in the session.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from crane_io.description import ArmDescription, default_arm
from crane_io.errors import ConfigError

from .config import Config
from .controller_layout import SAFETY_ROWS


def _floats(x) -> list:
    """x (an array or a sequence of numbers) as a list of Python floats."""
    return x.tolist() if isinstance(x, np.ndarray) else np.asarray(x, dtype=float).tolist()


@dataclass(frozen=True)
class Breach:
    kind: str  # joint_limit, velocity, communication, hardware_error, servo_fault
    arm: str  # "leader", "follower" or "both"
    joint: str  # joint name, "" when not about one joint
    message: str  # one sentence for the user and the session's events

    def __str__(self) -> str:
        return self.message


class SafetyMonitor:
    def __init__(self, config: Config, arm: ArmDescription | None = None):
        self.config = config
        self.arm = arm or default_arm()
        s = config.safety
        names = self.arm.joint_names
        self.names = names
        missing = [n for n in names if n not in s.velocity_limit]
        if missing:
            raise ConfigError(f"the configuration has no safety.velocity_limit for {missing[0]}")
        self.lower = np.array([j.lower for j in self.arm.joints])
        self.upper = np.array([j.upper for j in self.arm.joints])
        self.soft_lower = self.lower + s.limit_margin
        self.soft_upper = self.upper - s.limit_margin
        self.stop_lower = self.lower - s.limit_overshoot
        self.stop_upper = self.upper + s.limit_overshoot
        self.vmax = np.array([s.velocity_limit[n] for n in names])
        kt = np.array([j.torque_constant for j in self.arm.joints])
        self.current_max = np.array([j.current_limit for j in self.arm.joints]) * s.current_fraction
        self.tau_max = self.current_max * kt
        self.k_wall = s.limit_stiffness
        self.d_wall = s.limit_damping
        self.bil = np.array([n in self.arm.bilateral_joints for n in names])
        self.bil_f = self.bil.astype(float)
        self._kernel_constants = None
        # the bounds as lists for the usual case of limit_torque and check (the limits are fixed once the
        # monitor is built)
        self._soft = (self.soft_lower.tolist(), self.soft_upper.tolist())
        self._stop = (self.stop_lower.tolist(), self.stop_upper.tolist())
        self._vmax = self.vmax.tolist()
        self._neg_tau_max = -self.tau_max
        self._consecutive = {"leader": 0, "follower": 0}
        self._recent_errors: deque[float] = deque()
        self.errors_total = 0

    # ---- shaping commands ---------------------------------------------------------------------------
    def limit_torque(self, q: np.ndarray, tau: np.ndarray, dq: np.ndarray | None = None,
                     spring: bool = True) -> np.ndarray:
        """The goal torque made safe: soft joint limits, then the current clamp (held joints: 0).

        Inside the soft zone the outward part of the command is cut and a damped spring pushes back
        (stiffness per rad of penetration, damping on outward velocity only). spring=False only cuts
        the outward part (used while aligning, when a joint may start deep inside the zone)."""
        if not self._outside(_floats(q), *self._soft):
            return np.minimum(np.maximum(tau * self.bil_f, self._neg_tau_max), self.tau_max)
        return self.limit_torque_arrays(q, tau, dq, spring)

    def limit_torque_arrays(self, q: np.ndarray, tau: np.ndarray, dq: np.ndarray | None = None,
                            spring: bool = True) -> np.ndarray:
        """limit_torque in array operations only: what it computes when a joint is in its soft zone, and
        the reference its usual-case shortcut is tested against (the same bits)."""
        tau = tau * self.bil_f
        over = q - self.soft_upper
        under = self.soft_lower - q
        up = over > 0
        lo = under > 0
        if not (up.any() or lo.any()):
            return np.minimum(np.maximum(tau, -self.tau_max), self.tau_max)
        if not spring:
            tau = np.where(up, np.minimum(tau, 0.0), tau)
            tau = np.where(lo, np.maximum(tau, 0.0), tau)
        else:
            v = np.zeros_like(q) if dq is None else dq
            if up.any():
                wall = -self.k_wall * over - self.d_wall * np.maximum(v, 0.0)
                tau = np.where(up, np.minimum(tau, 0.0) + wall, tau)
            if lo.any():
                wall = self.k_wall * under - self.d_wall * np.minimum(v, 0.0)
                tau = np.where(lo, np.maximum(tau, 0.0) + wall, tau)
        return np.clip(tau, -self.tau_max, self.tau_max) * self.bil

    def kernel_constants(self) -> np.ndarray:
        """The limits as the compiled controller reads them: the rows collect/controller_layout.SAFETY_ROWS
        names (soft zone bounds, tau_max, stop bounds, velocity guards, bilateral mask), a (rows, n)
        C-contiguous float64 array made at the first call (the limits are fixed once the monitor is built)."""
        if self._kernel_constants is None:
            self._kernel_constants = np.ascontiguousarray(np.array(
                [getattr(self, name) for name in SAFETY_ROWS], dtype=float))
        return self._kernel_constants

    @staticmethod
    def _outside(q: list, lower: list, upper: list) -> bool:
        """Any q[i] above upper[i] or below lower[i] (floats; `q - upper > 0` is `q > upper`)."""
        for x, lo, hi in zip(q, lower, upper):
            if x > hi or x < lo:
                return True
        return False

    # ---- checks -------------------------------------------------------------------------------------
    def check(self, arm_name: str, q: np.ndarray, dq: np.ndarray | None) -> Breach | None:
        """Joint positions beyond limit + overshoot, or velocities beyond the guard."""
        if not self._outside(_floats(q), *self._stop) and (
                dq is None or not any(abs(v) > m for v, m in zip(_floats(dq), self._vmax))):
            return None  # the usual case, decided without numpy; the same tests as below
        bad = (q > self.stop_upper) | (q < self.stop_lower)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            lim = self.upper[i] if q[i] > self.upper[i] else self.lower[i]
            return Breach("joint_limit", arm_name, self.names[i],
                          f"{arm_name} {self.names[i]} at {np.degrees(q[i]):.1f} deg went past its limit "
                          f"of {np.degrees(lim):.1f} deg")
        if dq is not None:
            fast = np.abs(dq) > self.vmax
            if fast.any():
                i = int(np.flatnonzero(fast)[0])
                return Breach("velocity", arm_name, self.names[i],
                              f"{arm_name} {self.names[i]} moved at {abs(dq[i]):.2f} rad/s, faster than "
                              f"its guard of {self.vmax[i]:.2f} rad/s")
        return None

    def bus_ok(self, arm_name: str) -> None:
        self._consecutive[arm_name] = 0

    def bus_error(self, arm_name: str, t: float, error: Exception) -> Breach | None:
        """Count one failed bus cycle at time t (s); a Breach when the budget is spent."""
        s = self.config.safety
        self.errors_total += 1
        self._consecutive[arm_name] = self._consecutive.get(arm_name, 0) + 1
        self._recent_errors.append(t)
        while self._recent_errors and self._recent_errors[0] < t - 1.0:
            self._recent_errors.popleft()
        if self._consecutive[arm_name] >= s.error_budget_consecutive:
            return Breach("communication", arm_name, "",
                          f"{arm_name} bus failed {self._consecutive[arm_name]} cycles in a row ({error})")
        if len(self._recent_errors) >= s.error_budget_per_second:
            return Breach("communication", arm_name, "",
                          f"{len(self._recent_errors)} failed bus cycles within one second ({error})")
        return None

    def poll_due(self, cycle: int) -> bool:
        return cycle % self.config.safety.hardware_poll_cycles == 0

    def hardware(self, arm_name: str, errors: dict[str, list[str]]) -> Breach | None:
        """A Breach for the first joint with hardware-error bits set."""
        for joint, faults in (errors or {}).items():
            if faults:
                return Breach("hardware_error", arm_name, str(joint),
                              f"{arm_name} {joint} reports {', '.join(faults)}")
        return None
