"""The CRC-16 of Dynamixel Protocol 2.0, defined once: polynomial 0x8005, initial value 0, most significant
bit first, no final xor (ROBOTIS e-manual, "Protocol 2.0", CRC calculation).

Both the plain CRC (crane_io.dynamixel.crc) and the compiled kernels of the bus (cycle_kernel) and of the
simulated chain (crane_io.sim.chain_kernel) take the table and the loop from here; this module imports
numpy only, so compiled modules may import it. It holds no state: `byte_table()` makes a new table for
each caller, so the host and the simulator never share one (a damaged table on one side is caught by the
other's check).
"""

from __future__ import annotations

import numpy as np

POLYNOMIAL = 0x8005


def byte_table() -> np.ndarray:
    """A new copy of the e-manual's 256-entry table (int64): entry i is the CRC register after shifting
    byte i through a zero register."""
    table = np.zeros(256, dtype=np.int64)
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ POLYNOMIAL) if crc & 0x8000 else (crc << 1)
        table[i] = crc & 0xFFFF
    return table


def crc_step(crc, byte, table):
    """The CRC register `crc` after one more byte."""
    return ((crc << 8) & 0xFF00) ^ table[((crc >> 8) ^ byte) & 0xFF]


def crc_update(buf, start, stop, crc, table):
    """The CRC register `crc` after the bytes buf[start:stop], one table lookup per byte (compiled code
    compiles `crc_step` with it)."""
    for i in range(start, stop):
        crc = crc_step(crc, buf[i], table)
    return crc
