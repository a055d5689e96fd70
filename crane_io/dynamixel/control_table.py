"""The Dynamixel X-series control table (Protocol 2.0) as plain data, keyed by servo model.

XM430-W350 and XM540-W270 share one layout; they differ in model number and a few defaults and
limits. Values from the ROBOTIS e-manual as gathered in shared/crane_x7_facts.md section 2.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Register:
    name: str
    address: int
    size: int  # bytes
    access: str  # "R" or "RW"
    eeprom: bool  # EEPROM area: writable only with torque off
    signed: bool = False
    unit: str = ""  # what one LSB means, human-readable
    default: int | None = None


EEPROM_END = 64  # addresses below this are the EEPROM area
CONTROL_TABLE_SIZE = 662  # the X-series control table ends with Indirect Data 56 at address 661


def _r(name, address, size, access, signed=False, unit="", default=None):
    return Register(name, address, size, access, address < EEPROM_END, signed, unit, default)


_COMMON = [
    _r("model_number", 0, 2, "R"),
    _r("model_information", 2, 4, "R"),
    _r("firmware_version", 6, 1, "R"),
    _r("id", 7, 1, "RW", default=1),
    _r("baud_rate", 8, 1, "RW", default=1),
    _r("return_delay_time", 9, 1, "RW", unit="2 us", default=250),
    _r("drive_mode", 10, 1, "RW", default=0),
    _r("operating_mode", 11, 1, "RW", default=3),
    _r("secondary_id", 12, 1, "RW", default=255),
    _r("protocol_type", 13, 1, "RW", default=2),
    _r("homing_offset", 20, 4, "RW", signed=True, unit="pulse", default=0),
    _r("moving_threshold", 24, 4, "RW", unit="0.229 rpm", default=10),
    _r("temperature_limit", 31, 1, "RW", unit="1 C", default=80),
    _r("max_voltage_limit", 32, 2, "RW", unit="0.1 V", default=160),
    _r("min_voltage_limit", 34, 2, "RW", unit="0.1 V", default=95),
    _r("pwm_limit", 36, 2, "RW", unit="0.113 %", default=885),
    _r("current_limit", 38, 2, "RW", unit="2.69 mA"),
    _r("acceleration_limit", 40, 4, "RW", default=32767),
    _r("velocity_limit", 44, 4, "RW", unit="0.229 rpm"),
    _r("max_position_limit", 48, 4, "RW", unit="pulse", default=4095),
    _r("min_position_limit", 52, 4, "RW", unit="pulse", default=0),
    _r("shutdown", 63, 1, "RW", default=52),
    _r("torque_enable", 64, 1, "RW", default=0),
    _r("led", 65, 1, "RW", default=0),
    _r("status_return_level", 68, 1, "RW", default=2),
    _r("registered_instruction", 69, 1, "R", default=0),
    _r("hardware_error_status", 70, 1, "R", default=0),
    _r("velocity_i_gain", 76, 2, "RW", default=1920),
    _r("velocity_p_gain", 78, 2, "RW", default=100),
    _r("position_d_gain", 80, 2, "RW", default=0),
    _r("position_i_gain", 82, 2, "RW", default=0),
    _r("position_p_gain", 84, 2, "RW", default=800),
    _r("feedforward_2nd_gain", 88, 2, "RW", default=0),
    _r("feedforward_1st_gain", 90, 2, "RW", default=0),
    _r("bus_watchdog", 98, 1, "RW", signed=True, unit="20 ms", default=0),
    _r("goal_pwm", 100, 2, "RW", signed=True, unit="0.113 %"),
    _r("goal_current", 102, 2, "RW", signed=True, unit="2.69 mA"),
    _r("goal_velocity", 104, 4, "RW", signed=True, unit="0.229 rpm"),
    _r("profile_acceleration", 108, 4, "RW", default=0),
    _r("profile_velocity", 112, 4, "RW", default=0),
    _r("goal_position", 116, 4, "RW", signed=True, unit="pulse"),
    _r("realtime_tick", 120, 2, "R", unit="1 ms"),
    _r("moving", 122, 1, "R"),
    _r("moving_status", 123, 1, "R"),
    _r("present_pwm", 124, 2, "R", signed=True),
    _r("present_current", 126, 2, "R", signed=True, unit="2.69 mA"),
    _r("present_velocity", 128, 4, "R", signed=True, unit="0.229 rpm"),
    _r("present_position", 132, 4, "R", signed=True, unit="pulse"),
    _r("velocity_trajectory", 136, 4, "R", signed=True),
    _r("position_trajectory", 140, 4, "R", signed=True),
    _r("present_input_voltage", 144, 2, "R", unit="0.1 V"),
    _r("present_temperature", 146, 1, "R", unit="1 C"),
]
# Indirect Address k (2 bytes, 64 .. 661: the address Indirect Data k stands for; its default is Indirect Data
# k itself) and Indirect Data k (1 byte): k = 1 .. 28 at 168 / 224, k = 29 .. 56 at 578 / 634
# (first k, address of Indirect Address k, address of Indirect Data k) of each set
INDIRECT_SETS = ((1, 168, 224), (29, 578, 634))
INDIRECT_PER_SET = 28
for _first, _address_at, _data_at in INDIRECT_SETS:
    for _j in range(INDIRECT_PER_SET):
        _COMMON.append(_r(f"indirect_address_{_first + _j}", _address_at + 2 * _j, 2, "RW",
                          default=_data_at + _j))
    for _j in range(INDIRECT_PER_SET):
        _COMMON.append(_r(f"indirect_data_{_first + _j}", _data_at + _j, 1, "RW", default=0))


@dataclass(frozen=True)
class ServoModel:
    name: str
    model_number: int
    gear_ratio: float
    stall_torque_per_amp: float  # N m / A at 12 V (datasheet stall point)
    current_limit_default: int  # raw, 2.69 mA/LSB
    current_limit_max: int
    velocity_limit_default: int  # raw, 0.229 rpm/LSB
    registers: dict[str, Register] = field(default_factory=dict)

    def register(self, name: str) -> Register:
        try:
            return self.registers[name]
        except KeyError:
            raise KeyError(f"{self.name} has no control-table item named {name!r}") from None

    def defaults(self) -> dict[str, int]:
        """Factory values of every register that has one (for a simulated servo or a factory reset)."""
        values = {r.name: r.default for r in self.registers.values() if r.default is not None}
        values["model_number"] = self.model_number
        values["current_limit"] = self.current_limit_default
        values["goal_current"] = self.current_limit_default
        values["velocity_limit"] = self.velocity_limit_default
        values["goal_pwm"] = 885
        return values


def _model(name, number, gear, kt, cur_default, vel_default) -> ServoModel:
    return ServoModel(name, number, gear, kt, cur_default, cur_default, vel_default,
                      {r.name: r for r in _COMMON})


XM430_W350 = _model("XM430-W350", 1020, 353.5, 1.783, 1193, 350)
XM540_W270 = _model("XM540-W270", 1120, 272.5, 2.409, 2047, 128)

# The layout both models share: one sync read or sync write reaches every servo of the arm only because
# the address is the same in each. Code that addresses the whole chain at once takes addresses from here.
X_SERIES: dict[str, Register] = {r.name: r for r in _COMMON}


def span(first: str, last: str) -> tuple[int, int]:
    """(address, size) of the X-series items from `first` through `last`: what one read of them all
    covers, gaps included. `span("present_current", "present_position")` is (126, 10)."""
    a, b = X_SERIES[first], X_SERIES[last]
    if b.address < a.address:
        raise ValueError(f"{last!r} comes before {first!r} in the control table")
    return a.address, b.address + b.size - a.address


MODELS: dict[str, ServoModel] = {m.name: m for m in (XM430_W350, XM540_W270)}
MODELS_BY_NUMBER: dict[int, ServoModel] = {m.model_number: m for m in MODELS.values()}

# Operating modes (address 11)
MODE_CURRENT = 0
MODE_VELOCITY = 1
MODE_POSITION = 3
MODE_EXTENDED_POSITION = 4
MODE_CURRENT_BASED_POSITION = 5
MODE_PWM = 16

# The contiguous block read every control cycle: Present Current, Velocity, Position (126, 10 bytes).
PRESENT_BLOCK_ADDRESS, PRESENT_BLOCK_SIZE = span("present_current", "present_position")

# Hardware Error Status (address 70) bits
HARDWARE_ERROR_BITS = {
    0: "input voltage error",
    2: "overheating",
    3: "motor encoder error",
    4: "electrical shock",
    5: "overload",
}


def model_by_number(number: int) -> ServoModel | None:
    return MODELS_BY_NUMBER.get(number)
