"""The transfers of one bus (crane_io.dynamixel.bus): the one transfer wrapper and the one retry loop.

`Link` runs every dynamixel-sdk transfer of a `DynamixelBus` through `transfer` (counted, time-stamped on
the servos' clock for the bus's stall check, a failed port turned into a failed transfer) and repeats a
failed one only through `retry` (at most 1 + `retries` tries, the error budget spent per failed try of the
control cycle). On top of them: register blocks of one servo read and written by address, with the
messages a lab user reads when a servo stays silent or refuses.
"""

from __future__ import annotations

import collections
import time
from dataclasses import dataclass, field

import serial
from dynamixel_sdk import COMM_RX_CORRUPT, COMM_SUCCESS, COMM_TX_FAIL
from dynamixel_sdk.protocol2_packet_handler import PKT_ID, PKT_LENGTH_H, PKT_LENGTH_L

from crane_io.dynamixel import units
from crane_io.dynamixel.control_table import Register
from crane_io.dynamixel.faults import CommunicationError, ServoRejectedError, decode_status_error, servo_label
from crane_io.dynamixel.packets import CranePacketHandler
from crane_io.dynamixel.port import CranePortHandler

_ERR_CRC = 0x03  # a status packet's error number: the instruction arrived with a wrong CRC

# what a transfer whose port failed returns, in the shape of the SDK call: a result code, (data or
# model number, result, error), (result, error)
_NO_READ, _NO_WRITE = (None, COMM_TX_FAIL, 0), (COMM_TX_FAIL, 0)


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


class Link:
    """The transfers on one port (`port` is set when the bus opens it)."""

    def __init__(self, port_name: str, retries: int, error_budget: int, stats: BusStats):
        self.port_name = port_name
        self.retries = retries
        self.error_budget = error_budget  # failed transfers tolerated in any `error_window_s`
        self.error_window_s = 1.0
        self.stats = stats
        self.ph = CranePacketHandler()
        self.port: CranePortHandler | None = None
        self.last_result = COMM_SUCCESS  # the SDK result of the latest failed try (for messages)
        self.last_port_error = ""  # the port's own reason when it failed
        self.last_tx: float | None = None  # now() of the latest transfer
        self.checked_now: float | None = None  # now() of a stall check, for the transfer after it
        # the clock the stall check measures pauses with: the servos' own notion of time. Real servos
        # (and wall-clock simulated ones) live in real time; a lockstep simulated chain only advances
        # with the goal writes, so there a host pause cannot stop a servo and costs no extra read.
        self.now = time.monotonic

    def attach(self, port: CranePortHandler) -> None:
        """Transfer through `port` from now on, measuring pauses on its servos' clock."""
        self.port = port
        self.now = getattr(port.ser, "servo_time", None) or time.monotonic

    # ---- the one transfer wrapper and the one retry loop ----------------------------------------
    def transfer(self, fn, *args, failed=COMM_TX_FAIL):
        """Run one SDK transfer `fn(*args)`, counted in stats.attempts and time-stamped for the stall
        check. A serial-level exception (the port itself failed) makes it a failed transfer: it returns
        `failed` (shaped like fn's own result) and the port's reason is kept for the message."""
        self.stats.attempts += 1
        now = self.checked_now
        if now is None:
            now = self.now()
        else:
            self.checked_now = None
        self.last_tx = now
        try:
            return fn(*args)
        except (serial.SerialException, OSError) as exc:
            self.port.is_using = False
            self.last_port_error = str(exc)
            return failed

    def retry(self, attempt, *args, budget: bool = False, tries: int | None = None, done: int = 0):
        """THE retry loop of the bus: every transfer that is repeated on a missing or corrupted reply
        goes through here. `attempt(*args)` makes one try (through `transfer`) and returns what it got,
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
                self.spend_error_budget()
        return None

    def spend_error_budget(self) -> None:
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

    def paused_longer_than(self, limit_s: float) -> float | None:
        """The pause since the latest transfer on the servos' clock when it is longer than `limit_s`;
        else None, and the next transfer is stamped with this reading of the clock (nothing happened in
        between). None too before the first transfer."""
        last = self.last_tx
        if last is None:
            return None
        now = self.now()
        gap = now - last
        if gap > limit_s:
            return gap
        self.checked_now = now
        return None

    # one try of each kind of transfer, for `retry`: the value on success, None on failure
    def group_once(self, fn, *args) -> bool | None:
        """A sync write's txPacket or a sync read's txRxPacket (data in the reader's data_dict)."""
        result = self.transfer(fn, *args)
        if result == COMM_SUCCESS:
            return True
        self.last_result = result
        return None

    def ping_once(self, sid: int) -> int | None:
        """Ping: the model number."""
        number, result, error = self.transfer(self.ph.ping, self.port, sid, failed=_NO_READ)
        if result == COMM_SUCCESS and error & 0x7F == _ERR_CRC:
            result = COMM_RX_CORRUPT  # the servo received a corrupted instruction: a failed try
        elif result == COMM_SUCCESS:
            return number
        self.last_result = result
        return None

    def read_once(self, sid: int, address: int, size: int) -> tuple[bytes, int] | None:
        """Read: (data, status error byte)."""
        data, result, error = self.transfer(self.ph.readTxRx, self.port, sid, address, size, failed=_NO_READ)
        if result == COMM_SUCCESS and len(data) == size:
            return data, error
        self.last_result = result
        return None

    def write_once(self, sid: int, address: int, size: int, payload: list[int]) -> int | None:
        """Write (acknowledged): the status error byte."""
        result, error = self.transfer(self.ph.writeTxRx, self.port, sid, address, size, payload,
                                      failed=_NO_WRITE)
        if result == COMM_SUCCESS and error & 0x7F == _ERR_CRC:
            result = COMM_RX_CORRUPT  # the servo received a corrupted instruction: a failed try
        elif result == COMM_SUCCESS:
            return error
        self.last_result = result
        return None

    def reason(self, result: int) -> str:
        """The SDK's words for a transfer result, as a phrase ("" for none)."""
        return self.ph.getTxRxResult(result).split("] ")[-1].rstrip("!").lower()

    def update_byte_stats(self) -> None:
        if self.port is not None:
            self.stats.bytes_written = self.port.bytes_written
            self.stats.bytes_read = self.port.bytes_read

    # ---- one servo, by address ------------------------------------------------------------------
    def ping(self, sid: int, tries: int | None = None) -> int | None:
        """The model number of servo `sid`, or None when it did not answer (`tries`: default 1 + retries)."""
        return self.retry(self.ping_once, sid, tries=tries)

    def read_block(self, sid: int, address: int, size: int, joint: str) -> bytes:
        """`size` bytes from `address` of servo `sid` (joint `joint`), retried; CommunicationError when it
        does not answer, ServoRejectedError when it refuses."""
        out = self.retry(self.read_once, sid, address, size)
        if out is None:
            self.update_byte_stats()
            reason = self.reason(self.last_result)
            raise CommunicationError(f"servo {servo_label(joint, sid)} on {self.port_name} did not answer a "
                                     f"read of address {address} after {1 + self.retries} tries "
                                     f"({reason or 'no reply'})")
        data, error = out
        self.raise_if_rejected(error, sid, joint, f"reading address {address}")
        return bytes(data)

    def write_register(self, sid: int, reg: Register, value: int, joint: str) -> None:
        """Write `value` into register `reg` of servo `sid` (acknowledged), retried; CommunicationError when
        it does not acknowledge, ServoRejectedError when it refuses."""
        payload = list(units.to_unsigned(int(value), reg.size).to_bytes(reg.size, "little"))
        error = self.retry(self.write_once, sid, reg.address, reg.size, payload)
        if error is None:
            reason = self.reason(self.last_result) or "no reply"
            who = servo_label(joint, sid)
            raise CommunicationError(f"servo {who} on {self.port_name} did not acknowledge writing "
                                     f"{reg.name} after {1 + self.retries} tries ({reason})")
        self.raise_if_rejected(error, sid, joint, f"writing {reg.name} = {value}")

    def raise_if_rejected(self, error: int, sid: int, joint: str, what: str) -> None:
        names = [n for n in decode_status_error(error) if n != "alert"]
        if names:
            raise ServoRejectedError(f"servo {servo_label(joint, sid)} on {self.port_name} refused "
                                     f"{what}: {', '.join(names)}")

    def reply_timeout_s(self, data_length: int) -> float:
        """How long each try waits for the reply to a read of `data_length` bytes (as the SDK computes it,
        with this port's latency)."""
        self.port.setPacketTimeout(data_length + 11)
        return self.port.packet_timeout / 1000.0

    def late_reply_s(self, sid: int, address: int, size: int, listen_s: float) -> float | None:
        """Ask servo `sid` for `size` bytes at `address` once and listen up to `listen_s` for that reply
        (late replies to earlier reads, of another length, are skipped): the seconds it took, or None. For
        reports only: it waits far longer than any control cycle may."""
        port, ph = self.port, self.ph

        def probe():
            sent = time.monotonic()
            if ph.readTx(port, sid, address, size) != COMM_SUCCESS:
                port.is_using = False
                return None
            port.setPacketTimeoutMillis(listen_s * 1000.0)
            while True:
                packet, result = ph.rxPacket(port, False)
                if result == COMM_SUCCESS:
                    length = packet[PKT_LENGTH_L] | packet[PKT_LENGTH_H] << 8
                    if packet[PKT_ID] == sid and length == size + 4:  # INST ERR DATA CRC
                        return time.monotonic() - sent
                elif port.isPacketTimeout():
                    return None

        try:
            return self.transfer(probe, failed=None)  # a port error: no reply
        finally:
            self.update_byte_stats()
