"""Compiled pieces of the simulated chain's lockstep cycle: the plant's reading quantised into
every servo's Present items at once, the servos' commands read out at once, and the Fast Sync Read
status packet built with its CRCs in one call.

They work on the chain's control-table memories as one (n_servos, MEMORY_SIZE) uint8 array (each
EmulatedServo's `memory` is a view of its row). The plain Python functions here are the source; `compiled()`
compiles them with numba (`cache=True`, no `fastmath`: the same IEEE operations as the Python source,
which tests/test_chain_fast.py runs as the reference through `.py_func`). Each one does exactly what
the general path (EmulatedServo.set_sensors, .command, crane_io.sim.protocol.fast_status_packet) does for
the servos it is given; the chain decides when that applies (crane_io.sim.chain, "fast path").
"""

from __future__ import annotations

import math

import numpy as np

from crane_io.dynamixel.control_table import X_SERIES
from crane_io.dynamixel.crc_layout import byte_table, crc_step
from crane_io.dynamixel.units import (
    AMPERE_PER_CURRENT_LSB,
    POSITION_CENTER,
    RAD_PER_PULSE,
    RADS_PER_VELOCITY_LSB,
)

CRC_TABLE_U16 = byte_table()  # the simulated servos' own CRC table (the host's is another: cycle_kernel)
# the CRC's one-byte step (crc_layout), under the name the kernels compiled from this module call it by
_crc_byte = crc_step
_I32_MIN, _I32_MAX = -(2**31), 2**31 - 1
_BIG = 2.0**40  # beyond this a rounded value is clamped anyway (and stays exact below it)
_TWO_TO_MINUS_53 = 1.0 / 9007199254740992.0
# the frame of the Present and Goal items (crane_io.sim.servo_rules): Drive Mode's reverse bit, Homing Offset
# (ignored outside +-1024 in Position Control Mode)
_DRIVE_AT, _HOMING_AT = X_SERIES["drive_mode"].address, X_SERIES["homing_offset"].address
_MODE_AT = X_SERIES["operating_mode"].address
_MODE_POSITION, _POSITION_MODE_HOMING = 3, 1024


def _frame(m):
    """(direction +-1.0, effective Homing Offset) of the servo memory row m (servo_rules.direction and
    effective_homing)."""
    sign = -1.0 if m[_DRIVE_AT] & 1 else 1.0
    homing = _get_s(m, _HOMING_AT, 4)
    if m[_MODE_AT] == _MODE_POSITION and (homing < -_POSITION_MODE_HOMING or homing > _POSITION_MODE_HOMING):
        homing = np.int64(0)
    return sign, homing


def _quantise(x, scale, offset, lo, hi):
    """round(x / scale) + offset clamped to lo..hi, as Python's round (half to even) computes it."""
    r = np.rint(x / scale)
    if r < -_BIG:
        return lo
    if r > _BIG:
        return hi
    v = np.int64(r) + offset
    return lo if v < lo else hi if v > hi else v


def _put(m, at, value, size):
    for k in range(size):
        m[at + k] = (value >> (8 * k)) & 0xFF


def _get_u(m, at, size):
    v = np.int64(0)
    for k in range(size):
        v |= np.int64(m[at + k]) << (8 * k)
    return v


def _get_s(m, at, size):
    v = _get_u(m, at, size)
    sign = np.int64(1) << (8 * size - 1)
    return v - 2 * sign if v & sign else v


def sensors_into(mem, pos, vel, cur, volt, temp, tick, present_at, tick_at, supply_at, threshold_at):
    """EmulatedServo.set_sensors(pos[i], vel[i], cur[i], now, ...) for every row i of `mem`, with the Realtime
    Tick value `tick` (int(now * 1000) % 32768) and the supply's raw register values `volt`, `temp` (int64
    per row; -1: the plant gives none, the item is left as it is). Returns False, having written nothing,
    when a finite reading is too large to quantise (set_sensors raises OverflowError there: the caller
    takes the general path), else True."""
    for i in range(mem.shape[0]):
        p, v, c = pos[i], vel[i], cur[i]
        if math.isfinite(p) and math.isfinite(v) and math.isfinite(c):
            if (math.isinf(p / RAD_PER_PULSE) or math.isinf(v / RADS_PER_VELOCITY_LSB)
                    or math.isinf(c / AMPERE_PER_CURRENT_LSB)):
                return False
    for i in range(mem.shape[0]):
        m = mem[i]
        p, v, c = pos[i], vel[i], cur[i]
        if math.isfinite(p) and math.isfinite(v) and math.isfinite(c):
            sign, homing = _frame(m)
            qp = _quantise(sign * p, RAD_PER_PULSE, POSITION_CENTER + homing, _I32_MIN, _I32_MAX)
            qv = _quantise(sign * v, RADS_PER_VELOCITY_LSB, 0, _I32_MIN, _I32_MAX)
            qc = _quantise(sign * c, AMPERE_PER_CURRENT_LSB, 0, -32768, 32767)
            _put(m, present_at, qc, 2)
            _put(m, present_at + 2, qv, 4)
            _put(m, present_at + 6, qp, 4)
        else:  # a plant that blew up leaves the last finite reading in place
            qv = _get_s(m, present_at + 2, 4)
        if volt[i] >= 0:
            _put(m, supply_at, volt[i], 2)
        if temp[i] >= 0:
            m[supply_at + 2] = temp[i]
        _put(m, tick_at, tick, 2)
        m[tick_at + 2] = 1 if abs(qv) > _get_u(m, threshold_at, 4) else 0
    return True


def commands(mem, expired, out, torque_at, mode_at, gc_at, gp_at, lim_at):
    """EmulatedServo.command() of every row into out (5, n): driving (1.0/0.0), operating mode, goal
    current A, goal position rad, current limit A (`expired`: bit i set when row i's bus watchdog has
    expired). Returns the bit mask of the rows driving in a position mode (operating mode not 0)."""
    mask = 0
    for i in range(mem.shape[0]):
        m = mem[i]
        driving = m[torque_at] == 1 and not (expired >> i) & 1
        mode = m[mode_at]
        out[0, i] = 1.0 if driving else 0.0
        out[1, i] = mode
        sign, homing = _frame(m)
        out[2, i] = sign * (_get_s(m, gc_at, 2) * AMPERE_PER_CURRENT_LSB)
        out[3, i] = sign * ((_get_s(m, gp_at, 4) - POSITION_CENTER - homing) * RAD_PER_PULSE)
        out[4, i] = _get_u(m, lim_at, 2) * AMPERE_PER_CURRENT_LSB
        if driving and mode != 0:
            mask |= 1 << i
    return mask


def fast_status(mem, rows, ids, address, length, hw_at, table):
    """The Fast Sync Read status packet (crane_io.sim.protocol.fast_status_packet) of the servos in `rows`
    (IDs `ids`): each answers ERR (the alert bit when its Hardware Error Status is not 0) ID DATA (`length`
    bytes of its memory at `address`), byte-stuffed, then the running CRC. Returns (packet, its CRC)."""
    n = rows.shape[0]
    # a block is at most stuffed to 3/2 of its size; header 8 bytes, CRC 2 per block
    buf = np.empty(8 + n * (2 * (2 + length) + 2), dtype=np.uint8)
    buf[0] = 0xFF
    buf[1] = 0xFF
    buf[2] = 0xFD
    buf[3] = 0x00
    buf[4] = 0xFE
    buf[7] = 0x55
    k = 8
    part = np.empty(2 + length, dtype=np.uint8)
    slots = np.empty(n, dtype=np.int64)
    for j in range(n):
        m = mem[rows[j]]
        part[0] = 0x80 if m[hw_at] != 0 else 0
        part[1] = ids[j] & 0xFF
        for a in range(length):
            part[2 + a] = m[address + a]
        start = k
        for b in part:  # stuffing within the block: after every FF FF FD one more FD
            buf[k] = b
            k += 1
            if b == 0xFD and k - start >= 3 and buf[k - 2] == 0xFF and buf[k - 3] == 0xFF:
                buf[k] = 0xFD
                k += 1
        slots[j] = k
        k += 2  # its CRC, filled in below
    length_field = k - 7
    buf[5] = length_field & 0xFF
    buf[6] = (length_field >> 8) & 0xFF
    crc = 0
    i = 0
    for j in range(n):  # the running CRC: every block's CRC covers everything before it
        end = slots[j]
        while i < end:
            crc = _crc_byte(crc, buf[i], table)
            i += 1
        buf[end] = crc & 0xFF
        buf[end + 1] = crc >> 8
    return buf[:k], crc


def reading(q, dq, tau, hq, hdq, hcur, bi, held, kt, n, p, raw, flips, signs, vel_sd, cur_sd, z):
    """ArmPlant.read_lists' position, velocity and current as arrays (crane_io.sim.arm_plant.read_arrays):
    the integrated joints' state (current = motor torque / kt), the held joints', a one-pulse position error
    where the uniform is below p (from the raw PCG64 outputs `raw` as ArmPlant._position_noise derives them,
    or, when `raw` is empty, from `flips` and `signs`), then the velocity's and the current's normal noise
    from `z` in that order."""
    pos, vel, cur = np.zeros(n), np.zeros(n), np.zeros(n)
    for j in range(bi.shape[0]):
        i = bi[j]
        pos[i], vel[i], cur[i] = q[j], dq[j], tau[j] / kt[i]
    for j in range(held.shape[0]):
        i = held[j]
        pos[i], vel[i], cur[i] = hq[j], hdq[j], hcur[j]
    if p > 0:
        for i in range(n):
            if raw.shape[0] > 0:
                f = (raw[i] >> np.uint64(11)) * _TWO_TO_MINUS_53
                v = raw[n + i // 2]
                bit = (v >> np.uint64(31 if i % 2 == 0 else 63)) & np.uint64(1)
                sign = RAD_PER_PULSE if bit else -RAD_PER_PULSE
            else:
                f, sign = flips[i], signs[i]
            pos[i] = pos[i] + (1.0 if f < p else 0.0) * sign
    k = 0
    if vel_sd > 0:
        for i in range(n):
            vel[i] = vel[i] + (0.0 + vel_sd * z[k])
            k += 1
    if cur_sd > 0:
        for i in range(n):
            cur[i] = cur[i] + (0.0 + cur_sd * z[k])
            k += 1
    return pos, vel, cur


# the argument types the simulated chain and ArmPlant.read_arrays call them with (compiled up front,
# crane_io.jit)
_F, _I = "float64[::1]", "int64[::1]"
SIGNATURES = {
    "sensors_into": (f"(uint8[:, ::1], {_F}, {_F}, {_F}, {_I}, {_I}, int64, int64, int64, int64, int64)",),
    "commands": ("(uint8[:, ::1], int64, float64[:, ::1], int64, int64, int64, int64, int64)",),
    "fast_status": (f"(uint8[:, ::1], {_I}, {_I}, int64, int64, int64, {_I})",),
    "reading": (f"({_F}, {_F}, {_F}, {_F}, {_F}, {_F}, {_I}, {_I}, {_F}, int64, float64, uint64[::1], {_F}, "
                f"{_F}, float64, float64, {_F})",),
}


def compiled():
    """(sensors_into, commands, fast_status, reading) compiled with numba, or None without numba. The
    first call of a process compiles them, or loads them from numba's cache (crane_io.jit)."""
    global _COMPILED
    if _COMPILED is None:
        from crane_io.jit import compile_functions

        fns = compile_functions(globals(), ("_quantise", "_put", "_get_u", "_get_s", "_crc_byte", "_frame",
                                            "sensors_into", "commands", "fast_status", "reading"), SIGNATURES)
        _COMPILED = False if fns is None else (fns["sensors_into"], fns["commands"], fns["fast_status"],
                                               fns["reading"])
    return _COMPILED or None


_COMPILED = None
