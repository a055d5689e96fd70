"""Conversions between raw Dynamixel X-series register values and SI units.

Both servo models of the CRANE-X7 (XM430-W350 and XM540-W270) share these scales
(ROBOTIS e-manual; see shared/crane_x7_facts.md section 2). Position 2048 is joint zero.
"""

from __future__ import annotations

import math

import numpy as np

PULSES_PER_REV = 4096
POSITION_CENTER = 2048
RAD_PER_PULSE = 2.0 * math.pi / PULSES_PER_REV  # 1.5340e-3 rad
RPM_PER_LSB = 0.229
RADS_PER_VELOCITY_LSB = RPM_PER_LSB * 2.0 * math.pi / 60.0  # 0.0239808 rad/s
AMPERE_PER_CURRENT_LSB = 2.69e-3
VOLT_PER_LSB = 0.1
CELSIUS_PER_LSB = 1.0
SECONDS_PER_RETURN_DELAY_LSB = 2e-6
SECONDS_PER_WATCHDOG_LSB = 20e-3


def position_to_rad(raw):
    """Present/Goal Position counts -> joint angle in rad (2048 = 0 rad)."""
    return (np.asarray(raw, dtype=float) - POSITION_CENTER) * RAD_PER_PULSE


def rad_to_position(rad):
    """Joint angle in rad -> Goal Position counts (rounded to the nearest pulse)."""
    return np.rint(np.asarray(rad, dtype=float) / RAD_PER_PULSE + POSITION_CENTER).astype(np.int64)


def velocity_to_rads(raw):
    """Present Velocity LSB (0.229 rpm) -> rad/s."""
    return np.asarray(raw, dtype=float) * RADS_PER_VELOCITY_LSB


def rads_to_velocity(rads):
    return np.rint(np.asarray(rads, dtype=float) / RADS_PER_VELOCITY_LSB).astype(np.int64)


def current_to_ampere(raw):
    """Present/Goal Current LSB (2.69 mA) -> A."""
    return np.asarray(raw, dtype=float) * AMPERE_PER_CURRENT_LSB


def ampere_to_current(amp):
    """A -> Goal Current LSB, rounded to the nearest step."""
    return np.rint(np.asarray(amp, dtype=float) / AMPERE_PER_CURRENT_LSB).astype(np.int64)


def voltage_to_volt(raw):
    return np.asarray(raw, dtype=float) * VOLT_PER_LSB


def watchdog_to_seconds(raw):
    return np.asarray(raw, dtype=float) * SECONDS_PER_WATCHDOG_LSB


def seconds_to_watchdog(seconds: float) -> int:
    """Bus Watchdog register value (20 ms/LSB, 1..127) for a timeout in seconds."""
    return int(min(127, max(1, round(seconds / SECONDS_PER_WATCHDOG_LSB))))


def to_signed(value: int, size: int) -> int:
    """Interpret an unsigned little-endian register value of `size` bytes as two's complement."""
    bits = 8 * size
    value &= (1 << bits) - 1
    return value - (1 << bits) if value >= 1 << (bits - 1) else value


def to_unsigned(value: int, size: int) -> int:
    return int(value) & ((1 << (8 * size)) - 1)
