"""The small interface between the emulated servos and the physics behind them.

The servo chain owns the control tables (raw units); once per step it hands the plant what the
servos command, in SI, and reads back what the servos' sensors would measure, in SI. The chain does
the quantisation to register units; the plant may add sensor noise. Every plant (the simple
per-joint plant, the full CRANE-X7 arm plant) implements this protocol.

Optional, for speed: a plant class may define `read_lists()` -> (position, velocity, current, voltage,
temperature) lists and `step_lists(enabled, mode, goal_current, goal_position, gains, limit, dt)` beside
its `read` and `step`, giving exactly the same results without arrays in between (ArmPlant does). The
chain uses them only when the class whose `read` / `step` the plant uses defines them too, so a wrapper
or subclass that changes `read` or `step` is never bypassed. Likewise `read_arrays()` (position, velocity,
current as float arrays, voltage and temperature lists) and `step_command(cmds, position_mask, dt)` (the
commands as one (5, servos) array; returns False when it cannot take them so) for the chain's fast path
(crane_io.sim.chain_kernel), used only when the class defining `read` / `step` also defines `read_lists` /
`step_lists` and them, so that a subclass overriding any of the three is never bypassed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass
class ActuatorCommand:
    """What the servos command this step, one entry per servo in `Plant.servo_ids` order."""

    torque_enabled: np.ndarray  # (n,) bool
    operating_mode: np.ndarray  # (n,) int, control-table values (0 current, 3 position, ...)
    goal_current: np.ndarray  # (n,) A, already clamped to +-Current Limit by the servo
    goal_position: np.ndarray  # (n,) rad
    position_gains: np.ndarray  # (n, 3) raw P, I, D gains of the servo's position controller
    current_limit: np.ndarray  # (n,) A


@dataclass
class SensorReading:
    """What each servo's sensors measure, in SI, in `Plant.servo_ids` order."""

    position: np.ndarray  # (n,) rad
    velocity: np.ndarray  # (n,) rad/s
    current: np.ndarray  # (n,) A (the current the motor actually draws)
    voltage: np.ndarray | None = None  # (n,) V
    temperature: np.ndarray | None = None  # (n,) deg C


@runtime_checkable
class Plant(Protocol):
    servo_ids: tuple[int, ...]

    def step(self, command: ActuatorCommand, dt: float) -> None:
        """Advance the physics by dt seconds under a constant command."""

    def read(self) -> SensorReading:
        """The sensors' view of the present state."""

    def hardware_errors(self) -> dict[int, int]:
        """Hardware Error Status bits the plant raises per servo ID (e.g. overload); {} when healthy."""

    def set_external_torque(self, torque: np.ndarray) -> None:
        """Torque (n,) N m that the outside world (an operator's hand, a contact) applies to each
        joint from now on, in servo_ids order; the simulated operator uses it to move the leader."""
