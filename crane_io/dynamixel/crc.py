"""The CRC-16 of Dynamixel Protocol 2.0 in plain Python (the algorithm and its table: crc_layout).

    crc16 = Crc16()                 # one per side: the bus client's (crane_io.dynamixel.packets) and the
    crc16(packet[:-2])              # simulated servos' (crane_io.sim.protocol) each make their own

Each `Crc16` holds its own tables and no memo of earlier packets, so the host's check of a simulated
servo's reply and the servo's check of the host's packet are independent computations: a fault on one
side is caught by the other.

A 65536-entry word table lets the loop run once per 16-bit word instead of once per byte: for a 16-bit
CRC, shifting in the big-endian word w gives crc' = TABLE16[crc ^ w]. About 4x faster than the byte-wise
loop of the e-manual (and of dynamixel-sdk), same results.
"""

from __future__ import annotations

import array
import sys

from crane_io.dynamixel.crc_layout import byte_table, crc_step

_SWAP = sys.byteorder == "little"


def _word_table(table: list[int]) -> list[int]:
    """Entry (hi << 8 | lo): the register after shifting the bytes hi, lo through a zero register."""
    out = []
    for hi in range(256):
        th = table[hi]
        base, sub = (th << 8) & 0xFFFF, th >> 8
        out.extend([base ^ table[sub ^ lo] for lo in range(256)])
    return out


class Crc16:
    """The CRC-16 with tables of its own: `crc16(data, crc=0)` for bytes-like data (or a sequence of
    ints 0..255), optionally continuing `crc`."""

    def __init__(self):
        self.table = byte_table().tolist()  # the e-manual's 256 entries, as Python ints
        # 16-bit entries in one contiguous 128 KiB block: a list of 65536 Python ints is ~2.5 MB spread
        # over the heap, and in a running session its lookups miss the CPU caches
        self.table16 = array.array("H", _word_table(self.table))

    def __call__(self, data, crc: int = 0) -> int:
        if not isinstance(data, (bytes, bytearray, memoryview)):
            data = bytes(data)
        n = len(data)
        if n & 1:
            crc = crc_step(crc, data[0], self.table)
            data = memoryview(data)[1:]
        if n < 2:
            return crc
        return self._words(data, crc)

    def _words(self, data, crc: int) -> int:
        words = array.array("H")
        words.frombytes(data)
        if _SWAP:
            words.byteswap()
        table = self.table16
        for w in words:
            crc = table[crc ^ w]
        return crc

    def append(self, crc: int) -> int:
        """The CRC after the two bytes of `crc` itself (low byte first) have been appended to the data."""
        return self.table16[crc ^ (((crc & 0xFF) << 8) | (crc >> 8))]

    def chain(self, head, parts) -> list[int]:
        """Running CRCs of a Fast Sync Read status packet: the CRC of `head` + parts[0], then of everything
        so far plus that CRC (low byte first) + parts[1], and so on; one CRC per part."""
        crc = self(head)
        out = []
        if len(head) % 2 or any(len(p) % 2 for p in parts):
            for p in parts:
                crc = self(p, crc)
                out.append(crc)
                crc = self.append(crc)
            return out
        words = array.array("H")
        words.frombytes(b"".join(parts))
        if _SWAP:
            words.byteswap()
        table = self.table16
        k = 0
        for p in parts:
            end = k + (len(p) >> 1)
            for w in words[k:end]:
                crc = table[crc ^ w]
            k = end
            out.append(crc)
            crc = table[crc ^ (((crc & 0xFF) << 8) | (crc >> 8))]
        return out

    def fixed_prefix(self, prefix: bytes, n: int) -> FixedPrefixCrc:
        """`FixedPrefixCrc` of `prefix` and `n` parameter bytes, with this CRC's tables."""
        return FixedPrefixCrc(self, prefix, n)


class FixedPrefixCrc:
    """crc16(prefix + params) for `n`-byte params after a fixed `prefix` (a sync write's header), by the
    CRC's linearity: with the initial value 0 and no final xor, the CRC of a message is the xor of the
    CRCs of its bytes each alone at its place (zeros elsewhere). So it is the CRC of prefix + n zeros,
    xored with one table entry per parameter byte: n lookups instead of a pass over the whole packet."""

    def __init__(self, crc16: Crc16, prefix: bytes, n: int):
        self.n = n
        self.base = crc16(bytes(prefix) + bytes(n))
        byte = crc16.table
        tables = []
        table = byte  # byte v as the last byte: crc16(bytes([v])) == table[v]
        for _ in range(n):
            tables.append(table)
            table = [crc_step(x, 0, byte) for x in table]  # one more zero byte after it
        self.tables = tables[::-1]  # tables[p][v]: byte v at position p of the params

    def __call__(self, params) -> int:
        crc = self.base
        for table, byte in zip(self.tables, params):
            crc ^= table[byte]
        return crc
