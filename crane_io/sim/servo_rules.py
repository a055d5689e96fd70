"""Firmware rules of the emulated X-series servo (ROBOTIS e-manual, XM430-W350 / XM540-W270 control
tables and Protocol 2.0; docs/simulator-firmware.md lists each rule with its source):

- the value range each item accepts (Data Range Error 0x04 outside it: `in_range`);
- the frame of the position, velocity and current items: Drive Mode (10) bit 0 reverses the direction of
  the Present and Goal items, and Present Position = actual position + Homing Offset (20), the goals in
  the same frame (the offset's sign is not reversed with the direction; in Position Control Mode an
  offset outside -1024..1024 is ignored);
- the goal items bounded by a limit item (Goal PWM, Goal Current, Goal Velocity, Profile Velocity,
  Profile Acceleration, Goal Position in Position Control Mode) refuse a value beyond it with Data Limit
  Error (0x06) and keep their old value; Goal Position in the extended position modes has a fixed range
  (Data Range Error 0x04 outside it).

The compiled kernels (crane_io.sim.chain_kernel, lockstep_kernel) apply the same frame with the same
arithmetic; tests/test_chain_fast.py pins them to these functions.
"""

from __future__ import annotations

from crane_io.dynamixel.control_table import (
    MODE_CURRENT_BASED_POSITION,
    MODE_EXTENDED_POSITION,
    MODE_POSITION,
    X_SERIES,
)
from crane_io.sim import protocol as p
from crane_io.sim.servo_indirect import ADDRESS_ITEMS, TARGET_RANGE

DRIVE_MODE_AT = X_SERIES["drive_mode"].address
HOMING_OFFSET_AT = X_SERIES["homing_offset"].address
DRIVE_REVERSE = 0x01  # Drive Mode bit 0: Normal/Reverse Mode
DRIVE_TIME_PROFILE = 0x04  # Drive Mode bit 2: time-based profile (Profile Velocity in ms)
HOMING_RANGE = 1_044_479  # Homing Offset: -1,044,479 .. 1,044,479 (-255 .. 255 rev)
POSITION_MODE_HOMING = 1024  # Position Control Mode ignores an offset outside -1024 .. 1024
EXTENDED_GOAL_RANGE = 1_048_575  # Goal Position in the extended position modes (-256 .. 256 rev)
PROFILE_RANGE = 32767  # Profile Velocity and Profile Acceleration: 0 .. 32767
# goal item -> the limit item that bounds it (+- the limit for the signed ones)
VALID_MODES = (0, 1, 3, 4, 5, 16)  # Operating Mode values of the X series
# value ranges the servo accepts (e-manual); Current Limit's depends on the model, gains are 0..16383
_RANGES = {
    "id": (0, 252),
    "baud_rate": (0, 7),
    "return_delay_time": (0, 254),
    "torque_enable": (0, 1),
    "status_return_level": (0, 2),
    "bus_watchdog": (0, 127),
    "protocol_type": (1, 2),
    "secondary_id": (0, 255),
    "led": (0, 1),
    "max_voltage_limit": (95, 160),
    "min_voltage_limit": (95, 160),
    "acceleration_limit": (0, 32767),
    "velocity_limit": (0, 1023),
    "temperature_limit": (0, 100),
    "pwm_limit": (0, 885),
    "moving_threshold": (0, 1023),
    "max_position_limit": (0, 4095),
    "min_position_limit": (0, 4095),
    "homing_offset": (-HOMING_RANGE, HOMING_RANGE),
    **{name: TARGET_RANGE for name in ADDRESS_ITEMS},  # Indirect Address (crane_io.sim.servo_indirect)
}
_GAIN_ITEMS = ("velocity_i_gain", "velocity_p_gain", "position_d_gain", "position_i_gain", "position_p_gain")
GOAL_LIMITS = {
    "goal_pwm": "pwm_limit",
    "goal_current": "current_limit",
    "goal_velocity": "velocity_limit",
    "profile_velocity": "velocity_limit",
    "profile_acceleration": "acceleration_limit",
}


def direction(drive_mode: int) -> int:
    """+1, or -1 when Drive Mode's reverse bit is set."""
    return -1 if drive_mode & DRIVE_REVERSE else 1


def effective_homing(mode: int, homing: int) -> int:
    """The Homing Offset the firmware applies in operating mode `mode`."""
    if mode == MODE_POSITION and not -POSITION_MODE_HOMING <= homing <= POSITION_MODE_HOMING:
        return 0
    return homing


def goal_error(servo, name: str, value: int) -> int:
    """The error number of writing `value` to goal item `name` of `servo` (an EmulatedServo) as its
    limits stand (0: allowed; every other item: 0)."""
    limit_item = GOAL_LIMITS.get(name)
    if limit_item is not None:
        if name.startswith("profile_"):
            if not 0 <= value <= PROFILE_RANGE:
                return p.ERR_DATA_RANGE
            if servo.read_register("drive_mode") & DRIVE_TIME_PROFILE:
                return p.ERR_NONE  # a time span in ms, not bounded by the velocity or acceleration limit
            return p.ERR_NONE if value <= servo.read_register(limit_item) else p.ERR_DATA_LIMIT
        limit = servo.read_register(limit_item)
        return p.ERR_NONE if -limit <= value <= limit else p.ERR_DATA_LIMIT
    if name == "goal_position":
        mode = servo.read_register("operating_mode")
        if mode == MODE_POSITION:
            lo, hi = servo.read_register("min_position_limit"), servo.read_register("max_position_limit")
            return p.ERR_NONE if lo <= value <= hi else p.ERR_DATA_LIMIT
        if mode in (MODE_EXTENDED_POSITION, MODE_CURRENT_BASED_POSITION):
            return p.ERR_NONE if -EXTENDED_GOAL_RANGE <= value <= EXTENDED_GOAL_RANGE else p.ERR_DATA_RANGE
    return p.ERR_NONE


def in_range(name: str, value: int, current_limit_max: int) -> bool:
    """`value` is within the range item `name` accepts (Data Range Error otherwise); `current_limit_max`:
    the model's largest Current Limit."""
    if name == "operating_mode":
        return value in VALID_MODES
    if name in _GAIN_ITEMS:
        return 0 <= value <= 16383
    if name == "current_limit":
        return 0 <= value <= current_limit_max
    lo, hi = _RANGES.get(name, (-(2**31), 2**32))
    return lo <= value <= hi
