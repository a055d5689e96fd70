"""One emulated Dynamixel X-series servo: its control table and what writing to it does.

The memory is the Protocol 2.0 control table of the servo's model (crane_io.control_table), in raw
little-endian bytes. Rules follow the ROBOTIS e-manual (see shared/crane_x7_facts.md section 2):

- Read-only items (R) cannot be written (Access Error 0x07); neither can the EEPROM area (address
  < 64) while Torque Enable is 1. A write that covers only part of an item is a Data Length Error
  (0x05); a value outside an item's range is a Data Range Error (0x04). A rejected write changes
  nothing.
- Goal Current is clamped to +-Current Limit; Goal Position to the position limits in Position mode.
- Changing Operating Mode resets the gains, sets Profile Velocity/Acceleration to 0, Goal PWM to PWM
  Limit and Goal Current to Current Limit.
- Torque Enable 1 sets Goal Position to Present Position (the servo holds where it is) and is refused
  while a shutdown hardware error is latched (until reboot).
- Hardware Error Status bits that are in the Shutdown mask turn torque off; every status packet then
  carries the alert bit 0x80.
- Bus Watchdog (address 98, 20 ms/LSB): with torque on and a non-zero value, no instruction for that
  long makes the servo stop (the plant sees it as torque off), the item reads -1 and the goal items
  become read-only until 0 is written to it.

Time comes from the chain (`now`, seconds of simulated or wall time); this class never sleeps.
"""

from __future__ import annotations

import math

from ..control_table import (
    MODE_CURRENT_BASED_POSITION,
    MODE_EXTENDED_POSITION,
    MODE_POSITION,
    MODELS,
    XM430_W350,
    Register,
    ServoModel,
)
from ..units import (
    AMPERE_PER_CURRENT_LSB,
    POSITION_CENTER,
    RAD_PER_PULSE,
    RADS_PER_VELOCITY_LSB,
    SECONDS_PER_WATCHDOG_LSB,
    position_to_rad,
    to_signed,
    to_unsigned,
)
from . import protocol as p

MEMORY_SIZE = 662  # the X-series control table ends with Indirect Data 56 at address 661
EEPROM_END = 64
BAUD_CODES = {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000, 6: 4_000_000,
              7: 4_500_000}
VALID_MODES = (0, 1, 3, 4, 5, 16)
POSITION_MODES = (MODE_POSITION, MODE_EXTENDED_POSITION, MODE_CURRENT_BASED_POSITION)
GOAL_ITEMS = ("goal_pwm", "goal_current", "goal_velocity", "goal_position", "profile_acceleration",
              "profile_velocity")
MODE_RESET_ITEMS = ("velocity_i_gain", "velocity_p_gain", "position_d_gain", "position_i_gain",
                    "position_p_gain", "feedforward_2nd_gain", "feedforward_1st_gain",
                    "profile_acceleration", "profile_velocity")


class EmulatedServo:
    """A simulated X-series servo. `registers` maps item names to the model's Register data."""

    def __init__(
        self,
        servo_id: int,
        model: ServoModel | str = XM430_W350,
        *,
        baud_code: int = 5,
        return_delay_time: int | None = None,
        firmware_version: int = 52,
        supports_fast_sync_read: bool = True,
        input_voltage: float = 12.0,
        temperature: float = 35.0,
    ):
        self.model = MODELS[model] if isinstance(model, str) else model
        self.registers: dict[str, Register] = dict(self.model.registers)
        self._at: dict[int, Register] = {r.address: r for r in self.registers.values()}
        self._owner: list[Register | None] = [None] * MEMORY_SIZE
        for r in self.registers.values():
            for a in range(r.address, r.address + r.size):
                self._owner[a] = r
        self.firmware_version = firmware_version
        self.supports_fast_sync_read = supports_fast_sync_read
        self.memory = bytearray(MEMORY_SIZE)
        self.on_bus = True  # False: the servo has vanished from the bus (no packets in or out)
        self.registered: tuple[int, bytes] | None = None  # a Reg Write waiting for Action
        self.watchdog_expired = False
        self.last_contact = 0.0
        self.reboots = 0
        self._input_voltage = input_voltage
        self._temperature = temperature
        self._load_defaults(keep=())
        self.write_register("id", servo_id)
        self.write_register("baud_rate", baud_code)
        if return_delay_time is not None:
            self.write_register("return_delay_time", return_delay_time)
        self._set_present(0.0, 0.0, 0.0)
        self.write_register("goal_position", self.read_register("present_position"))

    # ---- raw register access (no access rules; for the chain and for tests) ---------------------
    @property
    def id(self) -> int:
        return self.memory[7]

    def read_register(self, name: str) -> int:
        r = self._register(name)
        value = int.from_bytes(self.memory[r.address:r.address + r.size], "little")
        if name == "bus_watchdog" and self.watchdog_expired:
            return -1
        return to_signed(value, r.size) if r.signed else value

    def write_register(self, name: str, value: int) -> None:
        """Set an item directly, bypassing access rules and side effects (tests, the chain)."""
        r = self._register(name)
        self.memory[r.address:r.address + r.size] = to_unsigned(int(value), r.size).to_bytes(r.size, "little")

    def _register(self, name: str) -> Register:
        try:
            return self.registers[name]
        except KeyError:
            raise KeyError(f"{self.model.name} has no control-table item named {name!r}") from None

    def _load_defaults(self, keep: tuple[str, ...]) -> None:
        kept = {name: self.read_register(name) for name in keep}
        self.memory[:] = bytes(MEMORY_SIZE)
        for name, value in self.model.defaults().items():
            self.write_register(name, value)
        self.write_register("firmware_version", self.firmware_version)
        self.write_register("present_input_voltage", round(self._input_voltage * 10))
        self.write_register("present_temperature", round(self._temperature))
        for name, value in kept.items():
            self.write_register(name, value)

    # ---- state the chain and the plant need ---------------------------------------------------
    @property
    def baudrate(self) -> int:
        return BAUD_CODES.get(self.read_register("baud_rate"), 0)

    @property
    def return_delay_s(self) -> float:
        return self.read_register("return_delay_time") * 2e-6

    @property
    def torque_enabled(self) -> bool:
        return self.read_register("torque_enable") == 1

    @property
    def driving(self) -> bool:
        """Torque on and not stopped by the bus watchdog: what the plant sees as torque enabled."""
        return self.torque_enabled and not self.watchdog_expired

    @property
    def alert(self) -> bool:
        return self.read_register("hardware_error_status") != 0

    def status_error(self, error_number: int = p.ERR_NONE) -> int:
        """The error byte of a status packet: the error number plus the alert bit when needed."""
        return error_number | (p.ERR_ALERT if self.alert else 0)

    def command(self) -> tuple[bool, int, float, float, tuple[int, int, int], float]:
        """(driving, operating mode, goal current A, goal position rad, (P, I, D) gains, current limit A)."""
        return (
            self.driving,
            self.read_register("operating_mode"),
            self.read_register("goal_current") * AMPERE_PER_CURRENT_LSB,
            float(position_to_rad(self.read_register("goal_position"))),
            (self.read_register("position_p_gain"), self.read_register("position_i_gain"),
             self.read_register("position_d_gain")),
            self.read_register("current_limit") * AMPERE_PER_CURRENT_LSB,
        )

    def set_sensors(self, position: float, velocity: float, current: float, now: float,
                    voltage: float | None = None, temperature: float | None = None) -> None:
        """Quantise what the plant measured into the Present items; update Moving and Realtime Tick."""
        self._set_present(position, velocity, current)
        if voltage is not None:
            self.write_register("present_input_voltage", max(0, round(voltage * 10)))
        if temperature is not None:
            self.write_register("present_temperature", max(0, round(temperature)))
        moving = abs(self.read_register("present_velocity")) > self.read_register("moving_threshold")
        self.write_register("moving", int(moving))
        self.write_register("realtime_tick", int(now * 1000) % 32768)

    def _set_present(self, position: float, velocity: float, current: float) -> None:
        if not all(math.isfinite(v) for v in (position, velocity, current)):
            return  # a plant that blew up leaves the last finite reading in place
        # same rounding as crane_io.units (rad_to_position etc.), in scalar arithmetic for speed
        pos = round(position / RAD_PER_PULSE) + POSITION_CENTER
        self.write_register("present_position", max(-(2**31), min(2**31 - 1, pos)))
        vel = round(velocity / RADS_PER_VELOCITY_LSB)
        self.write_register("present_velocity", max(-(2**31), min(2**31 - 1, vel)))
        cur = round(current / AMPERE_PER_CURRENT_LSB)
        self.write_register("present_current", max(-32768, min(32767, cur)))

    # ---- faults --------------------------------------------------------------------------------
    def set_hardware_error(self, bits: int) -> None:
        """Set Hardware Error Status; bits in the Shutdown mask turn torque off (latched to reboot)."""
        self.write_register("hardware_error_status", bits & 0xFF)
        if bits & self.read_register("shutdown"):
            self.write_register("torque_enable", 0)

    def raise_hardware_error(self, bits: int) -> None:
        """Add bits (from the plant: overload, overheating, ...) to Hardware Error Status."""
        if bits & ~self.read_register("hardware_error_status") & 0xFF:
            self.set_hardware_error(self.read_register("hardware_error_status") | bits)

    @property
    def shutdown_latched(self) -> bool:
        return bool(self.read_register("hardware_error_status") & self.read_register("shutdown"))

    # ---- bus watchdog ------------------------------------------------------------------------------
    def contact(self, now: float) -> None:
        """An instruction for this servo arrived at time `now`."""
        self.last_contact = now

    def check_watchdog(self, now: float) -> None:
        if self.watchdog_expired or not self.torque_enabled:
            return
        raw = self.read_register("bus_watchdog")
        if raw > 0 and now - self.last_contact > raw * SECONDS_PER_WATCHDOG_LSB + 1e-9:
            self.watchdog_expired = True

    # ---- instruction semantics -----------------------------------------------------------------
    def read(self, address: int, length: int) -> tuple[int, bytes]:
        """(error number, data) of a Read; an impossible range answers Access Error with zeros."""
        if length < 0 or address < 0 or address + length > MEMORY_SIZE:
            return p.ERR_ACCESS, bytes(max(0, min(length, p.MAX_LENGTH)))
        data = bytearray(self.memory[address:address + length])
        wd = self.registers["bus_watchdog"].address
        if self.watchdog_expired and address <= wd < address + length:
            data[wd - address] = 0xFF
        return p.ERR_NONE, bytes(data)

    def check_write(self, address: int, data: bytes) -> int:
        """The error number a Write of `data` at `address` would get (0 when it is allowed)."""
        end = address + len(data)
        if not data or address < 0 or end > MEMORY_SIZE:
            return p.ERR_ACCESS
        touched = []
        for r in {self._owner[a] for a in range(address, end)} - {None}:
            if r.address < address or r.address + r.size > end:
                return p.ERR_DATA_LENGTH
            touched.append(r)
        if not touched:
            return p.ERR_ACCESS
        torque = self.torque_enabled
        for r in touched:
            if r.access != "RW":
                return p.ERR_ACCESS
            if r.eeprom and torque:
                return p.ERR_ACCESS
            if self.watchdog_expired and r.name in GOAL_ITEMS:
                return p.ERR_ACCESS
            raw = int.from_bytes(data[r.address - address:r.address - address + r.size], "little")
            value = to_signed(raw, r.size) if r.signed else raw
            if not self._in_range(r.name, value):
                return p.ERR_DATA_RANGE
        return p.ERR_NONE

    def _in_range(self, name: str, value: int) -> bool:
        ranges = {
            "id": (0, 252),
            "baud_rate": (0, 7),
            "return_delay_time": (0, 254),
            "current_limit": (0, self.model.current_limit_max),
            "torque_enable": (0, 1),
            "status_return_level": (0, 2),
            "bus_watchdog": (0, 127),
            "protocol_type": (1, 2),
            "temperature_limit": (0, 100),
            "pwm_limit": (0, 885),
            "moving_threshold": (0, 1023),
            "max_position_limit": (0, 4095),
            "min_position_limit": (0, 4095),
        }
        if name == "operating_mode":
            return value in VALID_MODES
        if name in ("velocity_i_gain", "velocity_p_gain", "position_d_gain", "position_i_gain",
                    "position_p_gain"):
            return 0 <= value <= 16383
        lo, hi = ranges.get(name, (-(2**31), 2**32))
        return lo <= value <= hi

    def write(self, address: int, data: bytes, now: float = 0.0) -> int:
        """Apply a Write with the servo's rules; returns the error number (0 = written)."""
        error = self.check_write(address, data)
        if error:
            return error
        end = address + len(data)
        touched = sorted({self._owner[a] for a in range(address, end)} - {None}, key=lambda r: r.address)
        for r in touched:
            raw = int.from_bytes(data[r.address - address:r.address - address + r.size], "little")
            value = to_signed(raw, r.size) if r.signed else raw
            self._apply(r.name, value, now)
        return p.ERR_NONE

    def _apply(self, name: str, value: int, now: float) -> None:
        if name == "operating_mode":
            if value != self.read_register("operating_mode"):
                self.write_register("operating_mode", value)
                defaults = self.model.defaults()
                for item in MODE_RESET_ITEMS:
                    self.write_register(item, defaults.get(item, 0))
                self.write_register("goal_pwm", self.read_register("pwm_limit"))
                self.write_register("goal_current", self.read_register("current_limit"))
            return
        if name == "torque_enable":
            if value == 1 and self.shutdown_latched:
                return  # refused until reboot; the status packet carries the alert bit
            if value == 1 and not self.torque_enabled:
                self.write_register("goal_position", self.read_register("present_position"))
                self.last_contact = now
            self.write_register("torque_enable", value)
            return
        if name == "bus_watchdog":
            self.write_register("bus_watchdog", value)
            if value == 0:
                self.watchdog_expired = False
            self.last_contact = now
            return
        if name == "goal_current":
            limit = self.read_register("current_limit")
            value = max(-limit, min(limit, value))
        elif name == "goal_position" and self.read_register("operating_mode") == MODE_POSITION:
            value = max(self.read_register("min_position_limit"),
                        min(self.read_register("max_position_limit"), value))
        elif name == "current_limit":
            goal = self.read_register("goal_current")
            self.write_register("goal_current", max(-value, min(value, goal)))
        self.write_register(name, value)

    def reg_write(self, address: int, data: bytes) -> int:
        error = self.check_write(address, data)
        if error:
            return error
        self.registered = (address, bytes(data))
        self.write_register("registered_instruction", 1)
        return p.ERR_NONE

    def action(self, now: float = 0.0) -> int:
        if self.registered is None:
            return p.ERR_INSTRUCTION
        address, data = self.registered
        self.registered = None
        self.write_register("registered_instruction", 0)
        return self.write(address, data, now)

    def reboot(self, now: float = 0.0) -> None:
        """RAM (address >= 64) back to defaults, errors cleared, EEPROM kept; holds where it is."""
        eeprom = bytes(self.memory[:EEPROM_END])
        present = {n: self.read_register(n) for n in ("present_position", "present_velocity",
                                                      "present_current", "present_input_voltage",
                                                      "present_temperature")}
        self._load_defaults(keep=())
        self.memory[:EEPROM_END] = eeprom
        for n, v in present.items():
            self.write_register(n, v)
        self.write_register("goal_current", self.read_register("current_limit"))
        self.write_register("goal_pwm", self.read_register("pwm_limit"))
        self.write_register("goal_position", present["present_position"])
        self.registered = None
        self.watchdog_expired = False
        self.last_contact = now
        self.reboots += 1

    def factory_reset(self, option: int) -> int:
        """0xFF resets everything, 0x01 all but the ID, 0x02 all but the ID and the baud rate."""
        keep = {0xFF: (), 0x01: ("id",), 0x02: ("id", "baud_rate")}.get(option)
        if keep is None:
            return p.ERR_DATA_RANGE
        present = {n: self.read_register(n) for n in ("present_position", "present_velocity",
                                                      "present_current")}
        self._load_defaults(keep=keep)
        for n, v in present.items():
            self.write_register(n, v)
        self.write_register("goal_position", present["present_position"])
        self.registered = None
        self.watchdog_expired = False
        return p.ERR_NONE

    def __repr__(self) -> str:
        return f"EmulatedServo(id={self.id}, model={self.model.name!r})"

