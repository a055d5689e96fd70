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
"""

from __future__ import annotations

import collections
import logging
import math
import struct
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import serial
from dynamixel_sdk import (
    COMM_RX_CORRUPT,
    COMM_SUCCESS,
    COMM_TX_FAIL,
    GroupSyncRead,
    GroupSyncWrite,
)
from dynamixel_sdk.protocol2_packet_handler import INST_FAST_SYNC_READ, RXPACKET_MAX_LEN
from dynamixel_sdk.robotis_def import BROADCAST_ID, COMM_RX_TIMEOUT

from crane_io import shutdown
from crane_io.description import ArmDescription, default_arm
from crane_io.dynamixel import cycle_kernel, units
from crane_io.dynamixel.control_table import (
    MODE_CURRENT,
    MODE_POSITION,
    PRESENT_BLOCK_ADDRESS,
    PRESENT_BLOCK_SIZE,
    X_SERIES,
    ServoModel,
    model_by_number,
    span,
)
from crane_io.dynamixel.faults import (
    STATUS_ALERT_BIT,
    WATCHDOG_EXPIRED,
    CommunicationError,
    ConfigurationMismatchError,
    ServoFaultError,
    ServoMissingError,
    ServoRejectedError,
    WatchdogExpiredError,
    WrongModelError,
    decode_hardware_error,
    decode_status_error,
    describe_faults,
    servo_label,
)
from crane_io.dynamixel.packets import CranePacketHandler, crc16
from crane_io.dynamixel.port import CranePortHandler, open_port
from crane_io.dynamixel.servo_report import servo_report as _servo_report
from crane_io.errors import ConfigError, CraneError

log = logging.getLogger(__name__)

_PKT_RESERVED, _PKT_ID, _PKT_LEN_L, _PKT_INSTRUCTION = 3, 4, 5, 7  # as in dynamixel-sdk's protocol 2 handler
_STUFFED = b"\xff\xff\xfd\xfd"  # a stuffed FF FF FD in a packet
_PKT_FIRST_PARAM = 8  # fast sync read: the first servo's error byte
_FAST_TRIES_BEFORE_FALLBACK = 2
_PRESENT = struct.Struct("<hii")  # Present Current, Velocity, Position (addresses 126, 128, 132)
assert _PRESENT.size == PRESENT_BLOCK_SIZE
# one servo's part of the Fast Sync Read reply of the Present block: ERR ID DATA CRC
_FAST_RECORD = np.dtype([("error", "u1"), ("id", "u1"), ("current", "<i2"), ("velocity", "<i4"),
                         ("position", "<i4"), ("crc", "<u2")])
assert _FAST_RECORD.itemsize == PRESENT_BLOCK_SIZE + 4
_GOAL_CURRENT, _GOAL_POSITION = X_SERIES["goal_current"], X_SERIES["goal_position"]  # the goal sync writes
# the hardware-error poll: ONE sync read of Hardware Error Status (70) .. Bus Watchdog (98); offsets in it
_POLL_ADDRESS, _POLL_SIZE = span("hardware_error_status", "bus_watchdog")
_POLL_ERRORS = X_SERIES["hardware_error_status"].address - _POLL_ADDRESS
_POLL_WATCHDOG = X_SERIES["bus_watchdog"].address - _POLL_ADDRESS
# what a transfer whose port failed returns, in the shape of the SDK call: a result code, (data or
# model number, result, error), (result, error)
_NO_READ, _NO_WRITE = (None, COMM_TX_FAIL, 0), (COMM_TX_FAIL, 0)
_NO_FAST_READ = (COMM_TX_FAIL, None)  # ... and of the reader's fast_read
_STALL_FRACTION = 0.5  # a pause longer than this share of the watchdog time makes the bus check it


class CommandError(CraneError):
    """A command array that cannot be sent (wrong shape, NaN or infinite values)."""


@dataclass(frozen=True)
class ServoInfo:
    servo_id: int
    joint: str
    model_number: int
    model: str
    firmware: int


@dataclass(slots=True)
class BusState:
    """One synchronous snapshot of every servo, SI units, (8,) arrays in arm.joints order."""

    position: np.ndarray  # rad
    velocity: np.ndarray  # rad/s
    current: np.ndarray  # A (Present Current)
    t: float  # time.monotonic() when the read was sent
    fast: bool  # True when it came from a fast sync read


@dataclass
class BusStats:
    reads: int = 0  # read_state calls that returned data
    writes: int = 0  # goal sync writes sent
    attempts: int = 0  # transfers tried (including retries)
    retries: int = 0  # transfers repeated after a missing or corrupted reply
    failures: int = 0  # calls that finally raised CommunicationError
    fast: bool | None = None  # fast sync read in use (None: not decided yet)
    fallback_note: str | None = None
    bytes_written: int = 0
    bytes_read: int = 0
    recent_errors: collections.deque = field(default_factory=collections.deque, repr=False)

    def as_dict(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "recent_errors"}


class _StatusSyncRead(GroupSyncRead):
    """GroupSyncRead that keeps every servo's status error byte and removes byte stuffing from fast
    sync read replies (the SDK parses the stuffed packet, which shifts the data when a reading happens
    to contain FF FF FD)."""

    def __init__(self, port, ph, start_address, data_length):
        super().__init__(port, ph, start_address, data_length)
        self.errors: dict[int, int] = {}
        self.packet: bytes | None = None  # the latest fast reply when it took the fast path (else None)
        self._fast_head: bytes | None = None  # the expected fast reply's first 8 bytes, its length, IDs
        self._fast_total = 0
        self._fast_ids: tuple = ()
        self._fast_id_bytes: bytes | None = None
        self._no_errors = b""  # the error bytes of a reply without errors
        self._zero_errors: dict[int, int] = {}  # ... and its `errors`
        self._request: bytes | None = None  # fast_read's kept Fast Sync Read packet, for `param`
        self._request_param: list | None = None
        # fast_read(out): the compiled check and conversion of the Present block's reply (`use_kernel`)
        self._kernel = None
        self._kernel_args: tuple = ()
        self._head_array: np.ndarray | None = None  # _fast_head and _fast_id_bytes as arrays, for it
        self._id_array: np.ndarray | None = None
        self.decoded = False  # the latest fast_read(out) filled `out`

    def rxPacket(self):  # noqa: N802 (SDK name)
        self.last_result = False
        self.errors = {}
        self.packet = None
        for dxl_id in self.data_dict:
            data, result, error = self.ph.readRx(self.port, dxl_id, self.data_length)
            if result != COMM_SUCCESS:
                return result
            if len(data) != self.data_length:
                return COMM_RX_CORRUPT
            self.data_dict[dxl_id] = bytearray(data)
            self.errors[dxl_id] = error
        self.last_result = True
        return COMM_SUCCESS

    def fastSyncReadRxPacket(self):  # noqa: N802
        self.last_result = False
        self.errors = {}
        self.packet = None
        self._expect_fast_reply()
        return self._take_fast_reply(self.port.readPort(self._fast_total))

    def _expect_fast_reply(self) -> None:
        """The expected fast reply's first 8 bytes, length and servo IDs for the servos of data_dict."""
        count = len(self.data_dict)
        total = 8 + (self.data_length + 4) * count  # header, ID, LEN, INST, then ERR ID DATA CRC per servo
        if self._fast_head is None or self._fast_total != total or self._fast_ids != tuple(self.data_dict):
            length = total - 7
            self._fast_head = bytes((0xFF, 0xFF, 0xFD, 0x00, BROADCAST_ID, length & 0xFF, length >> 8, 0x55))
            self._fast_total = total
            self._fast_ids = tuple(self.data_dict)
            self._fast_id_bytes = bytes(self._fast_ids) if all(i < 256 for i in self._fast_ids) else None
            self._no_errors = bytes(count)
            self._zero_errors = dict.fromkeys(self._fast_ids, 0)
            self._head_array = np.frombuffer(self._fast_head, dtype=np.uint8)
            ok = self._fast_id_bytes is not None and self.data_length == PRESENT_BLOCK_SIZE
            self._id_array = np.frombuffer(self._fast_id_bytes, dtype=np.uint8) if ok else None

    def use_kernel(self, kernel, *args) -> None:
        """Let fast_read(out) check the reply and convert it into `out` in one compiled call,
        `kernel(reply, head, ids, out, *args)` (cycle_kernel.present_reply_state: the Present block only)."""
        self._kernel = kernel
        self._kernel_args = args

    def fast_read(self, out: np.ndarray | None = None) -> tuple[int, bytes | None]:
        """fastSyncRead for the control cycle, the same bytes on the wire: (result, reply). `reply` is the
        whole fast reply when it is the expected one with every status error byte 0 (the usual case);
        then only `packet` and `errors` are updated (not data_dict: the reply holds the data). Otherwise
        `reply` is None and the reader is left exactly as fastSyncRead leaves it. With `out` ((3, n)
        floats) and a kernel (`use_kernel`), an accepted reply is also converted into `out` (positions,
        velocities, currents in the servos' request order) and `decoded` is set."""
        self.decoded = False
        request = self._request
        if request is None or self.is_param_changed or self.param is not self._request_param:
            # first call, or other servos: the SDK's way (its packet handler keeps the packet)
            result = self.fastSyncRead()
            self._request_param = self.param
            self._request = self.ph.sync_read_packet(INST_FAST_SYNC_READ, self.start_address,
                                                     self.data_length, self.param)
            self._expect_fast_reply()
            return result, None
        port = self.port
        result = self.ph.send_packet(port, request)  # as syncReadTx sends it
        if result != COMM_SUCCESS:
            return result, None
        port.setPacketTimeout((11 + self.data_length) * len(self.param))
        self.last_result = False
        self.errors = {}
        self.packet = None
        total = self._fast_total
        data = port.readPort(total)
        kernel, ids = self._kernel, self._id_array
        if out is not None and kernel is not None and ids is not None and type(data) is bytes:
            # the same checks as below, and the conversion, compiled
            if kernel(data, self._head_array, ids, out, *self._kernel_args):
                port.is_using = False
                self.packet = data
                self.errors = self._zero_errors
                self.last_result = True
                self.decoded = True
                return COMM_SUCCESS, data
            return self._take_fast_reply(data), None
        chunk = self.data_length + 4
        if (len(data) == total and data.startswith(self._fast_head) and _STUFFED not in data
                and data[8::chunk] == self._no_errors
                and crc16(data[:-2]) == (data[-2] | (data[-1] << 8))
                and data[9::chunk] == self._fast_id_bytes):
            port.is_using = False
            self.packet = data
            self.errors = self._zero_errors  # shared: `errors` is always replaced, never changed in place
            self.last_result = True
            return COMM_SUCCESS, data
        return self._take_fast_reply(data), None

    def _take_fast_reply(self, data: bytes) -> int:
        """fastSyncReadRxPacket with the first `_fast_total` bytes already read."""
        port, n = self.port, self.data_length
        chunk = n + 4
        total = self._fast_total
        # fast path: the one expected reply read whole, as dynamixel-sdk's rxPacket would accept it (its
        # header at the start, its CRC right, no byte stuffing, the servos in request order); anything
        # else goes through rxPacket's own loop with the bytes already read (`_rx_packet`)
        if (len(data) == total and data.startswith(self._fast_head) and _STUFFED not in data
                and crc16(data[:-2]) == (data[-2] | (data[-1] << 8))
                and data[9::chunk] == self._fast_id_bytes):
            port.is_using = False
            self.packet = data
            ids = self._fast_ids
            self.errors = dict(zip(ids, data[8::chunk]))
            dd = self.data_dict
            for k, dxl_id in enumerate(ids):
                start = 10 + k * chunk
                dd[dxl_id] = bytearray(data[start:start + n])
            self.last_result = True
            return COMM_SUCCESS
        packet, result = _rx_packet(self.ph, port, data)
        if result != COMM_SUCCESS:
            return result
        return self.take_fast_packet(packet)

    def take_fast_packet(self, packet: list) -> int:
        """Take the blocks of a Fast Sync Read status packet as rxPacket returned it (a list of bytes,
        possibly stuffed): COMM_SUCCESS, or COMM_RX_CORRUPT for a packet not addressed to the broadcast
        ID, of the wrong length, or with an unknown or repeated servo ID."""
        if packet[_PKT_ID] != BROADCAST_ID:
            return COMM_RX_CORRUPT
        packet = self.ph.removeStuffing(packet)  # rxPacket's own list: unstuffed in place
        length = packet[5] | (packet[6] << 8)
        body = bytes(packet[_PKT_FIRST_PARAM: 7 + length])  # [ERR ID DATA.. CRC CRC] per servo
        n = self.data_length
        chunk = n + 4
        if len(body) != chunk * len(self.data_dict):
            return COMM_RX_CORRUPT
        seen = {}
        for k in range(0, len(body), chunk):
            dxl_id = body[k + 1]
            if dxl_id not in self.data_dict or dxl_id in seen:
                return COMM_RX_CORRUPT
            seen[dxl_id] = (bytearray(body[k + 2:k + 2 + n]), body[k])
        for dxl_id, (data, error) in seen.items():
            self.data_dict[dxl_id] = data
            self.errors[dxl_id] = error
        self.last_result = True
        return COMM_SUCCESS


def _rx_packet(ph, port, prefix=b""):
    """dynamixel-sdk's Protocol2PacketHandler.rxPacket(port, fast_option=True), step for step, starting
    with the bytes `prefix` already read from the port (the fast path's read). The SDK reads in pieces
    (11 bytes, then the rest of the packet); the bytes it sees, and so its verdict, are the same: only
    reads that would ask for no byte are skipped."""
    rxpacket = list(prefix)
    packet_id = BROADCAST_ID
    result = COMM_TX_FAIL
    rx_length = len(rxpacket)
    wait_length = 11  # minimum length (HEADER0..2 RESERVED ID LENGTH_L LENGTH_H INST ERROR CRC16_L CRC16_H)
    while True:
        if wait_length > rx_length:
            rxpacket.extend(port.readPort(wait_length - rx_length))
            rx_length = len(rxpacket)
        if rx_length >= wait_length:
            for idx in range(0, (rx_length - 3)):  # find the packet header
                if (rxpacket[idx] == 0xFF and rxpacket[idx + 1] == 0xFF and rxpacket[idx + 2] == 0xFD
                        and rxpacket[idx + 3] != 0xFD):
                    break
            if idx == 0:
                length = rxpacket[_PKT_LEN_L] | (rxpacket[_PKT_LEN_L + 1] << 8)
                if (rxpacket[_PKT_RESERVED] != 0x00 or rxpacket[_PKT_ID] > packet_id
                        or length > RXPACKET_MAX_LEN or rxpacket[_PKT_INSTRUCTION] != 0x55):
                    del rxpacket[0]  # remove the first byte in the packet
                    rx_length -= 1
                    continue
                if wait_length != length + _PKT_LEN_L + 2:
                    wait_length = length + _PKT_LEN_L + 2
                    continue
                if rx_length < wait_length:
                    if port.isPacketTimeout():
                        result = COMM_RX_TIMEOUT if rx_length == 0 else COMM_RX_CORRUPT
                        break
                    continue
                crc = rxpacket[wait_length - 2] | (rxpacket[wait_length - 1] << 8)
                ok = ph.updateCRC(0, rxpacket, wait_length - 2) == crc
                result = COMM_SUCCESS if ok else COMM_RX_CORRUPT
                break
            del rxpacket[0:idx]  # remove unnecessary packets
            rx_length -= idx
        elif port.isPacketTimeout():
            result = COMM_RX_TIMEOUT if rx_length == 0 else COMM_RX_CORRUPT
            break
    port.is_using = False
    return rxpacket, result


class DynamixelBus:
    """The CRANE-X7 servo chain behind one port (a U2D2 device path, a pty or `dxlsim://NAME`)."""

    def __init__(self, port: str, arm: ArmDescription | None = None, *, name: str = "arm", retries: int = 2,
                 error_budget: int = 50, latency_ms: float | None = None, fast_sync_read: bool = True):
        if retries < 0:
            raise ConfigError(f"retries must be 0 or more, got {retries}")
        if error_budget < 1:
            raise ConfigError(f"error_budget must be at least 1, got {error_budget}")
        self.port_name = str(port)
        self.arm = arm if arm is not None else default_arm()
        self.name = name
        self.retries = int(retries)
        self.error_budget = int(error_budget)  # failed transfers tolerated in any 1 s window
        self.error_window_s = 1.0
        self.latency_ms = latency_ms
        self.stats = BusStats(fast=None if fast_sync_read else False)
        self.servos: dict[str, ServoInfo] = {}
        self.stop_failures: dict[str, str] = {}
        self.torque_enabled = False
        self.watchdog_s: float | None = None  # the Bus Watchdog armed by configure (None: off)

        joints = self.arm.joints
        self.joint_names = tuple(j.name for j in joints)
        self.ids = tuple(j.servo_id for j in joints)
        self.modes = np.array([MODE_CURRENT if j.name in self.arm.bilateral_joints else MODE_POSITION
                               for j in joints])
        self.current_joints = tuple(i for i, m in enumerate(self.modes) if m == MODE_CURRENT)
        self.position_joints = tuple(i for i, m in enumerate(self.modes) if m == MODE_POSITION)
        self.current_limits = np.array([j.current_limit for j in joints])  # A; read back in configure
        self.lower = np.array([j.lower for j in joints])
        self._present_all = struct.Struct("<" + _PRESENT.format.lstrip("<") * len(self.ids))  # every servo's
        self._n_servos = len(self.ids)
        self._limits_seen: list | None = None  # current_limits as write_goal_current last saw them
        self._current_plan: list[tuple] = []  # ... per current-mode joint (see write_goal_current)
        self._kernels: tuple | None = None  # crane_io.dynamixel.cycle_kernel.compiled(), when the bus opens
        self._current_kernel = None  # its goal_current_packet when the current-mode joints suit it ...
        self._current_args: tuple = ()  # ... and its arguments after the amps, from the plan
        self._sent_size = 0  # the kernel's packet length
        self.upper = np.array([j.upper for j in joints])

        self._ph = CranePacketHandler()
        self._port: CranePortHandler | None = None
        self._reader: _StatusSyncRead | None = None
        self._current_writer: GroupSyncWrite | None = None
        self._position_writer: GroupSyncWrite | None = None
        self._closed = False
        self._fast_misses = 0
        self._last_port_error = ""
        self._last_result = COMM_SUCCESS  # the SDK result of the latest failed try (for messages)
        self._why = "no reply"  # read_state: why the latest try failed
        self._poll_reader: _StatusSyncRead | None = None
        self._last_tx: float | None = None  # self._now() of the latest transfer
        self._checked_now: float | None = None  # self._now() of a stall check, for the transfer after it
        # the clock the stall check measures pauses with: the servos' own notion of time. Real servos
        # (and wall-clock simulated ones) live in real time; a lockstep simulated chain only advances
        # with the goal writes, so there a host pause cannot stop a servo and costs no extra read.
        self._now = time.monotonic

    # ---- life cycle ----------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return self._port is not None and self._port.is_open

    def open(self) -> DynamixelBus:
        """Open the port at the arm's baud rate (3 Mbps). Raises HardwareError with the reason."""
        if self.is_open:
            return self
        if self._closed:
            raise CommunicationError(f"the bus on {self.port_name} was closed; make a new DynamixelBus")
        self._port = open_port(self.port_name, self.arm.baudrate, latency_ms=self.latency_ms)
        self._now = getattr(self._port.ser, "servo_time", None) or time.monotonic
        self._reader = _StatusSyncRead(self._port, self._ph, PRESENT_BLOCK_ADDRESS, PRESENT_BLOCK_SIZE)
        for sid in self.ids:
            self._reader.addParam(sid)
        cur, pos = _GOAL_CURRENT, _GOAL_POSITION
        self._current_writer = GroupSyncWrite(self._port, self._ph, cur.address, cur.size)
        for i in self.current_joints:
            self._current_writer.addParam(self.ids[i], [0] * cur.size)
        self._position_writer = GroupSyncWrite(self._port, self._ph, pos.address, pos.size)
        for i in self.position_joints:
            self._position_writer.addParam(self.ids[i], [0] * pos.size)
        self._poll_reader = _StatusSyncRead(self._port, self._ph, _POLL_ADDRESS, _POLL_SIZE)
        for sid in self.ids:
            self._poll_reader.addParam(sid)
        return self

    def _use_kernels(self) -> None:
        """The control cycle's compiled calls (crane_io.dynamixel.cycle_kernel), compiled or loaded from
        numba's cache now, between transfers (never while a reply is awaited); without numba the bus keeps
        its Python paths. Done by torque_on: a bus that never drives the arm (check, ping) needs no numba."""
        if self._kernels is not None or self._reader is None:
            return
        kernels = cycle_kernel.compiled()
        self._kernels = kernels
        self._limits_seen = None  # the next goal current write plans for the kernel
        if kernels is not None:
            self._reader.use_kernel(kernels[1], float(units.POSITION_CENTER), units.RAD_PER_PULSE,
                                    units.RADS_PER_VELOCITY_LSB, units.AMPERE_PER_CURRENT_LSB,
                                    cycle_kernel.TABLE)

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
                self._update_byte_stats()
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

    # ---- discovery and set-up ------------------------------------------------------------------
    def ping_all(self) -> dict[int, ServoInfo]:
        """Ping every servo of the arm and check its model number.
        Raises ServoMissingError (naming joint, ID and port) or WrongModelError."""
        self._need_port()
        missing = {}
        found = {}
        for joint, sid in zip(self.joint_names, self.ids):
            number = self._ping(sid)
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
        self._need_port()
        watchdog_raw = 0
        if watchdog_s:
            if not 0.02 <= watchdog_s <= 127 * units.SECONDS_PER_WATCHDOG_LSB:
                raise ConfigError(f"watchdog_s must be between 0.02 and 2.54 s (or 0 to disable), "
                                  f"got {watchdog_s}")
            watchdog_raw = units.seconds_to_watchdog(watchdog_s)
        limits_raw = self._current_limit_raw(current_limits)
        self.torque_off()
        for j, (joint, sid) in enumerate(zip(self.joint_names, self.ids)):
            self._write(sid, "return_delay_time", 0, joint)
            drive = self._read(sid, "drive_mode", joint)
            if drive & 1:
                self._write(sid, "drive_mode", drive & ~1, joint)
            if self._read(sid, "operating_mode", joint) != self.modes[j]:
                self._write(sid, "operating_mode", int(self.modes[j]), joint)
            if limits_raw[j] is not None:
                self._write(sid, "current_limit", limits_raw[j], joint)
            self._write(sid, "bus_watchdog", 0, joint)  # clears a latched watchdog error too
            if watchdog_raw:
                self._write(sid, "bus_watchdog", watchdog_raw, joint)
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
        self.watchdog_s = float(units.watchdog_to_seconds(watchdog_raw)) if watchdog_raw else None

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

    # ---- torque --------------------------------------------------------------------------------
    def torque_on(self) -> None:
        """Hold the held joints where they are (goal position = present), zero the goal current of the
        current-mode joints, then enable torque on every servo."""
        self._need_port()
        self._use_kernels()  # before the first write: the servos' torque is still off
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
        self._need_port()
        for joint, sid in zip(self.joint_names, self.ids):
            self._write(sid, "torque_enable", 0, joint)
        self.torque_enabled = False

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
            self._retry(self._group_once, self._current_writer.txPacket)  # unconfirmed: torque off follows
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
        self._need_port()
        self._last_port_error = ""
        self._check_stall()
        self._why = "no reply"
        reader = self._reader
        state = self._read_state_once(reader, check_faults)  # the first try of `_retry`, without its loop
        if state is not None:
            return state
        self._spend_error_budget()
        state = self._retry(self._read_state_once, reader, check_faults, budget=True, done=1)
        if state is not None:
            return state
        self.stats.failures += 1
        missing = self._silent_servos()
        if missing:
            raise self._missing_error(missing, "stopped answering", "stopped answering")
        if self._last_port_error:
            raise CommunicationError(f"the port {self.port_name} stopped working ({self._last_port_error}); "
                                     "is the U2D2 still plugged in?")
        raise CommunicationError(
            f"reading the servos on {self.port_name} failed {1 + self.retries} times in a row ({self._why}); "
            "check the cable, the power and the latency timer")

    def _read_state_once(self, reader: _StatusSyncRead, check_faults: bool) -> BusState | None:
        """One try of read_state (for `_retry`): the (fast) sync read, and while fast sync read is
        undecided a plain one right after a failed fast one. None when it failed (why: `_why`)."""
        t = time.monotonic()
        fast = self.stats.fast is not False
        if fast:
            out = np.empty((3, self._n_servos))  # filled by the compiled path (a new one per read)
            result, reply = self._transfer(reader.fast_read, out, failed=_NO_FAST_READ)
            if reply is not None:  # the expected reply, no status error
                if reader._fast_ids == self.ids:  # the usual case: the servos in joint order
                    if self.stats.fast is None:
                        self.stats.fast = True
                    if reader.decoded:
                        stats, port = self.stats, self._port
                        stats.reads += 1
                        stats.bytes_written, stats.bytes_read = port.bytes_written, port.bytes_read
                        return BusState(out[0], out[1], out[2], t, True)
                    return self._state_from_reply(reply, t)
                result = reader._take_fast_reply(reply)  # else the general path, from data_dict
        else:
            result = self._transfer(reader.txRxPacket)
        if result != COMM_SUCCESS and self.stats.fast is None:
            plain_t = time.monotonic()
            if self._transfer(reader.txRxPacket) == COMM_SUCCESS:
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
            self._why = self._reason(result) or str(result)
        return None

    def _fast_miss(self) -> None:
        self._fast_misses += 1
        if self._fast_misses >= _FAST_TRIES_BEFORE_FALLBACK:
            self.stats.fast = False
            self.stats.fallback_note = (
                f"the servos on {self.port_name} did not answer fast sync read while plain sync read "
                "worked; using plain sync read from now on (update the servo firmware to speed up the loop)")
            log.warning("%s: %s", self.name, self.stats.fallback_note)

    def _state_from_reply(self, reply: bytes, t: float) -> BusState:
        """`_state_from` for a whole fast reply of the servos in joint order without status errors."""
        rec = np.frombuffer(reply, dtype=_FAST_RECORD, count=self._n_servos, offset=_PKT_FIRST_PARAM)
        self.stats.reads += 1
        port = self._port
        self.stats.bytes_written, self.stats.bytes_read = port.bytes_written, port.bytes_read
        # the arithmetic of units.position_to_rad etc. (integers converted to float, then scaled)
        return BusState((rec["position"] - float(units.POSITION_CENTER)) * units.RAD_PER_PULSE,
                        rec["velocity"] * units.RADS_PER_VELOCITY_LSB,
                        rec["current"] * units.AMPERE_PER_CURRENT_LSB, t, True)

    def _state_from(self, reader: _StatusSyncRead, t: float, fast: bool, check_faults: bool) -> BusState:
        packet = reader.packet
        if packet is not None and reader._fast_ids == self.ids:  # the fast reply, servos in joint order
            rec = np.frombuffer(packet, dtype=_FAST_RECORD, count=len(self.ids), offset=_PKT_FIRST_PARAM)
            cur, vel, pos = rec["current"].astype(float), rec["velocity"].astype(float), \
                rec["position"].astype(float)
        else:
            data = reader.data_dict
            raw = np.array(self._present_all.unpack(b"".join([data[sid] for sid in self.ids])),
                           dtype=float).reshape(-1, 3)  # (8, 3)
            cur, vel, pos = raw[:, 0], raw[:, 1], raw[:, 2]
        self.stats.reads += 1
        self._update_byte_stats()
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
        self._need_port()
        limits = self.current_limits.tolist()
        if limits != self._limits_seen:  # configure() read them back, or a caller changed them
            self._plan_currents(limits)
        kernel = self._current_kernel
        if kernel is not None:
            arr = np.ascontiguousarray(amps, dtype=float)
            if arr.shape == (self._n_servos,):
                sent = np.zeros(self._n_servos)
                size = kernel(arr, *self._current_args, sent, cycle_kernel.TABLE)
                if size > 0:  # the packet, as the Python path below builds it
                    packet = self._current_args[-1].tobytes()
                    self._send(self._ph.send_broadcast, "goal current", self._port, packet)
                    return sent
            # a wrong shape or a value that is not finite (raised below), a packet to stuff (sent below)
        _arr, values = self._command_values(amps, "goal current", self.current_joints)
        lsb = units.AMPERE_PER_CURRENT_LSB
        sent = [0.0] * len(self.ids)
        params = []
        for i, sid, lim, lim_raw in self._current_plan:
            # scalar form of units.ampere_to_current(np.clip(...)): same rounding (half to even)
            raw = round(min(max(values[i], -lim), lim) / lsb)
            raw = max(-lim_raw, min(lim_raw, raw))
            sent[i] = raw * lsb
            params += (sid, raw & 0xFF, (raw >> 8) & 0xFF)
        # the Sync Write packet as GroupSyncWrite + CranePacketHandler make it, built here directly (a kept
        # header, the parameters, the CRC); a packet that needs byte stuffing goes the SDK's way
        cur = _GOAL_CURRENT
        packet = self._ph.sync_write_packet(cur.address, cur.size, params) if params else None
        if packet is None:
            for k in range(0, len(params), 3):
                self._current_writer.changeParam(params[k], params[k + 1:k + 3])
            self._send(self._current_writer.txPacket, "goal current")
        else:
            self._send(self._ph.send_broadcast, "goal current", self._port, packet)
        return np.array(sent)

    def _plan_currents(self, limits: list) -> None:
        """write_goal_current's per-joint plan for the Current Limits `limits` (A), and its kernel's
        arguments: the current-mode joints, their IDs, limits in A and in whole Goal Current steps, and the
        packet with its header in place (crane_io.dynamixel.cycle_kernel)."""
        lsb = units.AMPERE_PER_CURRENT_LSB
        self._limits_seen = limits
        # per current-mode joint: index, servo ID, limit in A and in Goal Current steps
        self._current_plan = plan = [(i, self.ids[i], limits[i], math.floor(limits[i] / lsb + 1e-9))
                                     for i in self.current_joints]
        self._current_kernel = None
        if self._kernels is None or not plan or any(sid > 0xFF for _i, sid, _l, _r in plan):
            return
        head = self._ph.sync_write_header(_GOAL_CURRENT.address, _GOAL_CURRENT.size, 3 * len(plan))
        buf = np.zeros(len(head) + 3 * len(plan) + 2, dtype=np.uint8)
        buf[:len(head)] = np.frombuffer(head, dtype=np.uint8)
        column = [np.array(c) for c in zip(*plan)]
        self._current_args = (column[0].astype(np.int64), column[1].astype(np.int64),
                              column[2].astype(float), column[3].astype(np.int64), lsb, buf)
        self._current_kernel = self._kernels[0]

    def write_goal_position(self, rad) -> np.ndarray:
        """Send the goal position of every position-mode (held) joint in ONE sync write, clamped to the
        joint limits. `rad` is (8,); entries of current-mode joints are ignored. Returns what was sent."""
        self._need_port()
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

    def _command_array(self, values, what: str, used) -> np.ndarray:
        return self._command_values(values, what, used)[0]

    def _command_values(self, values, what: str, used) -> tuple[np.ndarray, list[float]]:
        """The command as an (8,) float array and as a list; CommandError for a wrong shape or a value
        of a used joint that is not finite."""
        arr = np.asarray(values, dtype=float)
        if arr.shape != (len(self.ids),):
            raise CommandError(f"{what} needs {len(self.ids)} values in joint order "
                               f"({', '.join(self.joint_names)}), got shape {arr.shape}")
        values = arr.tolist()
        isfinite = math.isfinite
        for i in used:
            if not isfinite(values[i]):
                bad = [self.joint_names[i] for i in used if not isfinite(values[i])]
                raise CommandError(f"{what} for {', '.join(bad)} is not a finite number; nothing was sent")
        return arr, values

    def _send(self, fn, what: str, *args) -> None:
        """Send a sync write: `fn(*args)` (a GroupSyncWrite's txPacket, or the packet handler's
        send_broadcast of a finished packet), retried within the error budget."""
        self._check_stall()
        if self._group_once(fn, *args):  # the first try of `_retry`, without its loop
            self.stats.writes += 1
            return
        self._spend_error_budget()
        if self._retry(self._group_once, fn, *args, budget=True, done=1):
            self.stats.writes += 1
            return
        self.stats.failures += 1
        raise CommunicationError(f"sending the {what} on {self.port_name} failed {1 + self.retries} times")

    # ---- diagnostics ---------------------------------------------------------------------------
    def read_hardware_errors(self) -> dict[str, list[str]]:
        """Joint -> named faults, for the joints that have any: the Hardware Error Status bits
        (overload, overheating, ...) and "bus watchdog expired" (Bus Watchdog reads -1). ONE sync
        read of addresses 70..98 of every servo; when that fails, servo by servo, and a servo that
        does not answer is listed as ['not answering']."""
        self._need_port()
        reader = self._poll_reader
        if self._retry(self._group_once, reader.txRxPacket):
            blocks = {sid: bytes(reader.data_dict[sid]) for sid in self.ids}
        else:
            blocks = {}
            for joint, sid in zip(self.joint_names, self.ids):
                try:
                    blocks[sid] = self._read_block(sid, _POLL_ADDRESS, _POLL_SIZE, joint)
                except CommunicationError:
                    blocks[sid] = None
        self._update_byte_stats()
        faults = {}
        for joint, sid in zip(self.joint_names, self.ids):
            block = blocks[sid]
            if block is None:
                faults[joint] = ["not answering"]
                continue
            names = decode_hardware_error(block[_POLL_ERRORS])
            if block[_POLL_WATCHDOG] == 0xFF:  # Bus Watchdog = -1: expired
                names.append(WATCHDOG_EXPIRED)
            if names:
                faults[joint] = names
        return faults

    def check_watchdog(self) -> None:
        """Raise WatchdogExpiredError if the Bus Watchdog stopped any servo (one sync read)."""
        faults = self.read_hardware_errors()
        expired = {j: [WATCHDOG_EXPIRED] for j, f in faults.items() if WATCHDOG_EXPIRED in f}
        if expired:
            raise self._fault_error(expired)

    def _check_stall(self) -> None:
        """After a pause longer than half the watchdog time, confirm the servos are still running. The
        pause is measured on the servos' clock (`_now`): simulated time for a lockstep simulated chain."""
        wd, last = self.watchdog_s, self._last_tx
        if wd and self.torque_enabled and last is not None:
            now = self._now()
            gap = now - last
            if gap > _STALL_FRACTION * wd:
                faults = self.read_hardware_errors()
                expired = {j: [WATCHDOG_EXPIRED] for j, f in faults.items() if WATCHDOG_EXPIRED in f}
                if expired:
                    raise self._fault_error(expired, gap)
            else:  # the transfer that follows is stamped with this time (nothing happened in between)
                self._checked_now = now

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
        return ServoFaultError(
            f"hardware error on {self.port_name}: {where}"
            "; the servo switched its torque off (remove the cause, then power-cycle or reboot it)",
            faults=faults)

    def servo_report(self, late_listen_s: float = 0.0) -> list[dict]:
        """`crane_io.dynamixel.servo_report.servo_report(self, late_listen_s)`: one dict per servo for
        `crane-collect check` and the stop's torque read-back (see there)."""
        return _servo_report(self, late_listen_s)

    # ---- low level: the one transfer wrapper and the one retry loop ------------------------------
    def _need_port(self) -> CranePortHandler:
        if self._port is None or not self._port.is_open:
            if self._closed:
                raise CommunicationError(f"the bus on {self.port_name} is closed")
            raise CommunicationError(f"the bus on {self.port_name} is not open; call open() or use `with`")
        return self._port

    def _transfer(self, fn, *args, failed=COMM_TX_FAIL):
        """Run one SDK transfer `fn(*args)`, counted in stats.attempts and time-stamped for the stall
        check. A serial-level exception (the port itself failed) makes it a failed transfer: it returns
        `failed` (shaped like fn's own result) and the port's reason is kept for the message."""
        self.stats.attempts += 1
        now = self._checked_now
        if now is None:
            now = self._now()
        else:
            self._checked_now = None
        self._last_tx = now
        try:
            return fn(*args)
        except (serial.SerialException, OSError) as exc:
            self._port.is_using = False
            self._last_port_error = str(exc)
            return failed

    def _retry(self, attempt, *args, budget: bool = False, tries: int | None = None, done: int = 0):
        """THE retry loop of the bus: every transfer that is repeated on a missing or corrupted reply
        goes through here. `attempt(*args)` makes one try (through `_transfer`) and returns what it got,
        or None when it failed. At most `tries` (default 1 + retries) tries; each repeat counts in
        stats.retries; with `budget` (the control cycle's read and writes) each failed try spends the
        error budget, which raises when the link is unusable. Returns the first result that is not None,
        else None; the caller decides what a failure means (raise, fall back, or go on stopping). `done`:
        tries the caller already made (and spent the budget for) before calling."""
        for k in range(done, tries or 1 + self.retries):
            if k:
                self.stats.retries += 1
            out = attempt(*args)
            if out is not None:
                return out
            if budget:
                self._spend_error_budget()
        return None

    # one try of each kind of transfer, for `_retry`: the value on success, None on failure
    def _group_once(self, fn, *args) -> bool | None:
        """A sync write's txPacket or a sync read's txRxPacket (data in the reader's data_dict)."""
        result = self._transfer(fn, *args)
        if result == COMM_SUCCESS:
            return True
        self._last_result = result
        return None

    def _ping_once(self, sid: int) -> int | None:
        """Ping: the model number."""
        number, result, _error = self._transfer(self._ph.ping, self._port, sid, failed=_NO_READ)
        if result == COMM_SUCCESS:
            return number
        self._last_result = result
        return None

    def _read_once(self, sid: int, address: int, size: int) -> tuple[bytes, int] | None:
        """Read: (data, status error byte)."""
        data, result, error = self._transfer(self._ph.readTxRx, self._port, sid, address, size,
                                             failed=_NO_READ)
        if result == COMM_SUCCESS and len(data) == size:
            return data, error
        self._last_result = result
        return None

    def _write_once(self, sid: int, address: int, size: int, payload: list[int]) -> int | None:
        """Write (acknowledged): the status error byte."""
        result, error = self._transfer(self._ph.writeTxRx, self._port, sid, address, size, payload,
                                       failed=_NO_WRITE)
        if result == COMM_SUCCESS:
            return error
        self._last_result = result
        return None

    def _reason(self, result: int) -> str:
        """The SDK's words for a transfer result, as a phrase ("" for none)."""
        return self._ph.getTxRxResult(result).split("] ")[-1].rstrip("!").lower()

    def _spend_error_budget(self) -> None:
        now = time.monotonic()
        recent = self.stats.recent_errors
        recent.append(now)
        while recent and recent[0] < now - self.error_window_s:
            recent.popleft()
        if len(recent) > self.error_budget:
            self.stats.failures += 1
            raise CommunicationError(
                f"the bus on {self.port_name} lost or corrupted {len(recent)} replies within "
                f"{self.error_window_s:g} s (budget {self.error_budget}); check the cable, the RS-485 "
                "termination and the latency timer")

    # ---- register access by name, one servo at a time -----------------------------------------------
    def _ping(self, sid: int) -> int | None:
        return self._retry(self._ping_once, sid)

    def _read_block(self, sid: int, address: int, size: int, joint: str) -> bytes:
        out = self._retry(self._read_once, sid, address, size)
        if out is None:
            self._update_byte_stats()
            reason = self._reason(self._last_result)
            raise CommunicationError(f"servo {servo_label(joint, sid)} on {self.port_name} did not answer a "
                                     f"read of address {address} after {1 + self.retries} tries "
                                     f"({reason or 'no reply'})")
        data, error = out
        self._raise_if_rejected(error, sid, joint, f"reading address {address}")
        return bytes(data)

    def _read(self, sid: int, name: str, joint: str) -> int:
        reg = self.arm.by_id(sid).servo_model.register(name)
        data = self._read_block(sid, reg.address, reg.size, joint)
        return int.from_bytes(data, "little", signed=reg.signed)

    def _write(self, sid: int, name: str, value: int, joint: str) -> None:
        reg = self.arm.by_id(sid).servo_model.register(name)
        payload = list(units.to_unsigned(int(value), reg.size).to_bytes(reg.size, "little"))
        error = self._retry(self._write_once, sid, reg.address, reg.size, payload)
        if error is None:
            reason = self._reason(self._last_result) or "no reply"
            raise CommunicationError(f"servo {servo_label(joint, sid)} on {self.port_name} did not "
                                     f"acknowledge writing {name} after {1 + self.retries} tries ({reason})")
        self._raise_if_rejected(error, sid, joint, f"writing {name} = {value}")

    def _raise_if_rejected(self, error: int, sid: int, joint: str, what: str) -> None:
        names = [n for n in decode_status_error(error) if n != "alert"]
        if names:
            raise ServoRejectedError(f"servo {servo_label(joint, sid)} on {self.port_name} refused "
                                     f"{what}: {', '.join(names)}")

    def _silent_servos(self) -> dict[str, int]:
        """Ping each servo (once more if it failed) to learn which ones went silent (after a failed read)."""
        silent = {joint: sid for joint, sid in zip(self.joint_names, self.ids)
                  if self._retry(self._ping_once, sid, tries=2) is None}
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

    def _update_byte_stats(self) -> None:
        if self._port is not None:
            self.stats.bytes_written = self._port.bytes_written
            self.stats.bytes_read = self._port.bytes_read
