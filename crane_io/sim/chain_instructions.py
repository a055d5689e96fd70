"""The instructions the simulated chain's servos carry out (Protocol 2.0, X-series e-manual), on the
general path (crane_io.sim.chain.SimulatedChain.feed parses the packet and picks the servos that hear it):

- to one servo (`_unicast`): Ping, Read, Write, Reg Write, Action, Reboot, Factory Reset, Clear, each a
  function of `_UNICAST`; a broadcast one is carried out without a reply;
- broadcast: Ping (every servo answers, by ID), Sync Read, Fast Sync Read, Bulk Read, Fast Bulk Read, Sync
  Write, Bulk Write; a write of Goal Current or Goal Position (directly or through Indirect Data) is the
  lockstep tick.

`InstructionHandlers` is a part of SimulatedChain (its memories, servos, clock and plant step).
"""

from __future__ import annotations

from collections.abc import Iterable

from crane_io.dynamixel.control_table import X_SERIES
from crane_io.sim import protocol as p
from crane_io.sim.servo import _I16, _U16, BAUD_CODES, MEMORY_SIZE, S_BOOT, S_ON_BUS, EmulatedServo
from crane_io.sim.servo_indirect import reaches, touches_data

# a write to Goal Current or Goal Position is a lockstep tick
GOAL_CURRENT_ADDRESS = X_SERIES["goal_current"].address
GOAL_POSITION_ADDRESS = X_SERIES["goal_position"].address
ID_ADDRESS = X_SERIES["id"].address
TICK_ADDRESS = X_SERIES["realtime_tick"].address
BAUD_ADDRESS = X_SERIES["baud_rate"].address  # right after the ID (the chain reads both at once)
_LIMIT_AT = X_SERIES["current_limit"].address
BAUD_CODE_OF = {rate: code for code, rate in BAUD_CODES.items()}  # bit/s -> Baud Rate register value


class _Reply:
    """The status packet of an instruction to servo `s`, as its Status Return Level and Return Delay Time
    were when the instruction arrived (before it changed them); none for a broadcast instruction."""

    def __init__(self, s: EmulatedServo, broadcast: bool):
        self.servo, self.broadcast = s, broadcast
        self.level = s.read_register("status_return_level")
        self.delay = s.return_delay_s

    def __call__(self, error: int, data: bytes = b"", min_level: int = 2) -> list[tuple[bytes, float]]:
        if self.broadcast or self.level < min_level:
            return []
        s = self.servo
        return [(p.status_packet(s.id, s.status_error(error), data), self.delay)]


def _ping(s, inst, params, now, reply):
    if reply.broadcast:
        return []
    mn = s.read_register("model_number")
    data = bytes((mn & 0xFF, mn >> 8, s.read_register("firmware_version")))
    return [(p.status_packet(s.id, s.status_error(), data), reply.delay)]


def _read(s, inst, params, now, reply):
    if len(params) != 4:
        return reply(p.ERR_DATA_LENGTH, b"", 1)
    address, length = params[0] | params[1] << 8, params[2] | params[3] << 8
    error, data = s.read(address, length)
    return reply(error, data, 1)


def _write(s, inst, params, now, reply):
    if len(params) < 3:
        return reply(p.ERR_DATA_LENGTH)
    address, data = params[0] | params[1] << 8, params[2:]
    if inst == p.INST_WRITE:
        return reply(s.write(address, data, now))
    return reply(s.reg_write(address, data))


def _action(s, inst, params, now, reply):
    return reply(s.action(now))


def _reboot(s, inst, params, now, reply):
    replies = reply(p.ERR_NONE)
    s.reboot(now)
    return replies


def _factory_reset(s, inst, params, now, reply):
    if len(params) != 1:
        return reply(p.ERR_DATA_LENGTH)
    if reply.broadcast and params[0] == 0xFF:
        return []  # e-manual: broadcast "reset all" is not carried out
    replies = reply(p.ERR_NONE if params[0] in (0x01, 0x02, 0xFF) else p.ERR_DATA_RANGE)
    s.factory_reset(params[0], now)
    return replies


def _clear(s, inst, params, now, reply):
    ok = len(params) == 5 and params[0] == 0x01 and bytes(params[1:]) == b"\x44\x58\x4c\x22"
    if ok and s.read_register("moving"):
        return reply(p.ERR_RESULT_FAIL)
    return reply(p.ERR_NONE if ok else p.ERR_DATA_RANGE)


def _eeprom_write(inst, params) -> bool:
    """A Write or Reg Write into the EEPROM area (address < 64)."""
    return inst in (p.INST_WRITE, p.INST_REG_WRITE) and len(params) >= 2 and (params[0] | params[1] << 8) < 64


_UNICAST = {p.INST_PING: _ping, p.INST_READ: _read, p.INST_WRITE: _write, p.INST_REG_WRITE: _write,
            p.INST_ACTION: _action, p.INST_REBOOT: _reboot, p.INST_FACTORY_RESET: _factory_reset,
            p.INST_CLEAR: _clear}


class InstructionHandlers:
    """SimulatedChain's instruction handling (see the module docstring)."""

    # ---- who hears a packet, and what it does ------------------------------------------------------
    def _hearing(self, baudrate: int | None) -> list[EmulatedServo]:
        if self.fast:  # the same list as long as the port's speed, who is on the bus, IDs and bauds are
            key = (baudrate, self.servo_state[:, S_ON_BUS:S_BOOT + 1].tobytes(),
                   self.memories[:, ID_ADDRESS:BAUD_ADDRESS + 1].tobytes())
            cached = self._hearing_cache
            if cached is not None and cached[0] == key:
                return cached[1]
            servos = self._hearing_of(baudrate)
            self._hearing_cache = (key, servos, self._index_of(servos))
            return servos
        return self._hearing_of(baudrate)

    def _hearing_of(self, baudrate: int | None) -> list[EmulatedServo]:
        # a servo restarting after a Reboot hears nothing (booting_until: see _restarts)
        present = [s for s in self._order if s.on_bus and not s.booting_until]
        if baudrate is None:
            return present
        code = BAUD_CODE_OF.get(baudrate)
        if code is None:  # a speed no servo can be set to
            return [s for s in present if s.baudrate == baudrate]
        return [s for s in present if s.memory[s.baud_address] == code]

    def _restarts(self, now: float) -> None:
        """Servos whose reboot is over by `now` hear the bus again; `_booting`: one is still restarting."""
        if self.servo_state[:, S_BOOT].any():
            for s in self._order:
                if s.booting_until and now >= s.booting_until - 1e-9:
                    s.booting_until = 0.0
        self._booting = bool(self.servo_state[:, S_BOOT].any())

    def _handle(self, pkt: p.Packet, baudrate: int | None,
                now: float | None = None) -> Iterable[tuple[bytes, float]]:
        """`now`: the chain time the packet arrived at (default: the plant's time, as in lockstep)."""
        if now is None:
            now = self.time
        self._restarts(now)
        servos = self._hearing(baudrate)
        if not servos or pkt.instruction == p.INST_STATUS:
            return []
        inst, params = pkt.instruction, pkt.params
        if pkt.id == p.BROADCAST_ID:
            handler = self._broadcast_handlers.get(inst)
            if handler is not None:
                return handler(servos, params, now)
            for s in servos:  # broadcast write, reg write, action, reboot, factory reset: no replies
                s.contact(now)
                self._unicast(s, inst, params, now, broadcast=True)
            self._rekey()
            self._restarted(inst)
            return []
        replies = []
        for s in servos:
            if s.id == pkt.id:
                s.contact(now)
                replies.extend(self._unicast(s, inst, params, now, broadcast=False))
            elif (pkt.id <= p.MAX_ID and s.memory[s.secondary_address] == pkt.id
                  and not _eeprom_write(inst, params)):
                # Secondary ID (e-manual, Secondary(Shadow) ID (12)): carried out without a status packet
                # (the ID takes precedence; 253..255 switch it off; the EEPROM area cannot be written)
                s.contact(now)
                self._unicast(s, inst, params, now, broadcast=True)
        self._rekey()
        self._restarted(inst)
        return replies

    def _restarted(self, inst: int) -> None:
        """After a Reboot or Factory Reset: `_booting` (a servo is restarting) and `_tick_shift` (a servo's
        Realtime Tick counts from its restart: see _shift_ticks)."""
        if inst in (p.INST_REBOOT, p.INST_FACTORY_RESET):
            self._booting = self._booting or bool(self.servo_state[:, S_BOOT].any())
            self._tick_shift = any(s.tick_origin_ms for s in self._order)

    def _shift_ticks(self) -> None:
        """The Realtime Tick the compiled path wrote from the chain's clock, counted from each servo's
        restart."""
        if self._tick_shift:
            for s in self._order:
                if s.tick_origin_ms:
                    tick = _U16.unpack_from(s.memory, TICK_ADDRESS)[0]
                    _U16.pack_into(s.memory, TICK_ADDRESS, (tick - s.tick_origin_ms) % 32768)

    def _crc_replies(self, baudrate: int | None, now: float | None) -> list[tuple[bytes, float]]:
        """The status packets (CRC Error 0x03, e-manual Protocol 2.0 "Status Packet") of the servos that
        heard an instruction with a wrong CRC addressed to their ID; nothing is carried out, and a
        broadcast one gets no reply. Drains the parser's `crc_failed`."""
        failed, self.parser.crc_failed = self.parser.crc_failed, []
        if now is None:
            now = self.time
        self._restarts(now)
        replies = []
        for sid, inst in failed:
            if sid == p.BROADCAST_ID or inst == p.INST_STATUS:
                continue
            for s in self._hearing(baudrate):
                if s.id == sid:
                    min_level = 0 if inst == p.INST_PING else 1 if inst == p.INST_READ else 2
                    replies.extend(_Reply(s, False)(p.ERR_CRC, b"", min_level))
        return replies

    # ---- instructions to one servo --------------------------------------------------------------
    def _unicast(self, s: EmulatedServo, inst: int, params: bytes, now: float,
                 broadcast: bool) -> list[tuple[bytes, float]]:
        reply = _Reply(s, broadcast)
        handler = _UNICAST.get(inst)
        if handler is None:
            return reply(p.ERR_INSTRUCTION)
        return handler(s, inst, params, now, reply)

    # ---- broadcast instructions ------------------------------------------------------------------
    def _broadcast_ping(self, servos, params, now):
        replies = []
        for s in sorted(servos, key=lambda s: s.id):
            s.contact(now)
            replies.extend(self._unicast(s, p.INST_PING, b"", now, broadcast=False))
        return replies

    def _by_id(self, servos, sid):
        for s in servos:
            if s.id == sid:
                return s
        return None

    def _index(self, servos) -> dict[int, EmulatedServo]:
        """ID -> servo among `servos`; with duplicate IDs the first one wins (as in _by_id). Kept with the
        list _hearing returned last (IDs and who hears have not changed since: see _hearing) when that
        list is `servos` and no ID was written since."""
        cached = self._hearing_cache
        if (cached is not None and cached[1] is servos
                and cached[0][2] == self.memories[:, ID_ADDRESS:BAUD_ADDRESS + 1].tobytes()):
            return cached[2]
        return self._index_of(servos)

    @staticmethod
    def _index_of(servos) -> dict[int, EmulatedServo]:
        index: dict[int, EmulatedServo] = {}
        for s in servos:
            index.setdefault(s.id, s)
        return index

    def _sync_read(self, servos, params, now):
        if len(params) < 5:
            return []
        address, length = params[0] | params[1] << 8, params[2] | params[3] << 8
        return self._read_each(servos, [(sid, address, length) for sid in params[4:]], now)

    def _read_each(self, servos, requests, now):
        """One status packet per (id, address, length) request, in order, from the servos that answer."""
        replies = []
        for sid, address, length in requests:
            s = self._by_id(servos, sid)
            if s is None:
                continue
            s.contact(now)
            if s.read_register("status_return_level") < 1:
                continue
            error, data = s.read(address, length)
            replies.append((p.status_packet(sid, s.status_error(error), data), s.return_delay_s))
        return replies

    def _fast_blocks(self, servos, requests, now):
        """(blocks, complete) of a fast read; the chain breaks at the first silent servo."""
        blocks = []
        index = self._index(servos)
        for sid, address, length in requests:
            s = index.get(sid)
            # Status Return Level 0: no reply but to Ping (e-manual, Status Return Level (68))
            if s is None or not s.supports_fast_sync_read or s.memory[s.srl_address] == 0:
                return blocks, False
            s.contact(now)
            error, data = s.read(address, length)
            blocks.append((s.status_error(error), sid, data))
        return blocks, True

    def _fast_sync_read(self, servos, params, now):
        if len(params) < 5:
            return []
        if not self.fast_sync_read:
            self.stats.ignored_fast_sync_reads += 1
            return []
        address, length = params[0] | params[1] << 8, params[2] | params[3] << 8
        ids = list(params[4:])
        fast = self._fast()
        if fast is not None and length > 0 and address + length <= MEMORY_SIZE:
            reply = self._fast_sync_reply(fast, servos, ids, address, length, now)
            if reply is not None:
                return reply
        blocks, complete = self._fast_blocks(servos, [(i, address, length) for i in ids], now)
        if not blocks:
            return []
        first = self._by_id(servos, ids[0])
        delay = first.return_delay_s if first is not None else 0.0
        if complete:
            return [(p.fast_status_packet(blocks), delay)]
        return [(p.fast_status_prefix(blocks, len(ids), length), delay)]

    def _bulk_requests(self, params):
        return [(params[i], params[i + 1] | params[i + 2] << 8, params[i + 3] | params[i + 4] << 8)
                for i in range(0, len(params) - len(params) % 5, 5)]

    def _bulk_read(self, servos, params, now):
        return self._read_each(servos, self._bulk_requests(params), now)

    def _fast_bulk_read(self, servos, params, now):
        if not self.fast_sync_read:
            self.stats.ignored_fast_sync_reads += 1
            return []
        requests = self._bulk_requests(params)
        blocks, complete = self._fast_blocks(servos, requests, now)
        if not blocks or not complete:
            return []
        first = self._by_id(servos, requests[0][0])
        return [(p.fast_status_packet(blocks), first.return_delay_s)]

    def _sync_write(self, servos, params, now):
        if len(params) < 4:
            return []
        address, length = params[0] | params[1] << 8, params[2] | params[3] << 8
        body = params[4:]
        if length == 0:
            return []
        writes_id = address <= ID_ADDRESS < address + length  # IDs may change within this packet
        index = None if writes_id else self._index(servos)
        if address == GOAL_CURRENT_ADDRESS and length == 2 and self._fast() is not None:
            # the fast path: EmulatedServo.write of Goal Current (2 bytes, signed) without the general
            # checks that cannot fail for it (RW, RAM, any int16 in range): refused while the watchdog
            # has expired or beyond +-Current Limit (Data Limit Error; a Sync Write has no reply)
            for k in range(0, len(body) - len(body) % 3, 3):
                s = index.get(body[k])
                if s is not None:
                    s.contact(now)
                    if not s.watchdog_expired:
                        value = body[k + 1] | body[k + 2] << 8
                        if value & 0x8000:
                            value -= 0x10000
                        limit = _U16.unpack_from(s.memory, _LIMIT_AT)[0]
                        if -limit <= value <= limit:
                            _I16.pack_into(s.memory, GOAL_CURRENT_ADDRESS, value)
            self._lockstep_tick([(address, length)])
            return []
        for k in range(0, len(body) - len(body) % (1 + length), 1 + length):
            s = self._by_id(servos, body[k]) if writes_id else index.get(body[k])
            if s is not None:
                s.contact(now)
                s.write(address, body[k + 1:k + 1 + length], now)
        if writes_id:
            self._rekey()
        self._lockstep_tick([(address, length)])
        return []

    def _bulk_write(self, servos, params, now):
        i, spans = 0, []
        while i + 5 <= len(params):
            sid, address = params[i], params[i + 1] | params[i + 2] << 8
            length = params[i + 3] | params[i + 4] << 8
            data = params[i + 5:i + 5 + length]
            i += 5 + length
            if len(data) != length:
                break
            s = self._by_id(servos, sid)
            if s is not None:
                s.contact(now)
                s.write(address, data, now)
                spans.append((address, length))
        self._rekey()
        self._lockstep_tick(spans)
        return []

    def _lockstep_tick(self, spans) -> None:
        if self.clock != "lockstep":
            return
        goals = (GOAL_CURRENT_ADDRESS, GOAL_POSITION_ADDRESS)
        for address, length in spans:
            if any(address <= a < address + length for a in goals) or (
                    touches_data(address, address + length)
                    and any(reaches(s, address, length, goals) for s in self._order)):
                self._step(self.period_s)
                return
