"""A chain of emulated X-series servos on one Protocol 2.0 bus, with a plant behind them.

`SimulatedChain.feed(bytes)` takes what the host puts on the wire and returns what the servos put
back: status packets with real CRCs, byte stuffing and error bytes. Transports (crane_io.sim.transport:
an in-process pyserial URL `dxlsim://NAME`, or a pseudo-terminal) only move bytes.

Two clocks:
- "lockstep": the plant advances exactly `period_s` each time a Sync Write (or Bulk Write) of Goal
  Current or Goal Position arrives, after the written values are applied. Deterministic and as fast
  as the host can talk. `advance(seconds)` lets time pass without a write (a host that stalls).
  `set_clock("wall")` switches a running chain to the wall clock (and back) without a time jump.
- "wall": whenever the chain is touched, the plant is stepped (substeps of at most `max_substep_s`)
  toward time.monotonic(), for at most `step_budget_s` of real time per touch or packet, so a reply
  never waits long for the physics. A plant that falls further than `max_lag_s` behind real time
  (the machine is too slow or too busy, or nobody touched the chain for a while) is not caught up:
  simulated time slips ahead to now, and `stats` counts the slips (`slips`, `slip_s`, `max_slip_s`).
  Replies leave each servo's Return Delay Time after the instruction arrived (a real sleep).
The bus watchdogs and the Realtime Tick count the chain's time in both modes; on the wall clock a
servo's silence is measured from the real time each instruction arrived, so a slip never makes a
watchdog expire while the host keeps talking, and a host that really went silent is still caught.

Hooks for fault-injection tests: `servos`, `remove_servo`/`restore_servo`, `reply_filter`, `stats`.

The instructions the servos carry out are in crane_io.sim.chain_instructions, the lockstep Sync Write's
compiled path in chain_lockstep, the plant's faster methods and the compiled calls by name in chain_paths.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from crane_io.dynamixel.control_table import X_SERIES, XM430_W350, ServoModel
from crane_io.errors import ConfigError
from crane_io.sim import chain_kernel, lockstep_kernel
from crane_io.sim import protocol as p
from crane_io.sim.chain_instructions import (
    BAUD_CODE_OF,
    GOAL_CURRENT_ADDRESS,
    GOAL_POSITION_ADDRESS,
    InstructionHandlers,
)
from crane_io.sim.chain_lockstep import LockstepWrites
from crane_io.sim.chain_paths import ChainCalls, LockstepCalls, PlantPaths, fast_layout, plant_paths
from crane_io.sim.plant_api import ActuatorCommand, Plant
from crane_io.sim.servo import MEMORY_SIZE, STATE_SIZE, EmulatedServo
from crane_io.sim.servo_indirect import touches_data

__all__ = ["GOAL_CURRENT_ADDRESS", "GOAL_POSITION_ADDRESS", "ChainStats", "SimulatedChain"]
# the items the fast path reads and writes in every servo's memory (chain_paths.fast_layout checks them)
_TORQUE_AT, _MODE_AT = X_SERIES["torque_enable"].address, X_SERIES["operating_mode"].address
_LIMIT_AT, _HW_ERROR_AT = X_SERIES["current_limit"].address, X_SERIES["hardware_error_status"].address
_PRESENT_AT, _TICK_AT = X_SERIES["present_current"].address, X_SERIES["realtime_tick"].address
_SUPPLY_AT, _THRESHOLD_AT = X_SERIES["present_input_voltage"].address, X_SERIES["moving_threshold"].address
STEP_BUDGET_S = 0.001  # wall clock: most real time spent stepping the plant per packet or touch
MAX_LAG_S = 0.1  # wall clock: a plant further behind real time than this slips ahead to now


@dataclass
class ChainStats:
    """Counters of what crossed the simulated bus."""

    packets_received: int = 0  # instruction packets with a good CRC
    replies_sent: int = 0  # reply chunks (status packets) that went on the wire
    replies_dropped: int = 0  # reply chunks the reply_filter dropped
    crc_errors: int = 0  # packets whose CRC did not match (not carried out; see _crc_replies)
    bytes_received: int = 0
    bytes_sent: int = 0
    plant_steps: int = 0
    ignored_fast_sync_reads: int = 0  # Fast Sync Reads left unanswered (fast_sync_read=False)
    # wall clock: simulated time that was skipped because the plant could not keep up with real time
    slips: int = 0  # how many times simulated time jumped ahead
    slip_s: float = 0.0  # seconds skipped in all
    max_slip_s: float = 0.0  # the largest single jump, seconds


class SimulatedChain(InstructionHandlers, LockstepWrites):
    """Emulated servos (one per plant joint, in `plant.servo_ids` order) on one bus."""

    def __init__(
        self,
        plant: Plant,
        models: Mapping[int, ServoModel | str] | None = None,
        *,
        clock: str = "lockstep",
        period_s: float = 0.002,
        fast_sync_read: bool = True,
        baud_code: int = 5,
        return_delay_time: int | None = None,
        max_substep_s: float = 0.001,
        step_budget_s: float = STEP_BUDGET_S,
        max_lag_s: float = MAX_LAG_S,
        fast: bool | None = None,
    ):
        if clock not in ("lockstep", "wall"):
            raise ConfigError(f"clock must be 'lockstep' or 'wall', not {clock!r}")
        if not period_s > 0:
            raise ConfigError(f"the control period must be positive, got {period_s}")
        if not step_budget_s > 0 or not max_lag_s >= 0:
            raise ConfigError(f"step_budget_s must be positive and max_lag_s 0 or more, got "
                              f"{step_budget_s} and {max_lag_s}")
        self.plant = plant
        self.clock = clock
        self.period_s = float(period_s)
        self.fast_sync_read = fast_sync_read
        self.max_substep_s = float(max_substep_s)
        self.step_budget_s = float(step_budget_s)
        self.max_lag_s = float(max_lag_s)
        models = dict(models or {})
        # every servo's control table is a row of one array (the fast path reads and writes them at once)
        self.memories = np.zeros((len(plant.servo_ids), MEMORY_SIZE), dtype=np.uint8)
        # and every servo's state outside its control table (contact time, watchdog, on the bus, fast reads)
        self.servo_state = np.zeros((len(plant.servo_ids), STATE_SIZE))
        self._order: list[EmulatedServo] = [
            EmulatedServo(sid, models.get(sid, XM430_W350), baud_code=baud_code,
                          return_delay_time=return_delay_time, memory=self.memories[i],
                          state=self.servo_state[i])
            for i, sid in enumerate(plant.servo_ids)
        ]
        for i, s in enumerate(self._order):
            s.chain_row = i
        watch = getattr(plant, "watch_servo_limits", None)  # its health model reads their limits
        if watch is not None:
            watch(self.memories)
        if fast is None:
            fast = os.environ.get("CRANE_CHAIN_FAST", "1") != "0"
        # the compiled functions, loaded (or compiled) now, not at the first packet a host waits on
        # (crane_io.jit); None without numba, and then no fast path
        fns = chain_kernel.compiled() if fast and fast_layout(self._order) else None
        self._fast_fns = None if fns is None else ChainCalls(*fns)
        # the lockstep cycle's usual packets handled whole (crane_io.sim.lockstep_kernel; see feed)
        fns = lockstep_kernel.compiled() if self._fast_fns is not None else None
        self._lockstep_fns = None if fns is None else LockstepCalls(*fns)
        self.fast = self._fast_fns is not None and self._lockstep_fns is not None
        self._reply_buffer = np.zeros(4096, dtype=np.uint8)  # the fast Fast Sync Read reply is built here
        self._sensed = np.zeros((3, len(self._order)))  # lockstep_kernel.sense's reading (see _read_plant)
        self._noise_work = np.zeros(4 * len(self._order))  # lockstep_kernel.sync_write_read's noise
        none = np.zeros(0)  # a plant that lockstep_kernel does not step: its arguments' types
        self._no_plant_args = (0, none, none, none, np.zeros(4), none, none, np.zeros(11, dtype=np.int64),
                               0.0, 1, 0.0)
        self._commands = np.zeros((5, len(self._order)))
        self._supply_key: tuple = (None, None)  # the last (voltages, temperatures) and their raw values
        self._supply_raw = (None, None)
        self._hearing_cache = None  # (key, servos, index): see _hearing
        self._fast_read_kept = None  # see _fast_sync_reply
        self._booting = False  # a servo is restarting after a Reboot (the lockstep fast path waits)
        self._tick_shift = False  # a servo restarted: its Realtime Tick counts from then (see _shift_ticks)
        self.servos: dict[int, EmulatedServo] = {}
        self._rekey()
        self.reply_filter: Callable[[bytes], bytes | None] | None = None
        self._broadcast_handlers = {
            p.INST_PING: self._broadcast_ping,
            p.INST_SYNC_READ: self._sync_read,
            p.INST_FAST_SYNC_READ: self._fast_sync_read,
            p.INST_SYNC_WRITE: self._sync_write,
            p.INST_BULK_READ: self._bulk_read,
            p.INST_FAST_BULK_READ: self._fast_bulk_read,
            p.INST_BULK_WRITE: self._bulk_write,
        }
        self.stats = ChainStats()
        self.parser = p.PacketParser()
        self.time = 0.0
        self._t0 = time.monotonic()
        self._lock = threading.RLock()
        self._plant_paths: tuple = (None, None)  # (plant, its PlantPaths): see _paths_of
        self._read_plant()

    @classmethod
    def for_arm(cls, arm, plant: Plant, **kwargs) -> SimulatedChain:
        """A chain whose servo models follow an ArmDescription (crane_io.description)."""
        return cls(plant, {j.servo_id: j.model for j in arm.joints}, **kwargs)

    # ---- the fast path ---------------------------------------------------------------------------
    def _fast(self):
        """The compiled functions when the fast path is on, else None."""
        return self._fast_fns if self.fast else None

    # ---- fault-injection hooks ------------------------------------------------------------------
    def remove_servo(self, servo_id: int) -> None:
        """The servo vanishes from the bus: it neither hears instructions nor answers."""
        self._find(servo_id).on_bus = False

    def restore_servo(self, servo_id: int) -> None:
        self._find(servo_id).on_bus = True

    def _find(self, servo_id: int) -> EmulatedServo:
        for s in self._order:
            if s.id == servo_id:
                return s
        raise KeyError(f"no simulated servo with ID {servo_id}")

    def _rekey(self) -> None:
        self.servos = {s.id: s for s in self._order}

    # ---- time --------------------------------------------------------------------------------
    def touch(self) -> float:
        """Wall clock: step the plant toward now, for at most `step_budget_s` of real time (transports
        call this while idle). Returns how far the plant is still behind real time, in seconds (0 on
        the lockstep clock): call again soon when that is more than a substep."""
        with self._lock:
            if self.clock != "wall":
                return 0.0
            target = self._wall_time()
            self._catch_up(target)
            return max(0.0, target - self.time)

    @property
    def lag_s(self) -> float:
        """Wall clock: how far the plant is behind real time, in seconds (0 on the lockstep clock)."""
        if self.clock != "wall":
            return 0.0
        return max(0.0, self._wall_time() - self.time)

    def set_clock(self, clock: str) -> None:
        """Switch between "lockstep" and "wall" while running; simulated time continues from where it
        is (wall: from now on the chain follows time.monotonic(), starting at `self.time`)."""
        if clock not in ("lockstep", "wall"):
            raise ConfigError(f"clock must be 'lockstep' or 'wall', not {clock!r}")
        with self._lock:
            self._t0 = time.monotonic() - self.time
            self.clock = clock

    def advance(self, seconds: float) -> None:
        """Let `seconds` of simulated time pass in control periods without any instruction."""
        with self._lock:
            steps = int(round(seconds / self.period_s))
            for _ in range(steps):
                self._step(self.period_s)

    def servo_time(self) -> float:
        """The time the servos' watchdogs count: the simulated time in lockstep, real time (continuous
        across set_clock) on the wall clock."""
        return self.time if self.clock == "lockstep" else self._wall_time()

    def _wall_time(self) -> float:
        """Wall clock: the simulated time it is now, were the plant never behind."""
        return time.monotonic() - self._t0

    def _catch_up(self, target: float) -> None:
        """Step toward `target` in substeps of at most max_substep_s until there or until the budget of
        real time is spent (at least one substep); then, if the plant is still more than max_lag_s
        behind, skip simulated time ahead to `target` (a slip) instead of making anyone wait."""
        deadline = time.perf_counter() + self.step_budget_s
        while target - self.time > 1e-9:
            self._step(min(target - self.time, self.max_substep_s))
            if time.perf_counter() >= deadline:
                break
        lag = target - self.time
        if lag > self.max_lag_s:
            self._slip(target)

    def _slip(self, target: float) -> None:
        jump = target - self.time
        self.time = target
        st = self.stats
        st.slips += 1
        st.slip_s += jump
        st.max_slip_s = max(st.max_slip_s, jump)
        for s in self._order:  # a host that was silent through the skipped time is still caught
            s.check_watchdog(target)
        self._read_plant()

    def actuator_command(self) -> ActuatorCommand:
        cmds = [s.command() for s in self._order]
        driving, mode, goal_cur, goal_pos, gains, limit = zip(*cmds)
        return ActuatorCommand(
            torque_enabled=np.array(driving, dtype=bool),
            operating_mode=np.array(mode, dtype=int),
            goal_current=np.array(goal_cur, dtype=float),
            goal_position=np.array(goal_pos, dtype=float),
            position_gains=np.array(gains, dtype=float).reshape(len(cmds), 3),
            current_limit=np.array(limit, dtype=float),
        )

    def _plant_lists(self) -> tuple[list, list, list, list, list]:
        """The plant's reading as (position, velocity, current, voltage, temperature) lists of floats
        (None for a voltage or temperature the plant does not give)."""
        plant = self.plant
        reader = self._paths_of(plant).read_lists
        if reader is not None:
            return reader()
        reading = plant.read()
        def floats(values):
            return [None] * len(self._order) if values is None else np.asarray(values, dtype=float).tolist()

        return (floats(reading.position), floats(reading.velocity), floats(reading.current),
                floats(reading.voltage), floats(reading.temperature))

    def _paths_of(self, plant) -> PlantPaths:
        """The plant's faster methods (crane_io.sim.chain_paths.plant_paths), found once per plant."""
        kept_for, paths = self._plant_paths
        if kept_for is not plant:  # first use, or the plant was replaced
            paths = plant_paths(plant)
            self._plant_paths = (plant, paths)
        return paths

    def _step(self, dt: float) -> None:
        now = self.time
        expired = 0  # bit i: servo i's bus watchdog has expired
        for i, s in enumerate(self._order):
            s.check_watchdog(now)
            if s.watchdog_expired:
                expired |= 1 << i
        plant = self.plant
        paths = self._paths_of(plant)
        step_lists = paths.step_lists
        fast = self._fast()
        if fast is not None and paths.step_command is not None:  # the commands read out at once
            cmds = self._commands
            mask = fast.commands(self.memories, expired, cmds, _TORQUE_AT, _MODE_AT, GOAL_CURRENT_ADDRESS,
                                 GOAL_POSITION_ADDRESS, _LIMIT_AT)
            done = paths.step_command(cmds, mask, dt)
        else:
            done = False
        if not done:  # step_command did not step the plant (no fast path, or a case it hands back)
            if step_lists is not None:  # the commands as lists, as actuator_command's arrays would hold them
                step_lists(*zip(*[s.command() for s in self._order]), dt)
            else:
                plant.step(self.actuator_command(), dt)
        self.time += dt
        self.stats.plant_steps += 1
        self._read_plant()

    def _read_plant(self) -> None:
        now = self.time
        fast = self._fast()
        paths = self._paths_of(self.plant)
        sensed = paths.kernel_read_args() if fast is not None and paths.kernel_read_args is not None else None
        if sensed is not None:  # read_arrays + sensors_into in one compiled call (lockstep_kernel.sense)
            volt, temp = self._supply(sensed[10], sensed[11])
            done = self._lockstep_fns.sense(self.memories, *sensed[:10], volt, temp, int(now * 1000) % 32768,
                                            self._sensed)
            if done:
                self._shift_ticks()
            else:
                position, velocity, current = self._sensed.copy()
                voltage, temperature = sensed[10], sensed[11]
        elif fast is not None:
            reader = paths.read_arrays
            if reader is not None:  # the plant's reading as arrays, into every servo's memory at once
                position, velocity, current, voltage, temperature = reader()
            else:
                position, velocity, current, voltage, temperature = self._plant_lists()
            volt, temp = self._supply(voltage, temperature)
            if reader is None:
                position, velocity, current = (np.array(x, dtype=float)
                                               for x in (position, velocity, current))
            tick = int(now * 1000) % 32768
            done = fast.sensors_into(self.memories, position, velocity, current, volt, temp, tick,
                                     _PRESENT_AT, _TICK_AT, _SUPPLY_AT, _THRESHOLD_AT)
            if done:
                self._shift_ticks()
        else:
            position, velocity, current, voltage, temperature = self._plant_lists()
        if fast is None or not done:
            if fast is not None:
                position, velocity, current = position.tolist(), velocity.tolist(), current.tolist()
            self._set_sensors(position, velocity, current, voltage, temperature, now)
        self._plant_errors()

    def _set_sensors(self, position, velocity, current, voltage, temperature, now: float) -> None:
        for s, pos, vel, cur, volt, temp in zip(self._order, position, velocity, current, voltage,
                                                temperature):
            s.set_sensors(pos, vel, cur, now, volt, temp)

    def _plant_errors(self) -> None:
        """The plant's hardware errors latched into its servos."""
        errors = self.plant.hardware_errors()
        if errors:
            for sid, bits in errors.items():
                for s in self._order:
                    if s.id == sid and bits:
                        s.raise_hardware_error(bits)

    def _supply(self, voltage, temperature) -> tuple[np.ndarray, np.ndarray]:
        """The Present Input Voltage and Temperature register values set_sensors would write (-1: none)."""
        key = self._supply_key
        if voltage == key[0] and temperature == key[1]:
            return self._supply_raw
        volt = [-1 if v is None else max(0, round(v * 10)) & 0xFFFF for v in voltage]
        temp = [-1 if t is None else max(0, round(t)) & 0xFF for t in temperature]
        raw = (np.array(volt, dtype=np.int64), np.array(temp, dtype=np.int64))
        self._supply_key, self._supply_raw = (list(voltage), list(temperature)), raw
        return raw

    # ---- the wire ------------------------------------------------------------------------------
    def feed(self, data: bytes, baudrate: int | None = None) -> bytes:
        """Bytes from the host in, the servos' reply bytes out (possibly empty).

        `baudrate`: the host port's speed when the transport knows it; servos set to another baud
        rate do not understand the host (and stay silent)."""
        with self._lock:
            if (self.fast and self.clock == "lockstep" and type(data) is bytes and len(data) > 7
                    and not self.parser.buffer and not self._booting):
                reply = self._lockstep_packet(data, baudrate)
                if reply is not None:
                    return reply
            wall = time.monotonic()
            now = None
            if self.clock == "wall":
                now = wall - self._t0
                self._catch_up(now)
                for s in self._order:  # a servo's silence ends when this packet arrived, not later
                    s.check_watchdog(now)
            self.stats.bytes_received += len(data)
            crc_before = self.parser.crc_errors
            packets = self.parser.feed(data, now=wall)
            self.stats.crc_errors += self.parser.crc_errors - crc_before
            out = bytearray()
            due = wall  # Return Delay Times count from the instruction's arrival, one reply after another
            replies = []
            for pkt in packets:
                self.stats.packets_received += 1
                replies.extend(self._handle(pkt, baudrate, now))
            if self.parser.crc_failed:
                replies.extend(self._crc_replies(baudrate, now))
            for chunk, delay in replies:
                if self.clock == "wall" and delay > 0:
                    due += delay
                    wait = due - time.monotonic()
                    if wait > 0:
                        time.sleep(wait)
                if self.reply_filter is not None:
                    chunk = self.reply_filter(chunk)
                    if chunk is None:
                        self.stats.replies_dropped += 1
                        continue
                out += chunk
                self.stats.replies_sent += 1
            self.stats.bytes_sent += len(out)
            return bytes(out)

    def _lockstep_packet(self, data: bytes, baudrate: int | None) -> bytes | None:
        """The fast path of the lockstep cycle's two usual packets, one whole packet into an empty parser:
        a Sync Write of Goal Current or Position (written, watchdogs, commands and, when the plant's compiled
        kernel takes them, the plant step in one compiled call, then the reading in another) and a Fast Sync
        Read that every addressed servo answers (with no reply filter set). What feed would return, or None
        when the packet is not such a case and nothing was done (feed's general path takes it;
        crane_io.sim.lockstep_kernel)."""
        if baudrate is None:
            code = -1
        else:
            code = BAUD_CODE_OF.get(baudrate)
            if code is None:  # a speed no servo can be set to
                return None
        inst = data[7]
        fns = self._lockstep_fns
        if inst == p.INST_SYNC_WRITE:
            return self._lockstep_sync_write(data, code)
        if inst == p.INST_FAST_SYNC_READ and self.fast_sync_read and self.reply_filter is None:
            buf = self._reply_buffer
            result = fns.fast_sync_read(data, self.memories, self.servo_state, code,
                                        self.parser.max_length, self.time, buf)
            if result < 0:
                return None
            reply = buf[:result >> 16].tobytes()
            st = self.stats
            st.bytes_received += len(data)
            st.packets_received += 1
            st.replies_sent += 1
            st.bytes_sent += len(reply)
            return reply
        return None

    def _fast_sync_reply(self, fast, servos, ids, address, length, now):
        """The fast path of a Fast Sync Read: every addressed servo answers (on the bus, supports it, its
        watchdog has not expired, no Indirect Data is read), the packet built in one compiled call; else None
        (the general path)."""
        if touches_data(address, address + length):
            return None
        index = self._index(servos)
        kept = self._fast_read_kept  # (index, ids, servos, rows, ids array) of the last fast read
        if kept is not None and kept[0] is index and kept[1] == ids:
            chosen, rows, id_array = kept[2], kept[3], kept[4]
        else:
            chosen = [index.get(sid) for sid in ids]
            if None in chosen:
                return None
            rows = np.array([s.chain_row for s in chosen], dtype=np.int64)
            id_array = np.array(ids, dtype=np.int64)
            self._fast_read_kept = (index, ids, chosen, rows, id_array)
        for s in chosen:
            if not s.supports_fast_sync_read or s.watchdog_expired or s.memory[s.srl_address] == 0:
                return None
        for s in chosen:
            s.contact(now)
        packet, _crc = fast[2](self.memories, rows, id_array, address, length, _HW_ERROR_AT,
                               chain_kernel.CRC_TABLE_U16)
        return [(packet.tobytes(), chosen[0].return_delay_s)]


