"""Indirect Address / Indirect Data of the emulated X-series servo (ROBOTIS e-manual, XM430-W350 /
XM540-W270, "Indirect Address, Indirect Data"; docs/simulator-firmware.md):

- Indirect Address k (k = 1 .. 28 at 168 + 2 (k - 1), k = 29 .. 56 at 578 + 2 (k - 29)) holds the address
  Indirect Data k (224 + k - 1, 634 + k - 29) stands for: 64 .. 661 (the EEPROM area cannot be mapped; Data
  Range Error outside). Its default is Indirect Data k's own address: an unmapped Indirect Data byte is a
  plain read/write byte.
- A read of a mapped Indirect Data byte reads the byte it stands for; a write goes to that byte with the
  rules of the item there (read-only, value range, limits, side effects). Consecutive Indirect Data bytes
  mapped onto consecutive addresses form one write, so a 4-byte item is written through 4 mapped bytes at
  once; fewer bytes than the item has are a Data Length Error, as a direct partial write.
- A mapped byte that stands for another Indirect Data byte reaches that byte's own storage, not what the
  other byte is mapped to (the e-manual does not describe chains of indirection).

`EmulatedServo` keeps `indirect`, the mapped bytes that are not their own default ({} when no Indirect
Address is set): with it empty, reads and writes take the servo's usual path at the cost of one test.
"""

from __future__ import annotations

from crane_io.dynamixel.control_table import CONTROL_TABLE_SIZE, EEPROM_END, INDIRECT_PER_SET, INDIRECT_SETS
from crane_io.sim import protocol as p

# (first Indirect Data address, one past the last, address of the first Indirect Address) of each set
DATA_AREAS = tuple((data_at, data_at + INDIRECT_PER_SET, address_at)
                   for _k, address_at, data_at in INDIRECT_SETS)
ADDRESS_ITEMS = frozenset(f"indirect_address_{first + j}" for first, _a, _d in INDIRECT_SETS
                          for j in range(INDIRECT_PER_SET))
TARGET_RANGE = (EEPROM_END, CONTROL_TABLE_SIZE - 1)  # what an Indirect Address may hold: 64 .. 661


(_LO1, _HI1, _A1), (_LO2, _HI2, _A2) = DATA_AREAS


def touches_data(address: int, end: int) -> bool:
    """The byte range address .. end - 1 covers an Indirect Data byte."""
    return (address < _HI1 and _LO1 < end) or (address < _HI2 and _LO2 < end)


def _is_data(address: int) -> bool:
    return any(lo <= address < hi for lo, hi, _at in DATA_AREAS)


def mapping(memory) -> dict[int, int]:
    """{Indirect Data address: the address it stands for} of the bytes not mapped onto themselves."""
    mapped = {}
    for lo, hi, address_at in DATA_AREAS:
        for j in range(hi - lo):
            target = memory[address_at + 2 * j] | memory[address_at + 2 * j + 1] << 8
            if target != lo + j:
                mapped[lo + j] = target
    return mapped


def read(servo, address: int, length: int) -> tuple[int, bytes]:
    """A Read of address .. address + length - 1 (inside the control table) with the mapped bytes read
    where they point."""
    error, plain = servo.read(address, length, plain=True)
    data = bytearray(plain)
    for a, target in servo.indirect.items():
        if address <= a < address + length:
            if _is_data(target):
                data[a - address] = servo.memory[target]
            else:
                data[a - address] = servo.read(target, 1, plain=True)[1][0]
    return error, bytes(data)


def _runs(servo, address: int, data: bytes) -> list[tuple[int, bytearray, bool]]:
    """The write split into (target address, bytes, storage) runs of consecutive targets; `storage`: a mapped
    run onto Indirect Data bytes, written into their storage as it is."""
    runs: list[tuple[int, bytearray, bool]] = []
    mapped = servo.indirect
    for i, byte in enumerate(data):
        a = address + i
        target = mapped.get(a, a)
        storage = target != a and _is_data(target)
        if runs and runs[-1][0] + len(runs[-1][1]) == target and runs[-1][2] == storage:
            runs[-1][1].append(byte)
        else:
            runs.append((target, bytearray((byte,)), storage))
    return runs


def check_write(servo, address: int, data: bytes) -> int:
    """The error number the write would get (0: allowed): the first of its runs' errors."""
    for target, chunk, storage in _runs(servo, address, data):
        if storage:
            continue
        error = servo.check_write(target, bytes(chunk), plain=True)
        if error:
            return error
    return p.ERR_NONE


def write(servo, address: int, data: bytes, now: float) -> int:
    """Apply the write run by run when every run is allowed; else nothing is written."""
    runs = _runs(servo, address, data)
    for target, chunk, storage in runs:
        error = p.ERR_NONE if storage else servo.check_write(target, bytes(chunk), plain=True)
        if error:
            return error
    for target, chunk, storage in runs:
        if storage:
            servo.memory[target:target + len(chunk)] = chunk
        else:
            servo.write(target, bytes(chunk), now, plain=True)
    return p.ERR_NONE


def reaches(servo, address: int, length: int, targets: tuple[int, ...]) -> bool:
    """A write of address .. address + length - 1 reaches one of the addresses `targets` through a mapped
    Indirect Data byte."""
    return any(address <= a < address + length and t in targets for a, t in servo.indirect.items())
