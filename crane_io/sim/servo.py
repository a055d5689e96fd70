"""One emulated Dynamixel X-series servo: its control table and what writing to it does.

The memory is the Protocol 2.0 control table of the servo's model (crane_io.dynamixel.control_table), in raw
little-endian bytes. Rules follow the ROBOTIS e-manual (see shared/crane_x7_facts.md section 2):

- Read-only items (R) cannot be written (Access Error 0x07); neither can the EEPROM area (address
  < 64) while Torque Enable is 1. A write that covers only part of an item is a Data Length Error
  (0x05); a value outside an item's range is a Data Range Error (0x04). A rejected write changes
  nothing.
- A goal beyond its limit item (Goal Current beyond +-Current Limit, Goal Position outside the position
  limits in Position mode, ...) is refused with Data Limit Error (0x06); the frame of the position,
  velocity and current items follows Drive Mode and Homing Offset (crane_io.sim.servo_rules).
- Changing Operating Mode resets the gains, sets Profile Velocity/Acceleration to 0, Goal PWM to PWM
  Limit and Goal Current to Current Limit.
- Torque Enable 1 sets Goal Position to Present Position (the servo holds where it is) and is refused
  while a shutdown hardware error is latched (until reboot).
- Hardware Error Status bits that are in the Shutdown mask turn torque off; every status packet then
  carries the alert bit 0x80.
- Bus Watchdog (address 98, 20 ms/LSB): with torque on and a non-zero value, no instruction for that
  long makes the servo stop (the plant sees it as torque off), the item reads -1 and a write to a goal
  item is refused with Data Range Error (0x04) until 0 is written to it.
- Indirect Data bytes stand for the bytes their Indirect Address names (crane_io.sim.servo_indirect).
- Reboot and Factory Reset restart the servo: silent for REBOOT_SILENCE_S, then Realtime Tick from 0.

Time comes from the chain (`now`, seconds of simulated or wall time); this class never sleeps.
"""

from __future__ import annotations

import math
import struct

import numpy as np

from crane_io.dynamixel.control_table import (
    CONTROL_TABLE_SIZE,
    EEPROM_END,
    MODE_CURRENT_BASED_POSITION,
    MODE_EXTENDED_POSITION,
    MODE_POSITION,
    MODELS,
    XM430_W350,
    Register,
    ServoModel,
)
from crane_io.dynamixel.units import (
    AMPERE_PER_CURRENT_LSB,
    POSITION_CENTER,
    RAD_PER_PULSE,
    RADS_PER_VELOCITY_LSB,
    SECONDS_PER_WATCHDOG_LSB,
    to_signed,
)
from crane_io.sim import protocol as p
from crane_io.sim import servo_indirect
from crane_io.sim.servo_indirect import ADDRESS_ITEMS, touches_data
from crane_io.sim.servo_rules import (
    DRIVE_MODE_AT,
    HOMING_OFFSET_AT,
    effective_homing,
    goal_error,
    in_range,
)

# a servo's state outside its control table: one float64 per column (EmulatedServo's `state`)
S_CONTACT, S_EXPIRED, S_ON_BUS, S_FAST_READ, S_BOOT = range(5)
STATE_SIZE = 5
# a rebooting servo answers the Reboot instruction, then hears nothing for this long (chain seconds). The
# e-manual gives no figure; an X-series servo was measured at about 0.4 s
# (github.com/ROBOTIS-GIT/emanual/issues/1698), and the longer value is the stricter one for a host.
REBOOT_SILENCE_S = 0.5
MEMORY_SIZE = CONTROL_TABLE_SIZE  # the whole X-series control table, Indirect Data included
BAUD_CODES = {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000, 6: 4_000_000,
              7: 4_500_000}
POSITION_MODES = (MODE_POSITION, MODE_EXTENDED_POSITION, MODE_CURRENT_BASED_POSITION)
# the items a Bus Watchdog error makes read-only (e-manual, Bus Watchdog (98))
GOAL_ITEMS = ("goal_pwm", "goal_current", "goal_velocity", "goal_position")
_I16, _U16, _I32, _U32 = struct.Struct("<h"), struct.Struct("<H"), struct.Struct("<i"), struct.Struct("<I")
# (size, signed) -> how a register is stored
_STRUCTS = {(1, False): struct.Struct("<B"), (1, True): struct.Struct("<b"), (2, False): _U16,
            (2, True): _I16, (4, False): _U32, (4, True): _I32}
_PRESENT = struct.Struct("<hii")  # Present Current, Velocity, Position
_TICK_MOVING = struct.Struct("<HB")  # Realtime Tick, Moving
_SUPPLY = struct.Struct("<HB")  # Present Input Voltage, Present Temperature
_SUPPLY_RAW: dict[tuple[float, float], tuple[int, int]] = {}  # (V, deg C) -> their register values
_GAINS = struct.Struct("<HHH")  # Position D, I, P Gain
_I32_MIN, _I32_MAX = -(2**31), 2**31 - 1
_MASKS = {1: 0xFF, 2: 0xFFFF, 4: 0xFFFFFFFF}
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
        memory=None,
        state=None,
    ):
        """`memory`: a writable buffer of MEMORY_SIZE bytes to hold the control table (the simulated chain
        gives each servo a row of one array); default a bytearray of its own. `state`: a float64 array of
        STATE_SIZE holding `last_contact`, `watchdog_expired`, `on_bus`, `supports_fast_sync_read` and
        `booting_until` (the chain gives each servo a row of one array, which its compiled lockstep path
        reads and writes); default an array of its own."""
        self.model = MODELS[model] if isinstance(model, str) else model
        self.registers: dict[str, Register] = dict(self.model.registers)
        self._at: dict[int, Register] = {r.address: r for r in self.registers.values()}
        self._owner: list[Register | None] = [None] * MEMORY_SIZE
        for r in self.registers.values():
            for a in range(r.address, r.address + r.size):
                self._owner[a] = r
        # name -> (address, signed view, unsigned view, mask): register access is one struct call
        self._access: dict[str, tuple[int, struct.Struct, struct.Struct, int]] = {
            r.name: (r.address, _STRUCTS[r.size, r.signed], _STRUCTS[r.size, False], _MASKS[r.size])
            for r in self.registers.values()
        }
        a = self._access
        at = {name: entry[0] for name, entry in a.items()}
        # addresses of the items the chain reads and writes every control step
        self._moving_at, self._threshold_at = at["moving"], at["moving_threshold"]
        self._torque_at, self._hw_error_at = at["torque_enable"], at["hardware_error_status"]
        self._watchdog_at, self._baud_at = at["bus_watchdog"], at["baud_rate"]
        self._srl_at, self._id_at = at["status_return_level"], at["id"]
        self.baud_address = self._baud_at  # memory[baud_address] is the Baud Rate code (BAUD_CODES)
        self.srl_address = self._srl_at  # memory[srl_address] is the Status Return Level
        self.secondary_address = at["secondary_id"]  # memory[secondary_address] is the Secondary ID
        self._command_at = tuple(at[n] for n in (
            "torque_enable", "operating_mode", "goal_current", "goal_position", "position_d_gain",
            "current_limit"))
        # X-series layout: Present Current, Velocity, Position are one block at 126 (as the bus reads
        # them), Realtime Tick and Moving one at 120, Present Input Voltage and Temperature one at 144
        self._present_at = at["present_current"]
        self._tick_at = at["realtime_tick"]
        self._supply_at = at["present_input_voltage"]
        pa = self._present_at
        if not (at["present_velocity"] == pa + 2 and at["present_position"] == pa + 6
                and self._moving_at == self._tick_at + 2
                and at["present_temperature"] == self._supply_at + 2
                and at["position_i_gain"] == at["position_d_gain"] + 2
                and at["position_p_gain"] == at["position_d_gain"] + 4):
            raise ValueError(f"{self.model.name}: control table is not laid out like the X series")
        self.firmware_version = firmware_version
        if state is None:
            state = np.zeros(STATE_SIZE)
        if state.shape != (STATE_SIZE,) or state.dtype != np.float64:
            raise ValueError(f"a servo's state is a float64 array of {STATE_SIZE} values")
        self._state = state
        self.supports_fast_sync_read = supports_fast_sync_read
        if memory is None:
            self.memory = bytearray(MEMORY_SIZE)
        else:
            self.memory = memoryview(memory).cast("B")
            if len(self.memory) != MEMORY_SIZE or self.memory.readonly:
                raise ValueError(f"a servo's memory is a writable buffer of {MEMORY_SIZE} bytes")
        self.on_bus = True  # False: the servo has vanished from the bus (no packets in or out)
        self.registered: tuple[int, bytes] | None = None  # a Reg Write waiting for Action
        self.watchdog_expired = False
        self.last_contact = 0.0
        self.reboots = 0
        # Realtime Tick counts from the servo's last restart: the chain's millisecond count it restarted at
        self.tick_origin_ms = 0
        self.indirect: dict[int, int] = {}  # mapped Indirect Data bytes (crane_io.sim.servo_indirect)
        self._input_voltage = input_voltage
        self._temperature = temperature
        self._load_defaults(keep=())
        self.write_register("id", servo_id)
        self.write_register("baud_rate", baud_code)
        if return_delay_time is not None:
            self.write_register("return_delay_time", return_delay_time)
        _PRESENT.pack_into(self.memory, self._present_at, 0, 0, POSITION_CENTER)  # at 0 rad, at rest
        self.write_register("goal_position", self.read_register("present_position"))

    # ---- the servo's state outside its control table (a row of the chain's `servo_state`) -----------
    @property
    def last_contact(self) -> float:
        """The time (chain seconds) the last instruction for this servo arrived."""
        return float(self._state[S_CONTACT])

    @last_contact.setter
    def last_contact(self, now: float) -> None:
        self._state[S_CONTACT] = now

    @property
    def watchdog_expired(self) -> bool:
        """The Bus Watchdog stopped the servo (until 0 is written to it, or a reboot)."""
        return bool(self._state[S_EXPIRED])

    @watchdog_expired.setter
    def watchdog_expired(self, value: bool) -> None:
        self._state[S_EXPIRED] = 1.0 if value else 0.0

    @property
    def on_bus(self) -> bool:
        """False: the servo has vanished from the bus (no packets in or out)."""
        return bool(self._state[S_ON_BUS])

    @on_bus.setter
    def on_bus(self, value: bool) -> None:
        self._state[S_ON_BUS] = 1.0 if value else 0.0

    @property
    def booting_until(self) -> float:
        """The chain time a reboot ends (0: not rebooting); until then the servo hears nothing."""
        return float(self._state[S_BOOT])

    @booting_until.setter
    def booting_until(self, now: float) -> None:
        self._state[S_BOOT] = now

    @property
    def supports_fast_sync_read(self) -> bool:
        """The firmware answers Fast Sync Read and Fast Bulk Read."""
        return bool(self._state[S_FAST_READ])

    @supports_fast_sync_read.setter
    def supports_fast_sync_read(self, value: bool) -> None:
        self._state[S_FAST_READ] = 1.0 if value else 0.0

    # ---- raw register access (no access rules; for the chain and for tests) ---------------------
    @property
    def id(self) -> int:
        return self.memory[self._id_at]

    def read_register(self, name: str) -> int:
        try:
            address, view, _unsigned, _mask = self._access[name]
        except KeyError:
            self._register(name)  # raises the KeyError naming the model
            raise
        if name == "bus_watchdog" and self.watchdog_expired:
            return -1
        return view.unpack_from(self.memory, address)[0]

    def write_register(self, name: str, value: int) -> None:
        """Set an item directly, bypassing access rules and side effects (tests, the chain)."""
        try:
            address, _view, unsigned, mask = self._access[name]
        except KeyError:
            self._register(name)
            raise
        unsigned.pack_into(self.memory, address, int(value) & mask)

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
        self.indirect = servo_indirect.mapping(self.memory)

    # ---- state the chain and the plant need ---------------------------------------------------
    @property
    def baudrate(self) -> int:
        return BAUD_CODES.get(self.memory[self._baud_at], 0)
    @property
    def return_delay_s(self) -> float:
        return self.read_register("return_delay_time") * 2e-6

    @property
    def torque_enabled(self) -> bool:
        return self.memory[self._torque_at] == 1

    @property
    def driving(self) -> bool:
        """Torque on and not stopped by the bus watchdog: what the plant sees as torque enabled."""
        return self.torque_enabled and not self.watchdog_expired

    @property
    def alert(self) -> bool:
        return self.memory[self._hw_error_at] != 0

    def status_error(self, error_number: int = p.ERR_NONE) -> int:
        """The error byte of a status packet: the error number plus the alert bit when needed."""
        return error_number | (p.ERR_ALERT if self.memory[self._hw_error_at] else 0)

    def command(self) -> tuple[bool, int, float, float, tuple[int, int, int], float]:
        """(driving, operating mode, goal current A, goal position rad, (P, I, D) gains, current limit A)."""
        m = self.memory
        torque, mode, goal_cur, goal_pos, gains, limit = self._command_at
        kd, ki, kp = _GAINS.unpack_from(m, gains)
        # the goals in the servo's frame (Drive Mode direction, Homing Offset) back in the actual frame
        sign = -1.0 if m[DRIVE_MODE_AT] & 1 else 1.0
        homing = effective_homing(m[mode], _I32.unpack_from(m, HOMING_OFFSET_AT)[0])
        return (
            m[torque] == 1 and not self.watchdog_expired,
            m[mode],
            sign * (_I16.unpack_from(m, goal_cur)[0] * AMPERE_PER_CURRENT_LSB),
            sign * ((_I32.unpack_from(m, goal_pos)[0] - POSITION_CENTER - homing) * RAD_PER_PULSE),
            (kp, ki, kd),
            _U16.unpack_from(m, limit)[0] * AMPERE_PER_CURRENT_LSB,
        )

    def set_sensors(self, position: float, velocity: float, current: float, now: float,
                    voltage: float | None = None, temperature: float | None = None) -> None:
        """Quantise what the plant measured into the Present items; update Moving and Realtime Tick."""
        m = self.memory
        if math.isfinite(position) and math.isfinite(velocity) and math.isfinite(current):
            # the Present block, quantised like crane_io.dynamixel.units (rad_to_position etc.),
            # in scalar arithmetic, in the servo's frame (Drive Mode direction, Homing Offset)
            sign = -1.0 if m[DRIVE_MODE_AT] & 1 else 1.0
            homing = effective_homing(m[self._command_at[1]], _I32.unpack_from(m, HOMING_OFFSET_AT)[0])
            pos = round(sign * position / RAD_PER_PULSE) + POSITION_CENTER + homing
            vel = round(sign * velocity / RADS_PER_VELOCITY_LSB)
            cur = round(sign * current / AMPERE_PER_CURRENT_LSB)
            pos = _I32_MIN if pos < _I32_MIN else _I32_MAX if pos > _I32_MAX else pos
            vel = _I32_MIN if vel < _I32_MIN else _I32_MAX if vel > _I32_MAX else vel
            cur = -32768 if cur < -32768 else 32767 if cur > 32767 else cur
            _PRESENT.pack_into(m, self._present_at, cur, vel, pos)
        else:  # a plant that blew up leaves the last finite reading in place
            vel = _PRESENT.unpack_from(m, self._present_at)[1]
        if voltage is not None and temperature is not None:
            raw = _SUPPLY_RAW.get((voltage, temperature))  # the plant's supply rarely changes
            if raw is None:
                raw = (max(0, round(voltage * 10)) & 0xFFFF, max(0, round(temperature)) & 0xFF)
                if len(_SUPPLY_RAW) >= 64:
                    _SUPPLY_RAW.clear()
                _SUPPLY_RAW[voltage, temperature] = raw
            _SUPPLY.pack_into(m, self._supply_at, *raw)
        elif voltage is not None or temperature is not None:
            supply, temp = _SUPPLY.unpack_from(m, self._supply_at)
            if voltage is not None:
                supply = max(0, round(voltage * 10)) & 0xFFFF
            if temperature is not None:
                temp = max(0, round(temperature)) & 0xFF
            _SUPPLY.pack_into(m, self._supply_at, supply, temp)
        moving = abs(vel) > _U32.unpack_from(m, self._threshold_at)[0]
        _TICK_MOVING.pack_into(m, self._tick_at, (int(now * 1000) - self.tick_origin_ms) % 32768, moving)

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
        self._state[S_CONTACT] = now

    def check_watchdog(self, now: float) -> None:
        st = self._state
        if st[S_EXPIRED] or self.memory[self._torque_at] != 1:
            return
        raw = self.memory[self._watchdog_at]  # signed; only 1..127 arm the watchdog
        if 0 < raw < 128 and now - float(st[S_CONTACT]) > raw * SECONDS_PER_WATCHDOG_LSB + 1e-9:
            st[S_EXPIRED] = 1.0

    # ---- instruction semantics -----------------------------------------------------------------
    def read(self, address: int, length: int, plain: bool = False) -> tuple[int, bytes]:
        """(error number, data) of a Read; an impossible range answers Access Error with zeros. `plain`: the
        Indirect Data bytes as stored (not where their Indirect Address points)."""
        if length < 0 or address < 0 or address + length > MEMORY_SIZE:
            return p.ERR_ACCESS, bytes(max(0, min(length, p.MAX_LENGTH)))
        if self.indirect and not plain and touches_data(address, address + length):
            return servo_indirect.read(self, address, length)
        wd = self._watchdog_at
        if self.watchdog_expired and address <= wd < address + length:
            data = bytearray(self.memory[address:address + length])
            data[wd - address] = 0xFF
            return p.ERR_NONE, bytes(data)
        return p.ERR_NONE, bytes(self.memory[address:address + length])

    def check_write(self, address: int, data: bytes, plain: bool = False) -> int:
        """The error number a Write of `data` at `address` would get (0 when it is allowed). `plain`: into
        the Indirect Data bytes themselves (not where their Indirect Address points)."""
        end = address + len(data)
        if not data or address < 0 or end > MEMORY_SIZE:
            return p.ERR_ACCESS
        if self.indirect and not plain and touches_data(address, end):
            return servo_indirect.check_write(self, address, data)
        exact = self._at.get(address)
        if exact is not None and address + exact.size == end:
            touched = [exact]  # the usual write: exactly one item
        else:
            touched = []
            # items in address order, so that a write breaking several rules always gets the same
            # error (a set of Registers iterates in an order that depends on the string hash seed)
            owners = {self._owner[a] for a in range(address, end)} - {None}
            for r in sorted(owners, key=lambda r: r.address):
                if r.address < address or r.address + r.size > end:
                    return p.ERR_DATA_LENGTH
                touched.append(r)
            if not touched:
                return p.ERR_ACCESS
        torque = self.memory[self._torque_at] == 1
        for r in touched:
            raw = int.from_bytes(data[r.address - address:r.address - address + r.size], "little")
            error = self._item_error(r, to_signed(raw, r.size) if r.signed else raw, torque)
            if error:
                return error
        return p.ERR_NONE

    def _item_error(self, r: Register, value: int, torque: bool) -> int:
        """The error number of writing `value` to item r (0 when allowed); `torque`: Torque Enable is 1."""
        if r.access != "RW":
            return p.ERR_ACCESS
        if r.eeprom and torque:
            return p.ERR_ACCESS
        if self.watchdog_expired and r.name in GOAL_ITEMS:
            return p.ERR_DATA_RANGE  # the goal items are read-only after a Bus Watchdog error
        if not in_range(r.name, value, self.model.current_limit_max):
            return p.ERR_DATA_RANGE
        return goal_error(self, r.name, value)

    def write(self, address: int, data: bytes, now: float = 0.0, plain: bool = False) -> int:
        """Apply a Write with the servo's rules; returns the error number (0 = written). `plain`: as
        check_write's."""
        if self.indirect and not plain and touches_data(address, address + len(data)):
            return servo_indirect.write(self, address, data, now)
        exact = self._at.get(address)
        if exact is not None and len(data) == exact.size:  # the usual write: exactly one item
            raw = int.from_bytes(data, "little")
            value = to_signed(raw, exact.size) if exact.signed else raw
            error = self._item_error(exact, value, self.memory[self._torque_at] == 1)
            if not error:
                self._apply(exact.name, value, now)
            return error
        error = self.check_write(address, data, plain=True)
        if error:
            return error
        end = address + len(data)
        exact = self._at.get(address)
        if exact is not None and address + exact.size == end:
            touched = [exact]
        else:
            touched = sorted({self._owner[a] for a in range(address, end)} - {None}, key=lambda r: r.address)
        for r in touched:
            raw = int.from_bytes(data[r.address - address:r.address - address + r.size], "little")
            value = to_signed(raw, r.size) if r.signed else raw
            self._apply(r.name, value, now)
        return p.ERR_NONE

    def _set_operating_mode(self, value: int) -> None:
        """A new operating mode resets the mode's goals and limits to their defaults."""
        if value != self.read_register("operating_mode"):
            self.write_register("operating_mode", value)
            defaults = self.model.defaults()
            for item in MODE_RESET_ITEMS:
                self.write_register(item, defaults.get(item, 0))
            self.write_register("goal_pwm", self.read_register("pwm_limit"))
            self.write_register("goal_current", self.read_register("current_limit"))

    def _set_torque_enable(self, value: int, now: float) -> None:
        """Torque on holds the present position (refused while a shutdown is latched)."""
        if value == 1 and self.shutdown_latched:
            return  # refused until reboot; the status packet carries the alert bit
        if value == 1 and not self.torque_enabled:
            self.write_register("goal_position", self.read_register("present_position"))
            self.last_contact = now
        self.write_register("torque_enable", value)

    def _set_bus_watchdog(self, value: int, now: float) -> None:
        """Writing the watchdog restarts it; 0 also clears an expiry."""
        self.write_register("bus_watchdog", value)
        if value == 0:
            self.watchdog_expired = False
        self.last_contact = now

    def _apply(self, name: str, value: int, now: float) -> None:
        if name == "operating_mode":
            self._set_operating_mode(value)
            return
        if name == "torque_enable":
            self._set_torque_enable(value, now)
            return
        if name == "bus_watchdog":
            self._set_bus_watchdog(value, now)
            return
        if name == "current_limit":
            goal = self.read_register("goal_current")
            self.write_register("goal_current", max(-value, min(value, goal)))
        self.write_register(name, value)
        if name in ADDRESS_ITEMS:
            self.indirect = servo_indirect.mapping(self.memory)

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
        """RAM (address >= 64) back to defaults (torque off), errors cleared, EEPROM kept; the servo hears
        nothing for REBOOT_SILENCE_S (`booting_until`)."""
        eeprom = bytes(self.memory[:EEPROM_END])
        present = {n: self.read_register(n) for n in (
            "present_position", "present_velocity", "present_current", "present_input_voltage",
            "present_temperature")}
        self._load_defaults(keep=())
        self.memory[:EEPROM_END] = eeprom
        for n, v in present.items():
            self.write_register(n, v)
        self.write_register("goal_current", self.read_register("current_limit"))
        self.write_register("goal_pwm", self.read_register("pwm_limit"))
        self.write_register("goal_position", present["present_position"])
        self._restart(now)
        self.reboots += 1

    def _restart(self, now: float) -> None:
        """The firmware restarts: nothing registered, no watchdog error, silent for REBOOT_SILENCE_S, then
        Realtime Tick counts from 0."""
        self.registered = None
        self.watchdog_expired = False
        self.last_contact = now
        self.booting_until = now + REBOOT_SILENCE_S
        self.tick_origin_ms = round(self.booting_until * 1000)

    def factory_reset(self, option: int, now: float = 0.0) -> int:
        """0xFF resets everything, 0x01 all but the ID, 0x02 all but the ID and the baud rate; then the servo
        restarts as after a reboot."""
        keep = {0xFF: (), 0x01: ("id",), 0x02: ("id", "baud_rate")}.get(option)
        if keep is None:
            return p.ERR_DATA_RANGE
        present = {n: self.read_register(n) for n in ("present_position", "present_velocity",
                                                      "present_current")}
        self._load_defaults(keep=keep)
        for n, v in present.items():
            self.write_register(n, v)
        self.write_register("goal_position", present["present_position"])
        self._restart(now)
        return p.ERR_NONE

    def __repr__(self) -> str:
        return f"EmulatedServo(id={self.id}, model={self.model.name!r})"

