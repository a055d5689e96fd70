"""The light default plant behind the simulated servo chain: independent, gravity-free joints.

Each joint is a rigid inertia J with viscous friction b*dq and Coulomb friction fc*sign(dq)
(sticking while the applied torque is below fc). The motor torque depends on the servo's mode:

- current mode (0): torque = Kt * goal current (the servo already clamped it to its Current Limit);
- position modes (3, 4, 5): a PD controller like the servo's own, with stiffness
  P/128 * (stall torque / 885) per pulse (the e-manual's KPP = P/128 acting on PWM, full PWM = 885
  giving stall torque), a derivative term from D, and a damping floor of 0.7 of critical so that the
  default D = 0 still settles as the real geared servo does; limited to Current Limit (mode 3, 4) or
  Goal Current (mode 5);
- any other mode (velocity, PWM), or torque disabled: no motor torque.

The motor current the servo reports is the motor torque divided by Kt. The arm's full dynamics
(gravity, coupling, effects) live in crane_io/sim/arm_plant.py; this plant is for tests and rehearsals
where that does not matter.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from crane_io.dynamixel.units import RAD_PER_PULSE
from crane_io.sim.plant_api import ActuatorCommand, SensorReading

# Defaults per CRANE-X7 servo ID 2..9 (joint1..joint7, gripper). Inertia: the SKL bilateral
# program's nominal J; viscous: its identified D where known (0.1 where it gave none);
# Coulomb: a modest guess, since no public source gives one (facts section 7).
DEFAULT_IDS = (2, 3, 4, 5, 6, 7, 8, 9)
DEFAULT_INERTIA = (0.012258, 0.11299, 0.012028, 0.04, 0.005676, 0.0066, 0.006281, 0.006891)
DEFAULT_VISCOUS = (0.0501, 0.1, 0.242, 0.1, 0.040, 0.0391, 0.05, 0.021)
DEFAULT_COULOMB = (0.1, 0.15, 0.1, 0.1, 0.05, 0.05, 0.05, 0.05)
DEFAULT_KT = (2.20, 3.60, 2.20, 2.20, 2.20, 2.20, 2.20, 2.20)  # N m/A, crane_io.description
DEFAULT_STALL = (4.1, 10.6, 4.1, 4.1, 4.1, 4.1, 4.1, 4.1)  # N m at 12 V (datasheets)

POSITION_MODES = (3, 4, 5)
MAX_SUBSTEP_S = 0.0005


def _vec(value, n: int, name: str) -> np.ndarray:
    arr = np.broadcast_to(np.asarray(value, dtype=float), (n,)).copy() if np.ndim(value) == 0 \
        else np.asarray(value, dtype=float)
    if arr.shape != (n,):
        raise ValueError(f"{name} needs {n} values, got {arr.shape}")
    return arr


class SimplePlant:
    """Gravity-free independent joints with inertia, viscous and Coulomb friction (see module doc)."""

    def __init__(
        self,
        servo_ids: Sequence[int] = DEFAULT_IDS,
        inertia: Sequence[float] | float | None = None,
        viscous: Sequence[float] | float | None = None,
        coulomb: Sequence[float] | float | None = None,
        kt: Sequence[float] | float | None = None,
        stall_torque: Sequence[float] | float | None = None,
        lower: Sequence[float] | float | None = None,
        upper: Sequence[float] | float | None = None,
        initial_position: Sequence[float] | float = 0.0,
    ):
        self.servo_ids = tuple(int(i) for i in servo_ids)
        n = len(self.servo_ids)
        crane = self.servo_ids == DEFAULT_IDS  # None means: the CRANE-X7 value, or a generic one

        def pick(value, crane_default, generic):
            return value if value is not None else (crane_default if crane else generic)

        inertia = pick(inertia, DEFAULT_INERTIA, 0.01)
        viscous = pick(viscous, DEFAULT_VISCOUS, 0.05)
        coulomb = pick(coulomb, DEFAULT_COULOMB, 0.05)
        kt = pick(kt, DEFAULT_KT, 2.20)
        stall_torque = pick(stall_torque, DEFAULT_STALL, 4.1)
        self.inertia = _vec(inertia, n, "inertia")
        self.viscous = _vec(viscous, n, "viscous")
        self.coulomb = _vec(coulomb, n, "coulomb")
        self.kt = _vec(kt, n, "kt")
        self.stall_torque = _vec(stall_torque, n, "stall_torque")
        if np.any(self.inertia <= 0) or np.any(self.kt <= 0):
            raise ValueError("inertia and kt must be positive")
        self.lower = _vec(-np.inf if lower is None else lower, n, "lower")
        self.upper = _vec(np.inf if upper is None else upper, n, "upper")
        self.q = _vec(initial_position, n, "initial_position")
        self.dq = np.zeros(n)
        self.current = np.zeros(n)
        self.external_torque = np.zeros(n)
        self.errors: dict[int, int] = {}  # hardware-error bits to report per servo ID (tests)
        self.time = 0.0

    @classmethod
    def from_arm(cls, arm, **overrides) -> SimplePlant:
        """A SimplePlant for an ArmDescription: its IDs, torque constants and joint limits (+3 deg
        mechanical margin); inertia and friction are the CRANE-X7 defaults when the IDs are 2..9."""
        ids = arm.servo_ids
        kwargs = dict(
            servo_ids=ids,
            kt=[j.torque_constant for j in arm.joints],
            stall_torque=[10.6 if j.model == "XM540-W270" else 4.1 for j in arm.joints],
            lower=[j.lower - math.radians(3) for j in arm.joints],
            upper=[j.upper + math.radians(3) for j in arm.joints],
        )
        kwargs.update(overrides)
        return cls(**kwargs)

    # ---- Plant protocol --------------------------------------------------------------------------
    def motor_torque(self, command: ActuatorCommand) -> np.ndarray:
        n = len(self.servo_ids)
        tau = np.zeros(n)
        enabled = np.asarray(command.torque_enabled, dtype=bool)
        mode = np.asarray(command.operating_mode)
        cur = enabled & (mode == 0)
        tau[cur] = self.kt[cur] * np.asarray(command.goal_current, dtype=float)[cur]
        pos, kp, kd, cap = self.position_controller(command)
        if np.any(pos):
            err = np.asarray(command.goal_position, dtype=float) - self.q
            t = kp * err - kd * self.dq
            tau[pos] = np.clip(t, -cap, cap)[pos]
        return tau

    def position_controller(self, command: ActuatorCommand) -> tuple[np.ndarray, ...]:
        """The servo's position controller for a command: (pos, kp, kd, cap), each (n,): which servos
        are in a position mode, and torque = clip(kp (goal - q) - kd dq, -cap, cap) for them (stiffness
        P/128 x stall torque/885 per pulse, damping D's or at least 0.7 of critical, cap = the current
        limit, or |goal current| in current-based position mode, times Kt). kp, kd, cap are None when
        no servo is in a position mode."""
        enabled = np.asarray(command.torque_enabled, dtype=bool)
        mode = np.asarray(command.operating_mode)
        pos = enabled & ((mode == 3) | (mode == 4) | (mode == 5))  # POSITION_MODES
        if not np.any(pos):
            return pos, None, None, None
        limit = np.asarray(command.current_limit, dtype=float) * self.kt
        gains = np.asarray(command.position_gains, dtype=float)
        per_pulse = self.stall_torque / 885.0
        kp = gains[:, 0] / 128.0 * per_pulse / RAD_PER_PULSE
        kd_servo = gains[:, 2] / 16.0 * per_pulse / RAD_PER_PULSE * 1e-3
        kd = np.maximum(kd_servo, 1.4 * np.sqrt(np.maximum(kp, 0.0) * self.inertia))
        cap = np.where(mode == 5, np.abs(np.asarray(command.goal_current, dtype=float)) * self.kt, limit)
        return pos, kp, kd, cap

    def step(self, command: ActuatorCommand, dt: float) -> None:
        if dt <= 0:
            return
        n_sub = max(1, math.ceil(dt / MAX_SUBSTEP_S - 1e-9))
        h = dt / n_sub
        for _ in range(n_sub):
            tau_m = self.motor_torque(command)
            self.current = tau_m / self.kt
            drive = tau_m + self.external_torque - self.viscous * self.dq
            moving = self.dq != 0.0
            stuck = ~moving & (np.abs(drive) <= self.coulomb)
            direction = np.where(moving, np.sign(self.dq), np.sign(drive))
            ddq = np.where(stuck, 0.0, (drive - self.coulomb * direction) / self.inertia)
            dq_new = self.dq + ddq * h
            # Friction stops a joint; it never reverses it within a step.
            reversed_ = moving & (np.sign(dq_new) != np.sign(self.dq))
            dq_new[reversed_ | stuck] = 0.0
            self.q = self.q + dq_new * h
            self.dq = dq_new
            hit_low = self.q < self.lower
            hit_high = self.q > self.upper
            self.q = np.clip(self.q, self.lower, self.upper)
            self.dq[(hit_low & (self.dq < 0)) | (hit_high & (self.dq > 0))] = 0.0
            self.time += h

    def read(self) -> SensorReading:
        n = len(self.servo_ids)
        return SensorReading(
            position=self.q.copy(),
            velocity=self.dq.copy(),
            current=self.current.copy(),
            voltage=np.full(n, 12.0),
            temperature=np.full(n, 35.0),
        )

    def hardware_errors(self) -> dict[int, int]:
        return dict(self.errors)

    def set_external_torque(self, torque: np.ndarray) -> None:
        torque = np.asarray(torque, dtype=float)
        if torque.shape != (len(self.servo_ids),):
            raise ValueError(f"external torque needs {len(self.servo_ids)} values, got {torque.shape}")
        self.external_torque = torque.copy()
