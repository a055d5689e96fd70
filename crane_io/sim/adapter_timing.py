"""When the bytes of a Dynamixel exchange reach the host through a USB-serial adapter (a U2D2).

A real rig's host does not see a servo's reply the moment the servo has computed it. Three things
stand in between, and this module computes them as a schedule (no clock is read here; the transport,
crane_io.sim.transport.PtyServer, sleeps until the times it is given):

1. The RS-485 line. Every byte takes 10 bit times (start bit, 8 data bits, stop bit) at the servos'
   Baud Rate item (addr 8; 3,000,000 bps on the CRANE-X7, so 3.33 us a byte). The host's instruction
   goes out first, on a line nobody else drives; its last byte ends at
   `max(written, line free) + n_out * byte time`.
2. The servos. Each status packet starts its servo's Return Delay Time (addr 9, 2 us/LSB; e-manual,
   "Return Delay Time") after the line fell quiet: after the instruction's last byte for the first
   reply, after the previous reply's last byte for the next one (a Sync Read's servos answer one after
   another). A Fast Sync Read's one status packet counts the delay of the servo whose block comes
   first.
3. The adapter's USB side (FTDI application note AN232B-04, "Data Throughput, Latency and
   Handshaking", section "Small Amounts of Data and End of Buffer Conditions"). The chip holds the
   received bytes and sends them to the host in one USB packet when
     - its buffer fills: one USB packet holds `usb_packet_bytes` including 2 status bytes, so
       `usb_packet_bytes - 2` data bytes; or
     - its latency timer expires. The timer measures the time since the chip last sent a packet to the
       host and is reset by every packet sent; when it expires the chip sends the 2 status bytes and
       whatever data it holds, even none. So the expiries are a free-running grid of period
       `latency_timer_s`, re-anchored by every packet a full buffer sends.
   The U2D2 carries an FT232H, a USB 2.0 High-Speed chip whose bulk packets are 512 bytes (2 of them
   status), the default here; AN232B-04's full-speed chips (FT232R, FT232BM) use 64-byte packets
   (`usb_packet_bytes=64`). A CRANE-X7 cycle's Fast Sync Read reply (about 120 bytes) fits in one
   high-speed packet, so on a U2D2 it reaches the host at the next expiry of the timer.
   The timer is 16 ms on an adapter nobody configured and 1 ms with the udev rule or
   `echo 1 > /sys/bus/usb-serial/devices/ttyUSB0/latency_timer` (docs/rig-timing.md).

Not modelled: the USB bus's own scheduling (125 us micro-frames on a high-speed bus), the host's
driver and scheduler (the pseudo-terminal and the machine add theirs for real), the servos'
processing time beyond the Return Delay Time, and line errors.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass

from crane_io.errors import ConfigError
from crane_io.sim.protocol import BROADCAST_ID, HEADER

BITS_PER_BYTE = 10  # start bit, 8 data bits, stop bit (8N1, the Dynamixel bus's framing)
STATUS_BYTES = 2  # the modem and line status bytes that head every FTDI USB packet to the host
FT232H_PACKET_BYTES = 512  # USB 2.0 High-Speed bulk packet (the U2D2's FT232H)
DEFAULT_LATENCY_TIMER_S = 0.001  # the udev rule's value
UNCONFIGURED_LATENCY_TIMER_S = 0.016  # the ftdi_sio driver's default
_EPS = 1e-12  # s: a byte that completes on a timer expiry goes with that expiry


@dataclass(frozen=True)
class AdapterTiming:
    """The adapter's settings: its latency timer (s, > 0) and its USB packet size (bytes, with the
    2 status bytes)."""

    latency_timer_s: float = DEFAULT_LATENCY_TIMER_S
    usb_packet_bytes: int = FT232H_PACKET_BYTES

    def __post_init__(self):
        if not (math.isfinite(self.latency_timer_s) and self.latency_timer_s > 0):
            raise ConfigError(f"`latency_timer_s` must be a positive number of seconds, got "
                              f"{self.latency_timer_s}")
        if not (isinstance(self.usb_packet_bytes, int) and self.usb_packet_bytes > STATUS_BYTES):
            raise ConfigError(f"`usb_packet_bytes` must be an integer above {STATUS_BYTES}, got "
                              f"{self.usb_packet_bytes}")

    @property
    def data_per_packet(self) -> int:
        return self.usb_packet_bytes - STATUS_BYTES


def byte_time_s(baudrate: int) -> float:
    """Seconds one byte takes on the line at `baudrate` bit/s."""
    if not baudrate > 0:
        raise ConfigError(f"the baud rate must be positive, got {baudrate}")
    return BITS_PER_BYTE / baudrate


def reply_byte_times(line_quiet_s: float, replies: list[tuple[int, float, int]]) -> list[float]:
    """The time each reply byte has fully arrived at the adapter. `replies`: one (bytes, Return Delay
    Time s, baud rate) per status packet in the order they go on the line; `line_quiet_s`: when the
    instruction's last byte ended."""
    done: list[float] = []
    t = line_quiet_s
    for n, delay_s, baudrate in replies:
        per_byte = byte_time_s(baudrate)
        start = t + delay_s
        done.extend(start + (k + 1) * per_byte for k in range(n))
        t = start + n * per_byte
    return done


class AdapterLink:
    """One adapter and its line over time: where the latency timer's grid stands and when the line is
    free. `exchange` gives the schedule of one instruction and its replies; times are in any one
    clock's seconds (the transport uses time.monotonic())."""

    def __init__(self, timing: AdapterTiming, t0: float = 0.0):
        self.timing = timing
        self.anchor = float(t0)  # the last time the chip sent a packet to the host (timer reset)
        self.line_free = float(t0)  # when the line is free for the host's next instruction

    def next_expiry(self, t: float) -> float:
        """The first expiry of the latency timer at or after `t` (never the anchor itself)."""
        period = self.timing.latency_timer_s
        m = max(1, math.ceil((t - self.anchor) / period - 1e-9))
        return self.anchor + m * period

    def instruction_end(self, written_s: float, n_out: int, baudrate: int) -> float:
        """The instruction's `n_out` bytes on the line from `written_s` (or when the line is free): the
        time its last byte ends. The line stays the host's until then."""
        end = max(written_s, self.line_free) + n_out * byte_time_s(baudrate)
        self.line_free = end
        return end

    def deliveries(self, arrived: list[float]) -> list[tuple[float, int]]:
        """The USB packets that bring bytes that arrived at the adapter at `arrived` (ascending) to the
        host: [(time, data bytes)], in order, the anchor moved along."""
        out: list[tuple[float, int]] = []
        per_packet = self.timing.data_per_packet
        k, n = 0, len(arrived)
        while k < n:
            expiry = self.next_expiry(arrived[k])
            full = arrived[k + per_packet - 1] if k + per_packet - 1 < n else math.inf
            if full < expiry:  # the buffer fills before the timer expires
                out.append((full, per_packet))
                self.anchor = full
                k += per_packet
            else:
                m = bisect_right(arrived, expiry + _EPS, lo=k) - k
                out.append((expiry, m))
                self.anchor = expiry
                k += m
        return out

    def exchange(self, written_s: float, n_out: int, baudrate: int,
                 replies: list[tuple[int, float, int]]) -> list[tuple[float, int]]:
        """One instruction of `n_out` bytes written at `written_s` and its status packets `replies`
        ((bytes, Return Delay Time s, baud rate) each): the USB packets that bring the replies to the
        host, [(time, data bytes)]. The line is busy until the last reply byte."""
        quiet = self.instruction_end(written_s, n_out, baudrate)
        arrived = reply_byte_times(quiet, replies)
        if arrived:
            self.line_free = max(self.line_free, arrived[-1])
        return self.deliveries(arrived)


def status_packets(reply: bytes) -> list[tuple[int, int]]:
    """The status packets a reply's bytes hold, in order: [(bytes, ID of the servo that answers first)];
    a Fast Sync Read's packet (broadcast ID) names its first block's servo. Bytes that do not parse as
    a whole packet (a servo missing from a Fast Sync Read) count as one more packet of the last ID."""
    out: list[tuple[int, int]] = []
    i, n, last = 0, len(reply), -1
    while i < n:
        head = reply[i:i + 10]
        if len(head) >= 7 and head[:4] == HEADER:
            size = 7 + (head[5] | head[6] << 8)
            sid = head[4]
            if sid == BROADCAST_ID and len(head) == 10:
                sid = head[9]  # FF FF FD 00 FE LEN LEN 55 ERR ID: the first block's servo
            last = sid
            size = min(size, n - i)
        else:
            size = n - i
        out.append((size, last))
        i += size
    return out
