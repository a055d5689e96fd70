"""The compiled bus codec (crane_io.dynamixel.codec.CompiledCodec): the bus's two control-cycle transfers in
one compiled call each (numba), the Goal Current Sync Write packet built from the amps, and the Fast Sync
Read reply of the Present block checked and converted. It imports numpy and the CRC's layout only.

`goal_current_packet` does what `PlainCodec.goal_current`'s Python loop does, the same float
operations in the same order (no fastmath): per current-mode joint the clamp to its Current Limit, the
rounding half to even, the clamp to the limit's whole steps, the commanded amps, then the parameters (ID,
Goal Current low, high byte) written into a kept packet whose header is already there, the check for
byte stuffing and the CRC-16 (crc_layout's byte table and loop). The bytes are those of
`CranePacketHandler.sync_write_packet`; a packet that would need stuffing, or a command that is not
finite, is left to the caller (which refuses or stuffs).

`present_reply_state` accepts exactly the Fast Sync Read replies `PlainCodec.present_state` accepts (the
expected length and header, no stuffed FF FF FD FD, every status error byte 0, the CRC right, the servos
in request order) and converts the Present Current, Velocity and Position of each servo as it does
(integers to float, then scaled).

Compiled when a bus switches torque on (as crane_io.jit.compile_functions does: explicit signatures,
numba's cache), never lazily at a first packet; without numba `compiled()` is None and the bus keeps the
plain codec.
"""

from __future__ import annotations

import numpy as np

from crane_io.dynamixel.crc_layout import byte_table, crc_step, crc_update  # noqa: F401 (compiled with them)

TABLE = byte_table()  # the kernels' last argument: the bus client's own CRC table (the simulator has its own)
_HEAD_LEN = 12  # a sync write: FF FF FD 00, ID, LEN L H, INST, address L H, data length L H


def goal_current_packet(amps, joints, ids, limits, limits_raw, lsb, buf, sent, table):
    """Fill `buf` (the header in place) with the Goal Current Sync Write of `amps` and `sent` with the
    commanded amps (the joints in `joints` only): the packet's length; -1 when an amp value of those
    joints is not finite, -2 when the packet needs byte stuffing (nothing usable written then)."""
    m = joints.shape[0]
    for k in range(m):
        v = amps[joints[k]]
        if not np.isfinite(v):
            return -1
    p = _HEAD_LEN
    for k in range(m):
        i = joints[k]
        lim = limits[k]
        v = amps[i]
        # min(max(v, -lim), lim) as Python evaluates it
        if not v >= -lim:
            v = -lim
        if not v <= lim:
            v = lim
        raw = np.int64(np.rint(v / lsb))
        lim_raw = limits_raw[k]
        if raw > lim_raw:
            raw = lim_raw
        if raw < -lim_raw:
            raw = -lim_raw
        sent[i] = raw * lsb
        buf[p] = ids[k]
        buf[p + 1] = raw & 0xFF
        buf[p + 2] = (raw >> 8) & 0xFF
        p += 3
    for i in range(5, p - 2):
        if buf[i] == 0xFF and buf[i + 1] == 0xFF and buf[i + 2] == 0xFD:
            return -2
    crc = crc_update(buf, 0, p, np.int64(0), table)
    buf[p] = crc & 0xFF
    buf[p + 1] = crc >> 8
    return p + 2


def _u(data, i, size):
    v = np.int64(0)
    for b in range(size):
        v |= np.int64(data[i + b]) << (8 * b)
    return v


def _expected_reply(data, head, ids, table):
    """`data` is the whole Fast Sync Read reply of the Present block starting with `head`, the servos `ids`
    in request order, no stuffed FF FF FD FD, every status error byte 0 and the CRC right."""
    count = ids.shape[0]
    chunk = 14  # ERR ID, Present Current (2), Velocity (4), Position (4), CRC (2)
    n = 8 + chunk * count
    if len(data) != n:
        return False
    for i in range(8):
        if data[i] != head[i]:
            return False
    for i in range(n - 3):
        if data[i] == 0xFF and data[i + 1] == 0xFF and data[i + 2] == 0xFD and data[i + 3] == 0xFD:
            return False
    for k in range(count):
        s = 8 + k * chunk
        if data[s] != 0 or data[s + 1] != ids[k]:
            return False
    crc = crc_update(data, 0, n - 2, np.int64(0), table)
    return crc == (np.int64(data[n - 2]) | (np.int64(data[n - 1]) << 8))


def present_reply_state(data, head, ids, out, center, rad_per_pulse, rads_per_lsb, amps_per_lsb, table):
    """True when `data` is the whole expected Fast Sync Read reply of the Present block (`head`: its first
    8 bytes; `ids`: the servos in request order) with no status error; then out[0], out[1], out[2] hold
    every servo's position (rad), velocity (rad/s) and current (A). False (and `out` unusable) else."""
    if not _expected_reply(data, head, ids, table):
        return False
    for k in range(ids.shape[0]):
        s = 10 + k * 14  # ERR ID, then the Present block (its CRC after it)
        cur = _u(data, s, 2)
        if cur >= 0x8000:
            cur -= 0x10000
        vel = _u(data, s + 2, 4)
        if vel >= 0x80000000:
            vel -= 0x100000000
        pos = _u(data, s + 6, 4)
        if pos >= 0x80000000:
            pos -= 0x100000000
        out[0, k] = (np.float64(pos) - center) * rad_per_pulse
        out[1, k] = np.float64(vel) * rads_per_lsb
        out[2, k] = np.float64(cur) * amps_per_lsb
    return True


_I, _F, _U8 = "int64[::1]", "float64[::1]", "uint8[::1]"
_PKT = "Bytes(uint8, 1, 'C', readonly=True)"
SIGNATURES = {
    "goal_current_packet": (f"int64({_F}, {_I}, {_I}, {_F}, {_I}, float64, {_U8}, {_F}, {_I})",),
    "present_reply_state": (f"boolean({_PKT}, {_U8}, {_U8}, float64[:, ::1], float64, float64, float64, "
                            f"float64, {_I})",),
}
_COMPILED = None


def compiled():
    """(goal_current_packet, present_reply_state) compiled with numba (their last argument: `TABLE`), or
    None without numba. Compiled (or loaded from numba's cache) at the first call of a process."""
    global _COMPILED
    if _COMPILED is None:
        try:
            from crane_io.jit import compile_functions

            fns = compile_functions(globals(), ("crc_step", "crc_update", "_u", "_expected_reply",
                                                "goal_current_packet", "present_reply_state"),
                                    SIGNATURES, qualname_prefix="cycle_kernel.")
        except Exception:  # noqa: BLE001 - a broken numba install: the Python path, as without numba
            fns = None
        _COMPILED = False if fns is None else (fns["goal_current_packet"], fns["present_reply_state"])
    return _COMPILED or None

