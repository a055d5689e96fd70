"""The register-level side of a bus (crane_io.dynamixel.bus): the arm's servos found, set up, switched on and
off and diagnosed one register at a time, through the bus's transfers (crane_io.dynamixel.transfer).

`ServoRegisters` is what `DynamixelBus` adds its control cycle to: discovery (`ping_all`), set-up
(`configure`), torque, the hardware-error poll and the Bus Watchdog check, the per-servo report, and the
public register reads the report is made of (`read_block`, `reply_timeout_s`, `late_reply_s`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from crane_io.description import ArmDescription, default_arm
from crane_io.dynamixel import units
from crane_io.dynamixel.control_table import (
    HARDWARE_ERROR_BITS,
    MODE_CURRENT,
    MODE_POSITION,
    X_SERIES,
    ServoModel,
    model_by_number,
    span,
)
from crane_io.dynamixel.faults import (
    WATCHDOG_EXPIRED,
    CommunicationError,
    ConfigurationMismatchError,
    ServoFaultError,
    ServoMissingError,
    WatchdogExpiredError,
    WrongModelError,
    decode_hardware_error,
    describe_faults,
    servo_label,
)
from crane_io.dynamixel.packets import CranePacketHandler
from crane_io.dynamixel.port import CranePortHandler
from crane_io.dynamixel.servo_report import servo_report as _servo_report
from crane_io.dynamixel.status_read import StatusSyncRead
from crane_io.dynamixel.transfer import BusStats, Link
from crane_io.errors import ConfigError

log = logging.getLogger(__name__)

# the hardware-error poll: ONE sync read of Hardware Error Status (70) .. Bus Watchdog (98); offsets in it
_POLL_ADDRESS, _POLL_SIZE = span("hardware_error_status", "bus_watchdog")
_POLL_ERRORS = X_SERIES["hardware_error_status"].address - _POLL_ADDRESS
_POLL_WATCHDOG = X_SERIES["bus_watchdog"].address - _POLL_ADDRESS
# the faults the servo's factory Shutdown mask (e-manual Shutdown(63), default 0x34) turns its torque off for
_SHUTDOWN_FAULTS = {name for bit, name in HARDWARE_ERROR_BITS.items()
                    if X_SERIES["shutdown"].default >> bit & 1}


@dataclass(frozen=True)
class ServoInfo:
    servo_id: int
    joint: str
    model_number: int
    model: str
    firmware: int


class ServoRegisters:
    """The servos of one arm behind one port, register by register (see the module docstring)."""

    def __init__(self, port: str, arm: ArmDescription | None, name: str, retries: int, error_budget: int,
                 stats: BusStats):
        if retries < 0:
            raise ConfigError(f"retries must be 0 or more, got {retries}")
        if error_budget < 1:
            raise ConfigError(f"error_budget must be at least 1, got {error_budget}")
        self.port_name = str(port)
        self.arm = arm if arm is not None else default_arm()
        self.name = name
        self.stats = stats
        self._link = Link(self.port_name, int(retries), int(error_budget), stats)
        self.servos: dict[str, ServoInfo] = {}
        self.torque_enabled = False
        self.watchdog_s: float | None = None  # the Bus Watchdog armed by configure (None: off)
        self._closed = False
        self._poll_reader: StatusSyncRead | None = None

        joints = self.arm.joints
        self.joint_names = tuple(j.name for j in joints)
        self.ids = tuple(j.servo_id for j in joints)
        self.modes = np.array([MODE_CURRENT if j.name in self.arm.bilateral_joints else MODE_POSITION
                               for j in joints])
        self.current_joints = tuple(i for i, m in enumerate(self.modes) if m == MODE_CURRENT)
        self.position_joints = tuple(i for i, m in enumerate(self.modes) if m == MODE_POSITION)
        self.current_limits = np.array([j.current_limit for j in joints])  # A; read back in configure
        # rad, what a goal position is clamped to: the joint limits, in configure narrowed to the servos'
        # position limits (a servo refuses a Goal Position outside them)
        self.lower = np.array([j.lower for j in joints])
        self.upper = np.array([j.upper for j in joints])

    @property
    def retries(self) -> int:
        """Repeats of a transfer whose reply went missing or was corrupted (at most 1 + retries tries)."""
        return self._link.retries

    @property
    def error_budget(self) -> int:
        """Failed transfers tolerated in any one-second window."""
        return self._link.error_budget

    @property
    def _port(self) -> CranePortHandler | None:
        return self._link.port

    @property
    def _ph(self) -> CranePacketHandler:
        return self._link.ph

    @property
    def is_open(self) -> bool:
        return self._link.port is not None and self._link.port.is_open

    def _attach(self, port: CranePortHandler) -> None:
        """Transfer through the opened `port` (and poll its servos' hardware errors through it)."""
        self._link.attach(port)
        self._poll_reader = StatusSyncRead(port, self._link.ph, _POLL_ADDRESS, _POLL_SIZE)
        for sid in self.ids:
            self._poll_reader.addParam(sid)

    def require_open(self) -> CranePortHandler:
        """The open port; CommunicationError saying why there is none (not opened yet, or closed)."""
        port = self._link.port
        if port is None or not port.is_open:
            if self._closed:
                raise CommunicationError(f"the bus on {self.port_name} is closed")
            raise CommunicationError(f"the bus on {self.port_name} is not open; call open() or use `with`")
        return port

    # ---- discovery and set-up ------------------------------------------------------------------
    def ping_all(self) -> dict[int, ServoInfo]:
        """Ping every servo of the arm and check its model number.
        Raises ServoMissingError (naming joint, ID and port) or WrongModelError."""
        self.require_open()
        missing = {}
        found = {}
        for joint, sid in zip(self.joint_names, self.ids):
            number = self._link.ping(sid)
            if number is None:
                missing[joint] = sid
            else:
                found[joint] = number
        if missing:
            raise self._missing_error(missing, "does not answer", "do not answer")
        infos = {}
        for j, (joint, sid) in enumerate(zip(self.joint_names, self.ids)):
            expected = self.arm.joints[j].model
            number = found[joint]
            model = model_by_number(number)
            if model is None or model.name != expected:
                what = model.name if model else "an unknown model"
                raise WrongModelError(
                    f"servo {servo_label(joint, sid)} on {self.port_name} is model number {number} ({what}) "
                    f"but the arm description expects a {expected}",
                    joint=joint, expected=expected, found=number)
            firmware = self._read(sid, "firmware_version", joint)
            infos[sid] = ServoInfo(sid, joint, number, model.name, firmware)
        self.servos = {i.joint: i for i in infos.values()}
        return infos

    def configure(self, *, watchdog_s: float | None = 0.1, current_limits=None) -> None:
        """Torque off, then per servo: Return Delay Time 0, drive mode not reversed, operating mode
        (current for arm.bilateral_joints, position for the held joints), Current Limit (A, a dict
        joint -> A or an (8,) array; None keeps the servo's), Bus Watchdog (`watchdog_s`, 0.02..2.54 s,
        None or 0 to disable). Every register is read back and verified."""
        self.require_open()
        watchdog_raw = 0
        if watchdog_s:
            if not 0.02 <= watchdog_s <= 127 * units.SECONDS_PER_WATCHDOG_LSB:
                raise ConfigError(f"watchdog_s must be between 0.02 and 2.54 s (or 0 to disable), "
                                  f"got {watchdog_s}")
            watchdog_raw = units.seconds_to_watchdog(watchdog_s)
        limits_raw = self._current_limit_raw(current_limits)
        self.torque_off()
        for j, (joint, sid) in enumerate(zip(self.joint_names, self.ids)):
            self._set_up(j, joint, sid, limits_raw[j], watchdog_raw)
        for j, (joint, sid) in enumerate(zip(self.joint_names, self.ids)):
            expect = {"return_delay_time": 0, "operating_mode": int(self.modes[j]),
                      "bus_watchdog": watchdog_raw}
            if limits_raw[j] is not None:
                expect["current_limit"] = limits_raw[j]
            for reg, value in expect.items():
                got = self._read(sid, reg, joint)
                if got != value:
                    raise ConfigurationMismatchError(
                        f"servo {servo_label(joint, sid)} on {self.port_name} holds {reg} = {got} after "
                        f"{value} was written; is its torque on or its firmware too old?")
            self.current_limits[j] = float(units.current_to_ampere(self._read(sid, "current_limit", joint)))
            if j in self.position_joints:  # the servo refuses a Goal Position outside its position limits
                low = float(units.position_to_rad(self._read(sid, "min_position_limit", joint)))
                high = float(units.position_to_rad(self._read(sid, "max_position_limit", joint)))
                self.lower[j], self.upper[j] = max(self.lower[j], low), min(self.upper[j], high)
        self.watchdog_s = float(units.watchdog_to_seconds(watchdog_raw)) if watchdog_raw else None

    def _set_up(self, j: int, joint: str, sid: int, limit_raw: int | None, watchdog_raw: int) -> None:
        """configure's writes to one servo (its torque is off)."""
        self._write(sid, "return_delay_time", 0, joint)
        drive = self._read(sid, "drive_mode", joint)
        if drive & 1:
            self._write(sid, "drive_mode", drive & ~1, joint)
        if self._read(sid, "operating_mode", joint) != self.modes[j]:
            self._write(sid, "operating_mode", int(self.modes[j]), joint)
        if limit_raw is not None:
            self._write(sid, "current_limit", limit_raw, joint)
        self._write(sid, "bus_watchdog", 0, joint)  # clears a latched watchdog error too
        if watchdog_raw:
            self._write(sid, "bus_watchdog", watchdog_raw, joint)

    def _current_limit_raw(self, current_limits) -> list[int | None]:
        out: list[int | None] = [None] * len(self.ids)
        if current_limits is None:
            return out
        if isinstance(current_limits, dict):
            items = [(self.arm.index(k), v) for k, v in current_limits.items()]
        else:
            arr = np.asarray(current_limits, dtype=float)
            if arr.shape != (len(self.ids),):
                raise ConfigError(f"current_limits must have {len(self.ids)} entries, got shape {arr.shape}")
            items = list(enumerate(arr))
        for j, amps in items:
            model: ServoModel = self.arm.joints[j].servo_model
            raw = int(units.ampere_to_current(amps))
            if not np.isfinite(amps) or amps < 0 or raw > model.current_limit_max:
                top = float(units.current_to_ampere(model.current_limit_max))
                raise ConfigError(f"current limit {amps} A for {self.joint_names[j]} is outside "
                                  f"0..{top:.2f} A of its {model.name}")
            out[j] = raw
        return out

    def limit_motion(self, velocity_limit, profile_velocity) -> tuple[np.ndarray, np.ndarray]:
        """Velocity Limit and Profile Velocity of every servo (rad/s: one value or one per servo; a
        Profile Velocity of 0 is no profile), torque off. Returns the values they held before, to
        restore them with the same call (Velocity Limit is kept through a power cycle). Read back and
        verified."""
        self.require_open()
        n = len(self.ids)
        wanted = {"velocity_limit": np.broadcast_to(np.asarray(velocity_limit, dtype=float), (n,)),
                  "profile_velocity": np.broadcast_to(np.asarray(profile_velocity, dtype=float), (n,))}
        before = {reg: np.zeros(n) for reg in wanted}
        for j, (joint, sid) in enumerate(zip(self.joint_names, self.ids)):
            for reg, values in wanted.items():
                before[reg][j] = float(units.velocity_to_rads(self._read(sid, reg, joint)))
                raw = int(units.rads_to_velocity(values[j]))
                self._write(sid, reg, raw, joint)
                got = self._read(sid, reg, joint)
                if got != raw:
                    raise ConfigurationMismatchError(
                        f"servo {servo_label(joint, sid)} on {self.port_name} holds {reg} = {got} after "
                        f"{raw} was written; is its torque on?")
        return before["velocity_limit"], before["profile_velocity"]

    # ---- torque --------------------------------------------------------------------------------
    def torque_on(self) -> None:
        """Hold the held joints where they are (goal position = present), zero the goal current of the
        current-mode joints, then enable torque on every servo."""
        self.require_open()
        for i in self.position_joints:
            joint, sid = self.joint_names[i], self.ids[i]
            self._write(sid, "goal_position", self._read(sid, "present_position", joint), joint)
        for i in self.current_joints:
            self._write(self.ids[i], "goal_current", 0, self.joint_names[i])
        for joint, sid in zip(self.joint_names, self.ids):
            self._write(sid, "torque_enable", 1, joint)
        self.torque_enabled = True

    def torque_off(self) -> None:
        """Disable torque on every servo; raises if one does not acknowledge (see safe_stop)."""
        self.require_open()
        for joint, sid in zip(self.joint_names, self.ids):
            self._write(sid, "torque_enable", 0, joint)
        self.torque_enabled = False

    # ---- diagnostics ---------------------------------------------------------------------------
    def read_hardware_errors(self) -> dict[str, list[str]]:
        """Joint -> named faults, for the joints that have any: the Hardware Error Status bits
        (overload, overheating, ...) and "bus watchdog expired" (Bus Watchdog reads -1). ONE sync
        read of addresses 70..98 of every servo; when that fails, servo by servo, and a servo that
        does not answer is listed as ['not answering']."""
        self.require_open()
        link, reader = self._link, self._poll_reader
        if link.retry(link.group_once, reader.txRxPacket):
            blocks = {sid: bytes(reader.data_dict[sid]) for sid in self.ids}
        else:
            blocks = {}
            for joint, sid in zip(self.joint_names, self.ids):
                try:
                    blocks[sid] = link.read_block(sid, _POLL_ADDRESS, _POLL_SIZE, joint)
                except CommunicationError:
                    blocks[sid] = None
        link.update_byte_stats()
        faults = {}
        for joint, sid in zip(self.joint_names, self.ids):
            names = _poll_faults(blocks[sid])
            if names:
                faults[joint] = names
        return faults

    def check_watchdog(self) -> None:
        """Raise WatchdogExpiredError if the Bus Watchdog stopped any servo (one sync read)."""
        self._raise_if_expired(self.read_hardware_errors())

    def _raise_if_expired(self, faults: dict[str, list[str]], gap: float | None = None) -> None:
        expired = {j: [WATCHDOG_EXPIRED] for j, f in faults.items() if WATCHDOG_EXPIRED in f}
        if expired:
            raise self._fault_error(expired, gap)

    def _fault_error(self, faults: dict[str, list[str]], gap: float | None = None) -> ServoFaultError:
        ids = dict(zip(self.joint_names, self.ids))
        if all(f == [WATCHDOG_EXPIRED] for f in faults.values()):
            names = ", ".join(servo_label(j, ids[j]) for j in faults)
            wd = f"{self.watchdog_s:g} s " if self.watchdog_s else ""
            pause = f" (the host paused {gap:.3f} s)" if gap is not None else ""
            return WatchdogExpiredError(
                f"the Bus Watchdog ({wd}without an instruction) stopped {names} on {self.port_name}{pause}; "
                "they hold no torque until configure() re-arms them (keep the control loop from stalling)",
                faults=faults)
        where = describe_faults(faults, ids)
        off = any(_SHUTDOWN_FAULTS.intersection(names) for names in faults.values())
        return ServoFaultError(
            f"hardware error on {self.port_name}: {where}"
            + ("; the servo switched its torque off (remove the cause, then power-cycle or reboot it)" if off
               else "; remove the cause, then power-cycle or reboot the servo to clear it"),
            faults=faults)

    def _silent_servos(self) -> dict[str, int]:
        """Ping each servo (once more if it failed) to learn which ones went silent (after a failed read)."""
        silent = {joint: sid for joint, sid in zip(self.joint_names, self.ids)
                  if self._link.ping(sid, tries=2) is None}
        if len(silent) == len(self.ids):
            return {}  # nobody answers: a link problem, not a servo problem
        return silent

    def _missing_error(self, missing: dict[str, int], one: str, many: str) -> ServoMissingError:
        if len(missing) == len(self.ids):
            return ServoMissingError(
                f"no servo answers on {self.port_name} at {self.arm.baudrate} bps (is the arm powered, the "
                "cable plugged in and the baud rate right?)", missing=missing, port=self.port_name)
        names = ", ".join(servo_label(j, s) for j, s in missing.items())
        verb = one if len(missing) == 1 else many
        return ServoMissingError(f"servo {names} {verb} on {self.port_name} (check its cable and power)",
                                 missing=missing, port=self.port_name)

    # ---- the per-servo report and the reads it is made of -----------------------------------------
    def servo_report(self, late_listen_s: float = 0.0) -> list[dict]:
        """`crane_io.dynamixel.servo_report.servo_report(self, late_listen_s)`: one dict per servo for
        `crane-collect check` and the stop's torque read-back (see there)."""
        return _servo_report(self, late_listen_s)

    def read_block(self, sid: int, address: int, size: int, joint: str) -> bytes:
        """`size` bytes of servo `sid`'s control table from `address` in one read, retried; raises
        CommunicationError when it does not answer, ServoRejectedError when it refuses."""
        self.require_open()
        return self._link.read_block(sid, address, size, joint)

    def reply_timeout_s(self, data_length: int) -> float:
        """How long each try of a read of `data_length` bytes waits for its reply (as the SDK computes it,
        with this port's latency)."""
        self.require_open()
        return self._link.reply_timeout_s(data_length)

    def late_reply_s(self, sid: int, address: int, size: int, listen_s: float) -> float | None:
        """Ask servo `sid` once more for `size` bytes at `address` and listen up to `listen_s` for that
        reply: the seconds it took, or None (silence). For reports: far longer than a control cycle."""
        self.require_open()
        return self._link.late_reply_s(sid, address, size, listen_s)

    # ---- register access by name, one servo at a time -------------------------------------------
    def _read(self, sid: int, name: str, joint: str) -> int:
        reg = self.arm.by_id(sid).servo_model.register(name)
        data = self._link.read_block(sid, reg.address, reg.size, joint)
        return int.from_bytes(data, "little", signed=reg.signed)

    def _write(self, sid: int, name: str, value: int, joint: str) -> None:
        self._link.write_register(sid, self.arm.by_id(sid).servo_model.register(name), value, joint)


def _poll_faults(block: bytes | None) -> list[str]:
    """The named faults in one servo's block of the hardware-error poll (None: it did not answer)."""
    if block is None:
        return ["not answering"]
    names = decode_hardware_error(block[_POLL_ERRORS])
    if block[_POLL_WATCHDOG] == 0xFF:  # Bus Watchdog = -1: expired
        names.append(WATCHDOG_EXPIRED)
    return names
