"""The CRC-16 of Dynamixel Protocol 2.0 (polynomial 0x8005, initial value 0, MSB first, no final xor),
shared by the bus client (crane_io.dynamixel.packets) and the simulated servos (crane_io.sim.protocol).

Pure Python with a 65536-entry table so the loop runs once per 16-bit word instead of once per byte:
for a 16-bit CRC, shifting in the big-endian word w gives crc' = TABLE16[crc ^ w]. About 4x faster
than the byte-wise loop of the e-manual (and of dynamixel-sdk), same results.

Every packet on a simulated bus has its CRC computed twice, by its sender and by its receiver, over the
same bytes; and the Sync Read instruction of the control loop is the same packet every cycle. So
`crc16` from zero keeps the CRCs of the last few packets (a memo keyed by the exact bytes: any changed
byte is a different key and gets computed), and `remember` lets a sender that computed a packet's CRC
in pieces (the Fast Sync Read status packet) file it for the receiver.
"""

from __future__ import annotations

import array
import sys


def _byte_table() -> list[int]:
    """The e-manual's 256-entry table: CRC register after shifting byte i through a zero register."""
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


def _word_table(table: list[int]) -> list[int]:
    """Entry (hi << 8 | lo): the register after shifting the bytes hi, lo through a zero register."""
    out = []
    for hi in range(256):
        th = table[hi]
        base, sub = (th << 8) & 0xFFFF, th >> 8
        out.extend([base ^ table[sub ^ lo] for lo in range(256)])
    return out


CRC_TABLE = _byte_table()
# 16-bit entries in one contiguous 128 KiB block: a list of 65536 Python ints is ~2.5 MB spread over the
# heap, and in a running session (pinocchio, numpy, h5py around it) its lookups miss the CPU caches
CRC_TABLE16 = array.array("H", _word_table(CRC_TABLE))
_SWAP = sys.byteorder == "little"


_MEMO: dict[bytes, int] = {}
_MEMO_SIZE = 32  # packets remembered (a control cycle of two arms puts 4 on the wire)


def remember(data: bytes, crc: int) -> None:
    """File `crc` as the CRC-16 (from zero) of `data` for a later crc16(data)."""
    if len(_MEMO) >= _MEMO_SIZE:
        _MEMO.clear()
    _MEMO[bytes(data)] = crc


def crc16(data, crc: int = 0) -> int:
    """CRC-16 of `data` (bytes-like, or a sequence of ints 0..255), optionally continuing `crc`."""
    if crc == 0:
        key = data if type(data) is bytes else bytes(data)
        value = _MEMO.get(key)
        if value is None:
            value = _crc16(key, 0)
            remember(key, value)
        return value
    return _crc16(data, crc)


def _crc16(data, crc: int) -> int:
    if not isinstance(data, (bytes, bytearray, memoryview)):
        data = bytes(data)
    n = len(data)
    if n & 1:
        crc = ((crc << 8) & 0xFF00) ^ CRC_TABLE[(crc >> 8) ^ data[0]]
        data = memoryview(data)[1:]
    if n < 2:
        return crc
    words = array.array("H")
    words.frombytes(data)
    if _SWAP:
        words.byteswap()
    table = CRC_TABLE16
    for w in words:
        crc = table[crc ^ w]
    return crc


def crc16_append(crc: int) -> int:
    """The CRC after the two bytes of `crc` itself (low byte first) have been appended to the data."""
    return CRC_TABLE16[crc ^ (((crc & 0xFF) << 8) | (crc >> 8))]


def crc16_chain(head, parts) -> list[int]:
    """Running CRCs of a Fast Sync Read status packet: the CRC of `head` + parts[0], then of everything
    so far plus that CRC (low byte first) + parts[1], and so on; one CRC per part."""
    crc = crc16(head)
    out = []
    if len(head) % 2 or any(len(p) % 2 for p in parts):
        for p in parts:
            crc = crc16(p, crc)
            out.append(crc)
            crc = crc16_append(crc)
        return out
    words = array.array("H")
    words.frombytes(b"".join(parts))
    if _SWAP:
        words.byteswap()
    table = CRC_TABLE16
    k = 0
    for p in parts:
        end = k + (len(p) >> 1)
        for w in words[k:end]:
            crc = table[crc ^ w]
        k = end
        out.append(crc)
        crc = table[crc ^ (((crc & 0xFF) << 8) | (crc >> 8))]
    return out


class FixedPrefixCrc:
    """crc16(prefix + params) for `n`-byte params after a fixed `prefix` (a sync write's header), by the
    CRC's linearity: with the initial value 0 and no final xor, the CRC of a message is the xor of the
    CRCs of its bytes each alone at its place (zeros elsewhere). So it is the CRC of prefix + n zeros,
    xored with one table entry per parameter byte: n lookups instead of a pass over the whole packet."""

    def __init__(self, prefix: bytes, n: int):
        self.n = n
        self.base = _crc16(bytes(prefix) + bytes(n), 0)
        tables = []
        table = CRC_TABLE  # byte v as the last byte: crc16(bytes([v])) == CRC_TABLE[v]
        for _ in range(n):
            tables.append(table)
            table = [((x << 8) & 0xFF00) ^ CRC_TABLE[x >> 8] for x in table]  # one more zero byte after it
        self.tables = tables[::-1]  # tables[p][v]: byte v at position p of the params

    def __call__(self, params) -> int:
        crc = self.base
        for table, byte in zip(self.tables, params):
            crc ^= table[byte]
        return crc
