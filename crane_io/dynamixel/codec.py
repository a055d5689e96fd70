"""The bus codec: the control cycle's two packets, as a backend of `DynamixelBus` (crane_io.dynamixel.bus).

One interface, two implementations giving the same bytes and the same floats, bit for bit:

- `PlainCodec`, the reference: Python lists and numpy;
- `CompiledCodec`: one compiled call per packet (crane_io.dynamixel.cycle_kernel, numba).

A bus reads with the plain codec until it switches torque on; then it takes the compiled one when numba
is there (`compiled_codec`), so a bus that never drives the arm (a check, a ping) compiles nothing.
tests/test_host_cycle_kernel.py holds the two to each other.

The interface:

- `expect(head, ids)`: the Fast Sync Read reply of the Present block to accept from now on (its first 8
  bytes and the servo IDs in request order; None: accept none);
- `present_state(data, out) -> bool`: True when `data` is that whole reply with a good CRC, no byte
  stuffing and every status error byte 0; then out[0], out[1], out[2] hold each servo's position (rad),
  velocity (rad/s) and current (A). False otherwise (the reader's general path takes the reply);
- `plan_currents(plan)`: the current-mode joints as (index, servo ID, Current Limit in A, in whole Goal
  Current steps), for the writes that follow;
- `goal_current(amps) -> (packet, params, sent) | None`: the Goal Current Sync Write of `amps` ((n,) A in
  joint order) clamped to the limits: the finished packet (None when it needs byte stuffing: then the
  caller sends `params`, ID and Goal Current low, high byte per joint, the SDK's way) and the amps
  commanded; None when `amps` has the wrong shape or a current-mode joint's value is not finite (nothing
  usable: the caller refuses the command).
"""

from __future__ import annotations

import math

import numpy as np

from crane_io.dynamixel import cycle_kernel, units
from crane_io.dynamixel.control_table import PRESENT_BLOCK_SIZE, X_SERIES
from crane_io.dynamixel.packets import CranePacketHandler, crc16
from crane_io.dynamixel.status_read import FIRST_PARAM, STUFFED

# one servo's part of the Fast Sync Read reply of the Present block: ERR ID DATA CRC
FAST_RECORD = np.dtype([("error", "u1"), ("id", "u1"), ("current", "<i2"), ("velocity", "<i4"),
                         ("position", "<i4"), ("crc", "<u2")])
assert FAST_RECORD.itemsize == PRESENT_BLOCK_SIZE + 4
_CHUNK = PRESENT_BLOCK_SIZE + 4
_GOAL_CURRENT = X_SERIES["goal_current"]
_LSB = units.AMPERE_PER_CURRENT_LSB
# the reply kernel's arguments after `out`: the unit conversions and the host's CRC table
_REPLY_CONSTANTS = (float(units.POSITION_CENTER), units.RAD_PER_PULSE, units.RADS_PER_VELOCITY_LSB,
                    units.AMPERE_PER_CURRENT_LSB, cycle_kernel.TABLE)


class PlainCodec:
    """The reference codec (see the module docstring)."""

    def __init__(self, ph: CranePacketHandler, n_servos: int):
        self._ph = ph
        self._n = n_servos
        self._head: bytes | None = None
        self._ids: bytes | None = None
        self._total = 0
        self._no_errors = b""
        self._plan: list[tuple] = []

    # ---- the Fast Sync Read reply of the Present block ----------------------------------------------
    def expect(self, head: bytes, ids: bytes | None) -> None:
        self._head, self._ids = head, ids
        count = 0 if ids is None else len(ids)
        self._total = 8 + _CHUNK * count
        self._no_errors = bytes(count)

    def present_state(self, data: bytes, out: np.ndarray) -> bool:
        ids = self._ids
        if ids is None or not (
                len(data) == self._total and data.startswith(self._head) and STUFFED not in data
                and data[8::_CHUNK] == self._no_errors and crc16(data[:-2]) == (data[-2] | (data[-1] << 8))
                and data[9::_CHUNK] == ids):
            return False
        rec = np.frombuffer(data, dtype=FAST_RECORD, count=len(ids), offset=FIRST_PARAM)
        # the arithmetic of units.position_to_rad etc. (integers converted to float, then scaled)
        out[0] = (rec["position"] - float(units.POSITION_CENTER)) * units.RAD_PER_PULSE
        out[1] = rec["velocity"] * units.RADS_PER_VELOCITY_LSB
        out[2] = rec["current"] * units.AMPERE_PER_CURRENT_LSB
        return True

    # ---- the Goal Current Sync Write ----------------------------------------------------------------
    def plan_currents(self, plan: list[tuple]) -> None:
        self._plan = plan

    def goal_current(self, amps) -> tuple[bytes | None, bytes, np.ndarray] | None:
        arr = np.asarray(amps, dtype=float)
        if arr.shape != (self._n,):
            return None
        values = arr.tolist()
        sent = [0.0] * self._n
        params = []
        isfinite = math.isfinite
        for i, sid, lim, lim_raw in self._plan:
            v = values[i]
            if not isfinite(v):
                return None
            # scalar form of units.ampere_to_current(np.clip(...)): same rounding (half to even)
            raw = round(min(max(v, -lim), lim) / _LSB)
            raw = max(-lim_raw, min(lim_raw, raw))
            sent[i] = raw * _LSB
            params += (sid, raw & 0xFF, (raw >> 8) & 0xFF)
        # the Sync Write packet as GroupSyncWrite + CranePacketHandler make it (a kept header, the
        # parameters, the CRC); None when it needs byte stuffing
        cur = _GOAL_CURRENT
        packet = self._ph.sync_write_packet(cur.address, cur.size, params) if params else None
        return packet, bytes(params), np.array(sent)


class CompiledCodec(PlainCodec):
    """The compiled codec: cycle_kernel's two calls (`kernels`: cycle_kernel.compiled()). A plan or a reply
    those calls are not made for (no current-mode joint, a servo ID above 255, a reply that is not a bytes
    object) is the plain codec's."""

    def __init__(self, ph: CranePacketHandler, n_servos: int, kernels: tuple):
        super().__init__(ph, n_servos)
        self._packet_kernel, self._reply_kernel = kernels
        self._reply_args: tuple | None = None  # (head, ids) as arrays
        self._current_args: tuple | None = None  # the packet kernel's arguments after the amps

    def expect(self, head: bytes, ids: bytes | None) -> None:
        super().expect(head, ids)
        self._reply_args = None if ids is None else (np.frombuffer(head, dtype=np.uint8),
                                                     np.frombuffer(ids, dtype=np.uint8))

    def present_state(self, data: bytes, out: np.ndarray) -> bool:
        args = self._reply_args
        if args is None or type(data) is not bytes:
            return super().present_state(data, out)
        return self._reply_kernel(data, args[0], args[1], out, *_REPLY_CONSTANTS)

    def plan_currents(self, plan: list[tuple]) -> None:
        super().plan_currents(plan)
        self._current_args = None
        if not plan or any(sid > 0xFF for _i, sid, _l, _r in plan):
            return
        head = self._ph.sync_write_header(_GOAL_CURRENT.address, _GOAL_CURRENT.size, 3 * len(plan))
        buf = np.zeros(len(head) + 3 * len(plan) + 2, dtype=np.uint8)
        buf[:len(head)] = np.frombuffer(head, dtype=np.uint8)
        column = [np.array(c) for c in zip(*plan)]
        self._current_args = (column[0].astype(np.int64), column[1].astype(np.int64), column[2].astype(float),
                              column[3].astype(np.int64), _LSB, buf)

    def goal_current(self, amps) -> tuple[bytes | None, bytes, np.ndarray] | None:
        args = self._current_args
        if args is None:
            return super().goal_current(amps)
        arr = np.ascontiguousarray(amps, dtype=float)
        if arr.shape != (self._n,):
            return None
        sent = np.zeros(self._n)
        size = self._packet_kernel(arr, *args, sent, cycle_kernel.TABLE)
        buf = args[-1]
        if size > 0:
            packet = buf.tobytes()
            return packet, packet[12:-2], sent
        if size == -2:  # the parameters are written: the packet needs byte stuffing
            return None, buf[12:-2].tobytes(), sent
        return None  # a value that is not finite


def compiled_codec(ph: CranePacketHandler, n_servos: int) -> CompiledCodec | None:
    """The compiled codec, compiled (or loaded from numba's cache) now; None without numba."""
    kernels = cycle_kernel.compiled()
    return None if kernels is None else CompiledCodec(ph, n_servos, kernels)
