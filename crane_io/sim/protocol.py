"""Dynamixel Protocol 2.0 on the wire, as the servos see it: CRC-16, byte stuffing, an incremental
instruction-packet parser and status-packet building.

Packet layout (ROBOTIS e-manual, "Protocol 2.0"):

    FF FF FD 00 | ID | LEN_L LEN_H | INST | params ... | CRC_L CRC_H

LEN counts INST, the (stuffed) parameters and the two CRC bytes. A status packet has INST = 0x55
and an ERR byte before its parameters. Inside INST..params every "FF FF FD" gets an extra FD
(byte stuffing); LEN and the CRC are computed on the stuffed bytes.

This module is pure bytes; it knows nothing about servos or time except the parser's stale-packet
timeout, which the caller drives with its own clock.
"""

from __future__ import annotations

from dataclasses import dataclass

from crane_io.dynamixel.crc import Crc16

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC

# Instructions
INST_PING = 0x01
INST_READ = 0x02
INST_WRITE = 0x03
INST_REG_WRITE = 0x04
INST_ACTION = 0x05
INST_FACTORY_RESET = 0x06
INST_REBOOT = 0x08
INST_CLEAR = 0x10
INST_STATUS = 0x55
INST_SYNC_READ = 0x82
INST_SYNC_WRITE = 0x83
INST_FAST_SYNC_READ = 0x8A
INST_BULK_READ = 0x92
INST_BULK_WRITE = 0x93
INST_FAST_BULK_READ = 0x9A

# Error byte of a status packet: bit 7 alert, bits 0..6 an error number
ERR_NONE = 0x00
ERR_RESULT_FAIL = 0x01
ERR_INSTRUCTION = 0x02
ERR_CRC = 0x03
ERR_DATA_RANGE = 0x04
ERR_DATA_LENGTH = 0x05
ERR_DATA_LIMIT = 0x06
ERR_ACCESS = 0x07
ERR_ALERT = 0x80

# Longest LEN the parser accepts; anything larger is treated as line noise and skipped.
MAX_LENGTH = 1024

# the simulated servos' CRC, with tables of their own: the host computes its own (crane_io.dynamixel.packets),
# so a fault in either side's CRC is caught by the other's check
crc16 = Crc16()


_STUFF_MARK = b"\xff\xff\xfd"


def stuff(body: bytes | bytearray) -> bytes:
    """Byte-stuff the INST..params region: after every "FF FF FD" insert one more FD."""
    if _STUFF_MARK not in body:
        return bytes(body)
    out = bytearray()
    for b in body:
        out.append(b)
        if b == 0xFD and len(out) >= 3 and out[-2] == 0xFF and out[-3] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes | bytearray) -> bytes:
    """Undo `stuff`: drop the FD that follows every "FF FF FD"."""
    if _STUFF_MARK not in body:
        return bytes(body)
    out = bytearray()
    i, n = 0, len(body)
    while i < n:
        b = body[i]
        out.append(b)
        i += 1
        if b == 0xFD and len(out) >= 3 and out[-2] == 0xFF and out[-3] == 0xFF and i < n and body[i] == 0xFD:
            i += 1
    return bytes(out)


def _frame(packet_id: int, body: bytes) -> bytes:
    stuffed = stuff(body)
    length = len(stuffed) + 2
    head = HEADER + bytes((packet_id & 0xFF, length & 0xFF, (length >> 8) & 0xFF))
    packet = head + stuffed
    crc = crc16(packet)
    return packet + bytes((crc & 0xFF, crc >> 8))


def instruction_packet(packet_id: int, instruction: int, params: bytes | bytearray = b"") -> bytes:
    """A complete, stuffed instruction packet with its CRC."""
    return _frame(packet_id, bytes((instruction,)) + bytes(params))


def status_packet(packet_id: int, error: int, params: bytes | bytearray = b"") -> bytes:
    """A complete, stuffed status packet (INST 0x55) with the error byte and its CRC."""
    return _frame(packet_id, bytes((INST_STATUS, error & 0xFF)) + bytes(params))


def fast_status_packet(blocks: list[tuple[int, int, bytes]]) -> bytes:
    """The one combined status packet of a Fast Sync Read (or Fast Bulk Read).

    `blocks` holds (error, id, data) per servo in request order. On the wire each servo appends
    ERR ID DATA and then the CRC of the whole packet so far (the last servo's CRC is the packet's
    CRC); the packet ID is the broadcast ID and LEN = 1 + sum(4 + len(data)).
    """
    # LEN counts the stuffed bytes; stuffing of the data is rare (FF FF FD in the payload).
    stuffed_parts = [bytes((error & 0xFF, servo_id & 0xFF)) + bytes(data) for error, servo_id, data in blocks]
    if any(_STUFF_MARK in part for part in stuffed_parts):
        stuffed_parts = [stuff(part) for part in stuffed_parts]
    length = 1 + sum(len(s) + 2 for s in stuffed_parts)
    head = HEADER + bytes((BROADCAST_ID, length & 0xFF, (length >> 8) & 0xFF, INST_STATUS))
    packet = bytearray(head)
    for s, crc in zip(stuffed_parts, crc16.chain(head, stuffed_parts)):
        packet += s
        packet.append(crc & 0xFF)
        packet.append(crc >> 8)
    return bytes(packet)


def fast_status_prefix(blocks: list[tuple[int, int, bytes]], n_total: int, data_length: int) -> bytes:
    """The bytes a Fast Sync Read chain puts on the wire when only the first servos answer.

    The header announces `n_total` blocks of `data_length` bytes, but only `blocks` follow (each
    with its running CRC); the packet stays incomplete, as on a bus where a servo is missing.
    """
    length = 1 + n_total * (data_length + 4)
    packet = bytearray(HEADER + bytes((BROADCAST_ID, length & 0xFF, (length >> 8) & 0xFF, INST_STATUS)))
    crc = crc16(packet)
    for error, servo_id, data in blocks:
        part = stuff(bytes((error & 0xFF, servo_id & 0xFF)) + bytes(data))
        packet += part
        crc = crc16(part, crc)
        packet += bytes((crc & 0xFF, crc >> 8))
        crc = crc16.append(crc)
    return bytes(packet)


@dataclass(frozen=True, slots=True)
class Packet:
    """A parsed packet: the ID, the instruction, the unstuffed parameters, and the raw wire bytes.

    For a status packet (instruction 0x55) the first parameter byte is the error byte."""

    id: int
    instruction: int
    params: bytes
    raw: bytes


class PacketParser:
    """Incremental Protocol 2.0 packet parser.

    Feed it bytes as they arrive; it returns every complete packet whose CRC matches. It never
    raises on any input and never waits forever: garbage is skipped byte by byte until a header is
    found, a LEN that is impossible is skipped, a packet with a wrong CRC is counted in
    `crc_errors` and skipped (its ID and instruction kept in `crc_failed` for whoever answers them),
    and a partial packet that has waited longer than `stale_after_s`
    (on the caller's clock, passed as `now`) is abandoned when new bytes arrive (a servo's receive
    timeout), so a corrupted LEN cannot swallow the packets that follow it.
    """

    def __init__(self, stale_after_s: float = 0.02, max_length: int = MAX_LENGTH):
        self.stale_after_s = stale_after_s
        self.max_length = max_length
        self.buffer = bytearray()
        self.crc_errors = 0
        self.crc_failed: list[tuple[int, int]] = []  # (ID, instruction) of each packet with a wrong CRC
        self.discarded_bytes = 0
        self._partial_since: float | None = None

    def reset(self) -> None:
        self.buffer.clear()
        self._partial_since = None

    def feed(self, data: bytes | bytearray, now: float | None = None) -> list[Packet]:
        if not self.buffer and len(data) >= 10 and data[:4] == HEADER:
            # the usual case: exactly one whole packet with a good CRC into an empty buffer (what the
            # general loop below would make of it, without the loop)
            length = data[5] | (data[6] << 8)
            if 3 <= length <= self.max_length and len(data) == 7 + length:
                raw = bytes(data)
                if crc16(raw[:-2]) == raw[-2] | (raw[-1] << 8):
                    self._partial_since = None
                    return [Packet(raw[4], raw[7], unstuff(raw[8:-2]), raw)]
        dropped = False
        if (
            data
            and now is not None
            and self._partial_since is not None
            and now - self._partial_since > self.stale_after_s
            and self.buffer
        ):
            # The partial packet in the buffer waited too long: like a servo's receive timeout,
            # forget it and start afresh with the new bytes.
            self.discarded_bytes += len(self.buffer)
            self.buffer.clear()
            dropped = True
        self.buffer += data
        packets = []
        while True:
            pkt = self._next()
            if pkt is None:
                break
            packets.append(pkt)
        if not self.buffer or now is None:
            self._partial_since = None
        elif packets or dropped or self._partial_since is None:
            self._partial_since = now
        return packets

    def _next(self) -> Packet | None:
        buf = self.buffer
        while True:
            start = buf.find(HEADER)
            if start < 0:
                # Keep a possible header prefix at the end, drop the rest.
                keep = 0
                for k in (3, 2, 1):
                    if len(buf) >= k and bytes(buf[-k:]) == HEADER[:k]:
                        keep = k
                        break
                self.discarded_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                return None
            if start:
                self.discarded_bytes += start
                del buf[:start]
            if len(buf) < 7:
                return None
            length = buf[5] | (buf[6] << 8)
            if length < 3 or length > self.max_length:
                del buf[:1]
                self.discarded_bytes += 1
                continue
            total = 7 + length
            if len(buf) < total:
                return None
            raw = bytes(buf[:total])
            crc = raw[-2] | (raw[-1] << 8)
            if crc16(raw[:-2]) != crc:
                self.crc_errors += 1
                self.crc_failed.append((raw[4], raw[7]))
                del buf[:1]
                self.discarded_bytes += 1
                continue
            del buf[:total]
            return Packet(raw[4], raw[7], unstuff(raw[8:-2]), raw)


# ---- wire sizes (for bus-time budgets and the benchmark's "bytes on the wire vs minimum") --------

def instruction_length(n_params: int) -> int:
    """Bytes of an instruction packet with `n_params` parameter bytes (before any stuffing)."""
    return 10 + n_params


def status_length(n_params: int) -> int:
    """Bytes of a status packet with `n_params` parameter bytes after the error byte."""
    return 11 + n_params


def sync_read_bytes(n_servos: int, data_length: int) -> tuple[int, int]:
    """(instruction, replies) bytes of a Sync Read: one status packet per servo."""
    return instruction_length(4 + n_servos), n_servos * status_length(data_length)


def fast_sync_read_bytes(n_servos: int, data_length: int) -> tuple[int, int]:
    """(instruction, reply) bytes of a Fast Sync Read: one combined status packet."""
    return instruction_length(4 + n_servos), 8 + n_servos * (data_length + 4)


def sync_write_bytes(n_servos: int, data_length: int) -> int:
    """Bytes of a Sync Write instruction (no replies)."""
    return instruction_length(4 + n_servos * (1 + data_length))


def cycle_bytes(n_servos: int = 8, read_length: int = 10, write_length: int = 2, fast: bool = True) -> int:
    """Protocol 2.0 minimum bytes of one control cycle: a (fast) sync read plus a sync write.

    For the CRANE-X7 (8 servos, 10 bytes read at 126, 2 bytes Goal Current written) this is
    142 + 38 = 180 bytes with Fast Sync Read and 190 + 38 = 228 bytes with plain Sync Read."""
    tx, rx = (fast_sync_read_bytes if fast else sync_read_bytes)(n_servos, read_length)
    return tx + rx + sync_write_bytes(n_servos, write_length)
