"""The simulated chain's lockstep fast path for the cycle's Sync Write of Goal Current or Goal Position
(crane_io.sim.lockstep_kernel): the packet written, the watchdogs, the commands and, when the plant's
compiled kernel takes them, the plant step in one compiled call, and with it the reading when the plant
allows (`sync_write_read`), else the reading in another (`sense`, through the chain's `_read_plant`).

`LockstepWrites` is a part of SimulatedChain (crane_io.sim.chain: `_lockstep_packet` hands it the packet);
what the compiled calls return is named in crane_io.sim.lockstep_kernel (DECLINED, UNHEARD, STEPPED,
WRITTEN, STEPPED_UNSENSED).
"""

from __future__ import annotations

from crane_io.sim.lockstep_kernel import DECLINED, STEPPED, STEPPED_UNSENSED, WRITTEN


class LockstepWrites:
    """SimulatedChain's lockstep Sync Write (see the module docstring)."""

    def _lockstep_sync_write(self, data: bytes, code: int) -> bytes | None:
        """What feed returns for the Sync Write `data` (b"": no reply), or None when the packet is not such a
        case and nothing was done. `code`: the port's Baud Rate register value (-1: any)."""
        dt = self.period_s
        paths = self._paths_of(self.plant)
        args = None if paths.kernel_cycle_args is None else paths.kernel_cycle_args(dt)
        if args is not None:
            return self._sync_write_read(data, code, dt, args)
        if paths.kernel_step_args is not None:
            args = paths.kernel_step_args(dt)
        result = self._lockstep_fns.sync_write_goal(
            data, self.memories, self.servo_state, code, self.parser.max_length, self.time, self._commands,
            args is not None, *(args if args is not None else self._no_plant_args))
        if result == DECLINED:
            return None
        self._count_packet(len(data))
        if result == STEPPED:  # the clocks, the reading
            self._kernel_stepped(dt)
            self._read_plant()
        elif result == WRITTEN:  # the plant steps on the general path
            self._step(dt)
        return b""

    def _sync_write_read(self, data: bytes, code: int, dt: float, args: tuple) -> bytes | None:
        """Written, stepped and read in one call (lockstep_kernel.sync_write_read); `args`: the plant's
        kernel_cycle_args (its last two: the voltages and temperatures)."""
        volt, temp = self._supply(args[-2], args[-1])
        result = self._lockstep_fns.sync_write_read(
            data, self.memories, self.servo_state, code, self.parser.max_length, self.time, self._commands,
            *args[:-2], volt, temp, self._sensed, self._noise_work)
        if result == DECLINED:
            return None
        self._count_packet(len(data))
        if result in (STEPPED, STEPPED_UNSENSED):  # the clocks, then what sense did not write
            self._kernel_stepped(dt)
            if result == STEPPED_UNSENSED:
                position, velocity, current = self._sensed.tolist()
                self._set_sensors(position, velocity, current, args[-2], args[-1], self.time)
            else:
                self._shift_ticks()
            self._plant_errors()
        elif result == WRITTEN:  # the plant steps on the general path
            self._step(dt)
        return b""

    def _count_packet(self, size: int) -> None:
        st = self.stats
        st.bytes_received += size
        st.packets_received += 1

    def _kernel_stepped(self, dt: float) -> None:
        """The compiled call stepped the plant by dt: the plant's clock and the chain's."""
        self.plant.kernel_stepped(dt)
        self.time += dt
        self.stats.plant_steps += 1
