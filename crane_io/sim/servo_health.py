"""The simulated servos' health: winding temperature, the overload timer and the supply, as Hardware Error
Status bits (crane_io.sim.arm_plant steps it; docs/simulator-faults.md explains the models).

The firmware's rules (ROBOTIS e-manual, XM430-W350 / XM540-W270 control table, `control_table_shutdown.md`
"Shutdown(63)": bit 0 Input Voltage Error "input voltage exceeds the configured operating voltage", bit 2
Overheating Error "internal temperature exceeds the configured operating temperature", bit 5 Overload Error
"persistent load that exceeds maximum output"; Temperature Limit(31), Max/Min Voltage Limit(32, 34)):

- Input Voltage (bit 0) while Present Input Voltage (0.1 V) lies outside Min..Max Voltage Limit.
- Overheating (bit 2) while Present Temperature (1 C) exceeds Temperature Limit.
- Overload (bit 5) once the servo has driven at its maximum output without its output moving for
  `OverloadConfig.time_s`: torque on, |current| >= `current_fraction` x the motor's stall current at the
  present input voltage (V / R, the winding resistance of MOTOR_THERMAL) and |velocity| <=
  `still_velocity` (default the Moving Threshold's default, 10 x 0.229 rpm). The e-manual gives no time
  and no threshold; a servo stalled under a Current Limit well below its stall current is not at its
  maximum output and raises nothing (as ROBOTIS forum thread 8128 reports for a stall at 600 mA).

The bits are the present conditions, per servo; the servo latches them in Hardware Error Status and acts on
its Shutdown mask (crane_io.sim.servo.raise_hardware_error): torque off, alert bit, cleared only by a
reboot, after which a condition still present raises its bit again.

Temperature: one first-order node per motor, heated by the winding's I^2 R, cooled towards the ambient
through a thermal resistance:  C dT/dt = I^2 R - (T - T_amb) / R_th,  tau = R_th C,  integrated exactly
for a current held over the step. Supply: every servo sees V_supply - R_source x sum |I| (one supply line).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from crane_io.dynamixel.control_table import X_SERIES

INPUT_VOLTAGE_BIT, OVERHEATING_BIT, OVERLOAD_BIT = 0x01, 0x04, 0x20
NOMINAL_VOLTAGE = 12.0  # V: Present Input Voltage of a plant without a supply model
IDLE_TEMPERATURE_C = 35.0  # C: Present Temperature of a plant without a thermal model
_TEMP_LIMIT_AT = X_SERIES["temperature_limit"].address
_MAX_V_AT, _MIN_V_AT = X_SERIES["max_voltage_limit"].address, X_SERIES["min_voltage_limit"].address
_DEFAULT_LIMITS = (X_SERIES["temperature_limit"].default, X_SERIES["min_voltage_limit"].default,
                   X_SERIES["max_voltage_limit"].default)  # 1 C, 0.1 V, 0.1 V


@dataclass(frozen=True)
class MotorThermal:
    """One servo model's heating: winding resistance (ohm), thermal resistance winding to ambient (K/W) and
    time constant (s)."""

    resistance_ohm: float
    thermal_resistance: float
    time_constant_s: float


# Winding resistance: the 12 V stall point (crane_x7_facts.md section 2, e-manual: XM430-W350 2.3 A,
# XM540-W270 4.4 A at 12.0 V) -> R = 12 V / I_stall. Thermal resistance and time constant: estimates for an
# 82 g / 165 g servo (heat capacity ~0.45 J/(g K) of its mass: C ~ 37 / 75 J/K): a continuous 1 A warms an
# XM430 by ~40 K, a stall passes 80 C within about a minute, as a stalled servo does.
MOTOR_THERMAL = {
    "XM430-W350": MotorThermal(resistance_ohm=12.0 / 2.3, thermal_resistance=8.0, time_constant_s=300.0),
    "XM540-W270": MotorThermal(resistance_ohm=12.0 / 4.4, thermal_resistance=6.0, time_constant_s=450.0),
}


@dataclass
class OverloadConfig:
    enabled: bool = False
    time_s: float = 1.0  # s at the maximum output without moving before the overload bit is set
    current_fraction: float = 0.95  # |current| >= this x the stall current (V / R) is the maximum output
    still_velocity: float = 10 * 0.229 * 2 * math.pi / 60  # rad/s: slower counts as "does not move"


@dataclass
class ThermalConfig:
    enabled: bool = False
    ambient_c: float = 25.0  # C: the air around the servos (and their temperature at the start)
    time_constant_s: float = 0.0  # s, every motor's (0: each model's own, MOTOR_THERMAL)
    thermal_resistance: float = 0.0  # K/W, every motor's (0: each model's own)


@dataclass
class SupplyConfig:
    enabled: bool = False
    voltage: float = NOMINAL_VOLTAGE  # V at the supply
    resistance_ohm: float = 0.0  # ohm of the supply and its cable: the voltage sags by this x sum |I|


def check_configs(overload: OverloadConfig, thermal: ThermalConfig, supply: SupplyConfig, where: str) -> str:
    """'' when the values are usable, else one sentence naming the first that is not."""
    checks = (
        (overload.time_s > 0, "[overload] time_s must be positive"),
        (0 < overload.current_fraction <= 1, "[overload] current_fraction must be in (0, 1]"),
        (overload.still_velocity >= 0, "[overload] still_velocity must be zero or more"),
        (0 <= thermal.ambient_c <= 100, "[thermal] ambient_c must be between 0 and 100 C"),
        (thermal.time_constant_s >= 0, "[thermal] time_constant_s must be zero or more"),
        (thermal.thermal_resistance >= 0, "[thermal] thermal_resistance must be zero or more"),
        (0 < supply.voltage <= 30, "[supply] voltage must be positive and at most 30 V"),
        (supply.resistance_ohm >= 0, "[supply] resistance_ohm must be zero or more"),
    )
    for ok, message in checks:
        if not ok:
            return f"{where}: {message}"
    return ""


class ControlTableLimits:
    """Each servo's Temperature Limit and Min/Max Voltage Limit, read from the simulated chain's control
    tables (`memories`: (servos, bytes), servo order) in their raw units (1 C, 0.1 V)."""

    def __init__(self, memories: np.ndarray):
        self.memories = memories

    def raw(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        m = self.memories
        temperature = m[:, _TEMP_LIMIT_AT].astype(np.int64)
        v_max = m[:, _MAX_V_AT].astype(np.int64) | m[:, _MAX_V_AT + 1].astype(np.int64) << 8
        v_min = m[:, _MIN_V_AT].astype(np.int64) | m[:, _MIN_V_AT + 1].astype(np.int64) << 8
        return temperature, v_min, v_max


class DefaultLimits:
    """The control table's default limits (80 C, 9.5 V, 16.0 V) for a plant outside a simulated chain."""

    def __init__(self, n: int):
        self._raw = tuple(np.full(n, v, dtype=np.int64) for v in _DEFAULT_LIMITS)

    def raw(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self._raw


class ServoHealth:
    """The health of `len(models)` servos (servo order; `models`: their model names, MOTOR_THERMAL keys)."""

    def __init__(self, models, overload: OverloadConfig, thermal: ThermalConfig, supply: SupplyConfig):
        n = len(models)
        self.overload, self.thermal, self.supply = overload, thermal, supply
        motors = [MOTOR_THERMAL[m] for m in models]
        self.resistance = np.array([m.resistance_ohm for m in motors])
        self.r_th = np.array([thermal.thermal_resistance or m.thermal_resistance for m in motors])
        self.tau = np.array([thermal.time_constant_s or m.time_constant_s for m in motors])
        start = thermal.ambient_c if thermal.enabled else IDLE_TEMPERATURE_C
        self.temperature = np.full(n, float(start))
        self.voltage = np.full(n, float(supply.voltage if supply.enabled else NOMINAL_VOLTAGE))
        self.stalled_s = np.zeros(n)  # how long each servo has been at its maximum output, not moving
        self.limits: ControlTableLimits | DefaultLimits = DefaultLimits(n)

    def step(self, enabled, current, velocity, dt: float) -> None:
        """Advance by dt with each servo's torque on/off, current (A) and velocity (rad/s) (sequences in
        servo order) held over the step."""
        if not dt > 0:
            return
        cur = np.asarray(current, dtype=float)
        if self.thermal.enabled:
            t_ss = self.thermal.ambient_c + self.r_th * cur * cur * self.resistance
            self.temperature = t_ss + (self.temperature - t_ss) * np.exp(-dt / self.tau)
        if self.supply.enabled:
            self.voltage[:] = self.supply.voltage - self.supply.resistance_ohm * float(np.abs(cur).sum())
        if self.overload.enabled:
            o = self.overload
            at_max = (np.asarray(enabled, dtype=bool)
                      & (np.abs(cur) >= o.current_fraction * self.voltage / self.resistance)
                      & (np.abs(np.asarray(velocity, dtype=float)) <= o.still_velocity))
            self.stalled_s = np.where(at_max, self.stalled_s + dt, 0.0)

    def readings(self) -> tuple[list, list]:
        """(voltages V, temperatures C) lists in servo order: what Present Input Voltage and Present
        Temperature read."""
        return self.voltage.tolist(), self.temperature.tolist()

    def error_bits(self) -> np.ndarray:
        """Per servo (servo order) the Hardware Error Status bits whose condition holds now."""
        temp_limit, v_min, v_max = self.limits.raw()
        bits = np.zeros(len(self.temperature), dtype=np.int64)
        if self.supply.enabled:
            volt = np.round(self.voltage * 10)
            bits |= np.where((volt < v_min) | (volt > v_max), INPUT_VOLTAGE_BIT, 0)
        if self.thermal.enabled:
            bits |= np.where(np.round(self.temperature) > temp_limit, OVERHEATING_BIT, 0)
        if self.overload.enabled:
            bits |= np.where(self.stalled_s >= self.overload.time_s, OVERLOAD_BIT, 0)
        return bits

    def reset_overload(self) -> None:
        self.stalled_s[:] = 0.0


def build(models, overload: OverloadConfig, thermal: ThermalConfig,
          supply: SupplyConfig) -> ServoHealth | None:
    """The health model of servos of `models`, or None when none of its parts is enabled (the plant then
    reads a constant NOMINAL_VOLTAGE and IDLE_TEMPERATURE_C and raises no bits)."""
    if not (overload.enabled or thermal.enabled or supply.enabled):
        return None
    return ServoHealth(models, overload, thermal, supply)
