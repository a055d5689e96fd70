"""`DynamixelBus`: one CRANE-X7 on one U2D2, driven through dynamixel-sdk, in SI units.

    from crane_io.dynamixel.bus import DynamixelBus

    with DynamixelBus("/dev/crane_x7_follower", name="follower") as bus:   # opens at 3 Mbps
        bus.ping_all()                  # every servo present and of the right model?
        bus.configure(watchdog_s=0.1)   # torque off, return delay 0, modes, limits, bus watchdog
        bus.torque_on()
        for _ in range(1000):
            state = bus.read_state()    # ONE fast sync read of addresses 126..135: rad, rad/s, A
            bus.write_goal_current(...) # ONE sync write of Goal Current, clamped to the limits
    # leaving the block (normally, by exception, Ctrl+C): goal current 0, then torque off

Arrays are always (8,) in `arm.joints` order. Raw register units never leave this module.

Faults: every transfer is retried at most `retries` times; a read that still fails raises
`CommunicationError` (or `ServoMissingError` naming the silent servo) and never returns zeros or old
values. Failed attempts are also counted in a sliding one-second window; more than `error_budget` of
them means the link is unusable and the bus raises even if retries kept succeeding. A status packet
with the alert bit set makes `read_state` read the Hardware Error Status registers and raise
`ServoFaultError` naming each joint's faults.

Bus Watchdog: a sync write gets no reply, so a servo stopped by its watchdog (the host was silent
longer than `configure(watchdog_s=...)`) would go unnoticed. The bus therefore (1) reads the Bus
Watchdog register (-1 after expiry) in `read_hardware_errors`, which the collect loop polls, and
(2) re-checks it whenever the host paused longer than half the watchdog time between two transfers:
`read_state` / `write_goal_*` then raise `WatchdogExpiredError` naming the stopped joints.

The object is not thread-safe: use one bus per thread (one per arm).

Its layers, one module each: the packets (crane_io.dynamixel.packets: instruction packets; status_read: the
sync reads and their replies; codec: the control cycle's two packets, plain or compiled, a backend), the
transfers with the one retry loop and the error budget (transfer.Link), the register-level API
(registers.ServoRegisters: discovery, set-up, torque, diagnostics, the per-servo report's reads); this module
adds the control cycle (`read_state`, `write_goal_current`, `write_goal_position`) and the life cycle.
"""

from __future__ import annotations

import logging
import math
import struct
import time
import warnings
from dataclasses import dataclass

import numpy as np
import serial
from dynamixel_sdk import COMM_RX_CORRUPT, COMM_SUCCESS, COMM_TX_FAIL, GroupSyncWrite

from crane_io import shutdown
from crane_io.description import ArmDescription
from crane_io.dynamixel import units
from crane_io.dynamixel.codec import FAST_RECORD, PlainCodec, compiled_codec
from crane_io.dynamixel.control_table import PRESENT_BLOCK_ADDRESS, PRESENT_BLOCK_SIZE, X_SERIES
from crane_io.dynamixel.faults import STATUS_ALERT_BIT, CommunicationError, decode_status_error
from crane_io.dynamixel.port import open_port
from crane_io.dynamixel.registers import ServoInfo, ServoRegisters
from crane_io.dynamixel.status_read import FIRST_PARAM, StatusSyncRead
from crane_io.dynamixel.transfer import BusStats
from crane_io.errors import CraneError

_StatusSyncRead = StatusSyncRead  # the control cycle's reader, under its name in this module too
__all__ = ["BusState", "BusStats", "CommandError", "DynamixelBus", "ServoInfo"]

log = logging.getLogger(__name__)

_FAST_TRIES_BEFORE_FALLBACK = 2
_PRESENT = struct.Struct("<hii")  # Present Current, Velocity, Position (addresses 126, 128, 132)
assert _PRESENT.size == PRESENT_BLOCK_SIZE
_GOAL_CURRENT, _GOAL_POSITION = X_SERIES["goal_current"], X_SERIES["goal_position"]  # the goal sync writes
_NO_FAST_READ = (COMM_TX_FAIL, None)  # what the reader's fast_read returns when the port failed
_STALL_FRACTION = 0.5  # a pause longer than this share of the watchdog time makes the bus check it


class CommandError(CraneError):
    """A command array that cannot be sent (wrong shape, NaN or infinite values)."""


@dataclass(slots=True)
class BusState:
    """One synchronous snapshot of every servo, SI units, (8,) arrays in arm.joints order."""

    position: np.ndarray  # rad
    velocity: np.ndarray  # rad/s
    current: np.ndarray  # A (Present Current)
    t: float  # time.monotonic() when the read was sent
    fast: bool  # True when it came from a fast sync read


class DynamixelBus(ServoRegisters):
    """The CRANE-X7 servo chain behind one port (a U2D2 device path, a pty or `dxlsim://NAME`)."""

    def __init__(self, port: str, arm: ArmDescription | None = None, *, name: str = "arm", retries: int = 2,
                 error_budget: int = 50, latency_ms: float | None = None, fast_sync_read: bool = True):
        stats = BusStats(fast=None if fast_sync_read else False)
        super().__init__(port, arm, name, retries, error_budget, stats)
        self.latency_ms = latency_ms
        self.stop_failures: dict[str, str] = {}
        self._present_all = struct.Struct("<" + _PRESENT.format.lstrip("<") * len(self.ids))  # every servo's
        self._n_servos = len(self.ids)
        self._limits_seen: list | None = None  # current_limits as write_goal_current last saw them
        # the control cycle's packets (crane_io.dynamixel.codec): plain, compiled from torque_on on
        self._codec: PlainCodec = PlainCodec(self._ph, self._n_servos)
        self._compiled_tried = False
        self._reader: StatusSyncRead | None = None
        self._current_writer: GroupSyncWrite | None = None
        self._position_writer: GroupSyncWrite | None = None
        self._fast_misses = 0
        self._why = "no reply"  # read_state: why the latest try failed

    # ---- life cycle ----------------------------------------------------------------------------
    def open(self) -> DynamixelBus:
        """Open the port at the arm's baud rate (3 Mbps). Raises HardwareError with the reason."""
        if self.is_open:
            return self
        if self._closed:
            raise CommunicationError(f"the bus on {self.port_name} was closed; make a new DynamixelBus")
        port = open_port(self.port_name, self.arm.baudrate, latency_ms=self.latency_ms)
        self._attach(port)
        ph = self._ph
        self._reader = StatusSyncRead(port, ph, PRESENT_BLOCK_ADDRESS, PRESENT_BLOCK_SIZE)
        for sid in self.ids:
            self._reader.addParam(sid)
        self._reader.use_codec(self._codec)
        cur, pos = _GOAL_CURRENT, _GOAL_POSITION
        self._current_writer = GroupSyncWrite(port, ph, cur.address, cur.size)
        for i in self.current_joints:
            self._current_writer.addParam(self.ids[i], [0] * cur.size)
        self._position_writer = GroupSyncWrite(port, ph, pos.address, pos.size)
        for i in self.position_joints:
            self._position_writer.addParam(self.ids[i], [0] * pos.size)
        return self

    def _use_compiled_codec(self) -> None:
        """The compiled codec (crane_io.dynamixel.codec), compiled or loaded from numba's cache now, between
        transfers (never while a reply is awaited); without numba the bus keeps the plain one. Done by
        torque_on: a bus that never drives the arm (check, ping) needs no numba."""
        if self._compiled_tried or self._reader is None:
            return
        self._compiled_tried = True
        codec = compiled_codec(self._ph, self._n_servos)
        if codec is not None:
            self.use_codec(codec)

    def use_codec(self, codec: PlainCodec) -> None:
        """Build the control cycle's packets with `codec` from now on (crane_io.dynamixel.codec)."""
        self._codec = codec
        self._limits_seen = None  # the next goal current write plans for it
        if self._reader is not None:
            self._reader.use_codec(codec)

    def close(self) -> None:
        """Goal current 0 and torque off on every servo that answers, then close the port.
        Idempotent; never raises because of a servo that does not answer."""
        if self._closed:
            return
        self._closed = True
        port = self._port
        if port is None:
            return
        with shutdown.stopping():  # a stop signal meanwhile must not skip a torque-off write
            try:
                if port.is_open:
                    self.safe_stop()
            finally:
                self._link.update_byte_stats()
                try:
                    port.closePort()
                except Exception as exc:  # noqa: BLE001 - closing must not raise
                    log.warning("closing %s: %s", self.port_name, exc)

    def __enter__(self) -> DynamixelBus:
        return self.open()

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()

    def __del__(self):
        if getattr(self, "_port", None) is not None and not getattr(self, "_closed", True):
            warnings.warn(f"DynamixelBus on {self.port_name} was not closed; closing it now "
                          "(use `with DynamixelBus(...)` or call close())", ResourceWarning, stacklevel=2)
            try:
                self.close()
            except Exception:  # noqa: BLE001 - never raise from a finaliser
                pass

    def __repr__(self) -> str:
        state = "open" if self.is_open else ("closed" if self._closed else "not opened")
        return f"DynamixelBus({self.port_name!r}, name={self.name!r}, {state})"


    # ---- torque --------------------------------------------------------------------------------
    def torque_on(self) -> None:
        """Hold the held joints where they are (goal position = present), zero the goal current of the
        current-mode joints, then enable torque on every servo."""
        self._use_compiled_codec()  # before the first write: the servos' torque is still off
        super().torque_on()

    def safe_stop(self) -> dict[str, str]:
        """Goal current 0 on every current-mode servo, then torque off on each servo individually.
        Never raises for a servo that does not answer: returns (and logs) joint -> reason instead."""
        with shutdown.stopping():  # a stop signal meanwhile must not skip a torque-off write
            return self._safe_stop()

    def _safe_stop(self) -> dict[str, str]:
        failures: dict[str, str] = {}
        port = self._port
        if port is None or not port.is_open:
            return failures
        port.is_using = False  # an exception in the middle of a transfer may have left it set
        if self.current_joints:
            for i in self.current_joints:
                self._current_writer.changeParam(self.ids[i], [0] * _GOAL_CURRENT.size)
            link = self._link
            link.retry(link.group_once, self._current_writer.txPacket)  # unconfirmed: torque off follows
        for joint, sid in zip(self.joint_names, self.ids):
            try:
                self._write(sid, "torque_enable", 0, joint)
            except CraneError as exc:
                failures[joint] = str(exc)
            except (serial.SerialException, OSError) as exc:
                failures[joint] = f"port error: {exc}"
                port.is_using = False
        self.torque_enabled = False
        self.stop_failures = failures
        if failures:
            log.warning("%s: torque off not confirmed on %s", self.name, ", ".join(failures))
        return failures


    # ---- the control cycle ---------------------------------------------------------------------
    def read_state(self, *, check_faults: bool = True) -> BusState:
        """Present current, velocity and position of every servo in ONE (fast) sync read.

        Retries within the budget; raises CommunicationError / ServoMissingError when the read finally
        fails, and ServoFaultError when a servo reports a hardware error (unless check_faults=False);
        WatchdogExpiredError when the host paused long enough for the Bus Watchdog to stop servos."""
        self.require_open()
        self._link.last_port_error = ""
        self._check_stall()
        self._why = "no reply"
        reader = self._reader
        state = self._read_state_once(reader, check_faults)  # the first try of `_retry`, without its loop
        if state is not None:
            return state
        self._link.spend_error_budget()
        state = self._link.retry(self._read_state_once, reader, check_faults, budget=True, done=1)
        if state is not None:
            return state
        self.stats.failures += 1
        missing = self._silent_servos()
        if missing:
            raise self._missing_error(missing, "stopped answering", "stopped answering")
        if self._link.last_port_error:
            raise CommunicationError(f"the port {self.port_name} stopped working "
                                     f"({self._link.last_port_error}); is the U2D2 still plugged in?")
        raise CommunicationError(
            f"reading the servos on {self.port_name} failed {1 + self.retries} times in a row ({self._why}); "
            "check the cable, the power and the latency timer")

    def _read_state_once(self, reader: StatusSyncRead, check_faults: bool) -> BusState | None:
        """One try of read_state (for `_retry`): the (fast) sync read, and while fast sync read is
        undecided a plain one right after a failed fast one. None when it failed (why: `_why`)."""
        t = time.monotonic()
        fast = self.stats.fast is not False
        if fast:
            out = np.empty((3, self._n_servos))  # filled by the compiled path (a new one per read)
            result, reply = self._link.transfer(reader.fast_read, out, failed=_NO_FAST_READ)
            if reply is not None:  # the expected reply, no status error, converted into `out`
                if reader._fast_ids == self.ids:  # the usual case: the servos in joint order
                    return self._fast_state(out, t)
                result = reader._take_fast_reply(reply)  # else the general path, from data_dict
        else:
            result = self._link.transfer(reader.txRxPacket)
        if result != COMM_SUCCESS and self.stats.fast is None:
            plain_t = time.monotonic()
            if self._link.transfer(reader.txRxPacket) == COMM_SUCCESS:
                self._fast_miss()
                result, fast, t = COMM_SUCCESS, False, plain_t
        if result == COMM_SUCCESS and any(e & 0x7F for e in reader.errors.values()):
            bad = {s: e for s, e in reader.errors.items() if e & 0x7F}
            self._why = "; ".join(f"ID {s}: {', '.join(decode_status_error(e))}" for s, e in bad.items())
            result = COMM_RX_CORRUPT
        if result == COMM_SUCCESS:
            if fast and self.stats.fast is None:
                self.stats.fast = True
            return self._state_from(reader, t, fast, check_faults)
        if result != COMM_RX_CORRUPT or self._why == "no reply":
            self._why = self._link.reason(result) or str(result)
        return None

    def _fast_miss(self) -> None:
        self._fast_misses += 1
        if self._fast_misses >= _FAST_TRIES_BEFORE_FALLBACK:
            self.stats.fast = False
            self.stats.fallback_note = (
                f"the servos on {self.port_name} did not answer fast sync read while plain sync read "
                "worked; using plain sync read from now on (update the servo firmware to speed up the loop)")
            log.warning("%s: %s", self.name, self.stats.fallback_note)

    def _fast_state(self, out: np.ndarray, t: float) -> BusState:
        """The state of a whole fast reply of the servos in joint order without status errors, which the
        codec converted into `out` (positions, velocities, currents)."""
        stats, port = self.stats, self._port
        if stats.fast is None:
            stats.fast = True
        stats.reads += 1
        stats.bytes_written, stats.bytes_read = port.bytes_written, port.bytes_read
        return BusState(out[0], out[1], out[2], t, True)

    def _state_from(self, reader: StatusSyncRead, t: float, fast: bool, check_faults: bool) -> BusState:
        packet = reader.packet
        if packet is not None and reader._fast_ids == self.ids:  # the fast reply, servos in joint order
            rec = np.frombuffer(packet, dtype=FAST_RECORD, count=len(self.ids), offset=FIRST_PARAM)
            cur, vel, pos = rec["current"].astype(float), rec["velocity"].astype(float), \
                rec["position"].astype(float)
        else:
            data = reader.data_dict
            raw = np.array(self._present_all.unpack(b"".join([data[sid] for sid in self.ids])),
                           dtype=float).reshape(-1, 3)  # (8, 3)
            cur, vel, pos = raw[:, 0], raw[:, 1], raw[:, 2]
        self.stats.reads += 1
        self._link.update_byte_stats()
        if check_faults and any(e & STATUS_ALERT_BIT for e in reader.errors.values()):  # status_alert
            faults = self.read_hardware_errors()
            if faults:
                raise self._fault_error(faults)
        # units.position_to_rad etc., written out (same arithmetic) to skip their asarray calls; columns:
        # Present Current, Velocity, Position
        return BusState(position=(pos - units.POSITION_CENTER) * units.RAD_PER_PULSE,
                        velocity=vel * units.RADS_PER_VELOCITY_LSB,
                        current=cur * units.AMPERE_PER_CURRENT_LSB, t=t, fast=fast)

    def write_goal_current(self, amps) -> np.ndarray:
        """Send the goal current of every current-mode joint in ONE sync write.

        `amps` is (8,) in arm.joints order; entries of position-mode joints are ignored. Values are
        clamped to each servo's Current Limit. Returns the currents actually commanded (A, quantised;
        0 for position-mode joints)."""
        self.require_open()
        limits = self.current_limits.tolist()
        if limits != self._limits_seen:  # configure() read them back, or a caller changed them
            self._plan_currents(limits)
        done = self._codec.goal_current(amps)
        if done is None:  # a wrong shape or a value that is not finite: nothing was sent
            raise self._refusal(amps, "goal current", self.current_joints)
        packet, params, sent = done
        if packet is None:  # it needs byte stuffing: the SDK's way
            for k in range(0, len(params), 3):
                self._current_writer.changeParam(params[k], list(params[k + 1:k + 3]))
            self._send(self._current_writer.txPacket, "goal current")
        else:
            self._send(self._ph.send_broadcast, "goal current", self._port, packet)
        return sent

    def _plan_currents(self, limits: list) -> None:
        """write_goal_current's plan for the Current Limits `limits` (A), given to the codec: per
        current-mode joint its index, servo ID, limit in A and in whole Goal Current steps."""
        lsb = units.AMPERE_PER_CURRENT_LSB
        self._limits_seen = limits
        self._codec.plan_currents([(i, self.ids[i], limits[i], math.floor(limits[i] / lsb + 1e-9))
                                   for i in self.current_joints])

    def write_goal_position(self, rad) -> np.ndarray:
        """Send the goal position of every position-mode (held) joint in ONE sync write, clamped to the
        joint limits. `rad` is (8,); entries of current-mode joints are ignored. Returns what was sent."""
        self.require_open()
        _arr, values = self._command_values(rad, "goal position", self.position_joints)
        sent = [0.0] * len(self.ids)
        if not self.position_joints:  # every joint in current mode: nothing to send (an empty sync write
            return np.array(sent)     # is no packet the servos accept)
        lower, upper = self.lower.tolist(), self.upper.tolist()
        rad_per_pulse, center = units.RAD_PER_PULSE, units.POSITION_CENTER
        params = []
        for i in self.position_joints:
            # scalar form of units.rad_to_position(np.clip(...)) and position_to_rad: the same float
            # operations, the same rounding (half to even)
            raw = round(min(max(values[i], lower[i]), upper[i]) / rad_per_pulse + center)
            sent[i] = (raw - center) * rad_per_pulse
            params += (self.ids[i], *(raw & 0xFFFFFFFF).to_bytes(4, "little"))
        # the packet as the position GroupSyncWrite makes it (see write_goal_current)
        pos = _GOAL_POSITION
        packet = self._ph.sync_write_packet(pos.address, pos.size, params)
        if packet is None:
            for k in range(0, len(params), 5):
                self._position_writer.changeParam(params[k], params[k + 1:k + 5])
            self._send(self._position_writer.txPacket, "goal position")
        else:
            self._send(self._ph.send_broadcast, "goal position", self._port, packet)
        return np.array(sent)

    def _command_values(self, values, what: str, used) -> tuple[np.ndarray, list[float]]:
        """The command as an (8,) float array and as a list; CommandError for a wrong shape or a value
        of a used joint that is not finite."""
        arr = np.asarray(values, dtype=float)
        if arr.shape != (len(self.ids),):
            raise self._refusal(arr, what, used)
        values = arr.tolist()
        isfinite = math.isfinite
        for i in used:
            if not isfinite(values[i]):
                raise self._refusal(arr, what, used)
        return arr, values

    def _refusal(self, values, what: str, used) -> CommandError:
        """Why the command `values` cannot be sent: a wrong shape, or the used joints whose value is not
        finite."""
        arr = np.asarray(values, dtype=float)
        if arr.shape != (len(self.ids),):
            return CommandError(f"{what} needs {len(self.ids)} values in joint order "
                                f"({', '.join(self.joint_names)}), got shape {arr.shape}")
        bad = [self.joint_names[i] for i in used if not math.isfinite(arr[i])]
        return CommandError(f"{what} for {', '.join(bad)} is not a finite number; nothing was sent")

    def _send(self, fn, what: str, *args) -> None:
        """Send a sync write: `fn(*args)` (a GroupSyncWrite's txPacket, or the packet handler's
        send_broadcast of a finished packet), retried within the error budget."""
        self._check_stall()
        if self._link.group_once(fn, *args):  # the first try of `_retry`, without its loop
            self.stats.writes += 1
            return
        self._link.spend_error_budget()
        if self._link.retry(self._link.group_once, fn, *args, budget=True, done=1):
            self.stats.writes += 1
            return
        self.stats.failures += 1
        raise CommunicationError(f"sending the {what} on {self.port_name} failed {1 + self.retries} times")

    def _check_stall(self) -> None:
        """After a pause longer than half the watchdog time, confirm the servos are still running. The
        pause is measured on the servos' clock (`Link.now`): simulated time for a lockstep simulated chain."""
        wd = self.watchdog_s
        if wd and self.torque_enabled:
            gap = self._link.paused_longer_than(_STALL_FRACTION * wd)
            if gap is not None:
                self._raise_if_expired(self.read_hardware_errors(), gap)
