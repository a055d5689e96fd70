"""Leader and follower buses driven as a pair: both read, both written, both stopped.

On hardware every transfer of the two arms runs concurrently, one thread per bus (they wait on I/O
without the GIL). Simulated arms live in this process and are pure CPU work: threads would only fight
for the GIL (5 ms switch interval), so they are driven one after the other, deterministically.

Every transfer returns (value, error, seconds): a CraneError is handed back, not raised, so the caller
decides whether a failed cycle is a fault. `safe_stop` (goal current 0, torque off) reaches both arms
even if one fails; `torque_report` reads the torque state back from the servos afterwards.

Calibrated angles (crane_io.dynamixel.calibration): with `offsets[arm]` set, every state read has the arm's
offsets subtracted from its positions and every goal position has them added, so everything above the
pair (controller, safety, alignment, session) sees calibrated angles only.
"""

from __future__ import annotations

import concurrent.futures
import time

from crane_io.errors import CraneError

ARMS = ("leader", "follower")


class ArmPair:
    def __init__(self, concurrent_io: bool, checkpoint=None):
        self.buses: dict = {}
        # called before every read of both arms (the alignment's and the loop's cycles): raises to end
        # the run when a stop was requested (crane_io.shutdown.StopRequest.check)
        self.checkpoint = checkpoint
        self.pool = concurrent.futures.ThreadPoolExecutor(2, "crane-bus") if concurrent_io else None
        self._inflight: list = []  # bus transfers a signal may have left running in the pool
        self.stopped = False  # both arms confirmed stopped (goal current 0, torque off)
        self.offsets: dict = {}  # arm name -> (n,) rad encoder offsets (crane_io.dynamixel.calibration)

    def attach(self, buses: dict) -> None:
        """The opened, configured buses (torque on) to drive."""
        self.buses = buses

    # -- transfers --------------------------------------------------------------------------------------
    def _timed(self, fn, *args):
        t = time.perf_counter()
        try:
            return fn(*args), None, time.perf_counter() - t
        except CraneError as exc:
            return None, exc, time.perf_counter() - t

    @staticmethod
    def _one_after_other(fn_l, fn_f, args_l=(), args_f=()):
        """[_timed(fn_l, *args_l), _timed(fn_f, *args_f)], one clock reading between the two."""
        clock = time.perf_counter
        t0 = clock()
        try:
            out_l, err_l = fn_l(*args_l), None
        except CraneError as exc:
            out_l, err_l = None, exc
        t1 = clock()
        try:
            out_f, err_f = fn_f(*args_f), None
        except CraneError as exc:
            out_f, err_f = None, exc
        t2 = clock()
        return [(out_l, err_l, t1 - t0), (out_f, err_f, t2 - t1)]

    def _both(self, calls):
        if self.pool is None:
            return [self._timed(*c) for c in calls]
        futures = [self.pool.submit(self._timed, *c) for c in calls]
        self._inflight = futures
        return [f.result() for f in futures]

    def read_both(self):
        """[(ServoState | None, CraneError | None, s)] for leader, follower."""
        if self.checkpoint is not None:
            self.checkpoint()
        buses = self.buses
        if self.pool is None:  # one after the other (simulated arms): `_both` without its call lists
            results = self._one_after_other(buses["leader"].read_state, buses["follower"].read_state)
        else:
            results = self._both([(buses[a].read_state,) for a in ARMS])
        if self.offsets:
            for name, (state, _exc, _s) in zip(ARMS, results):
                off = self.offsets.get(name)
                if state is not None and off is not None:
                    state.position = state.position - off
        return results

    def write_currents(self, amps_l, amps_f):
        buses = self.buses
        if self.pool is None:
            return self._one_after_other(buses["leader"].write_goal_current,
                                         buses["follower"].write_goal_current, (amps_l,), (amps_f,))
        return self._both([(buses["leader"].write_goal_current, amps_l),
                           (buses["follower"].write_goal_current, amps_f)])

    def write_positions(self, q_l, q_f):
        off_l, off_f = self.offsets.get("leader"), self.offsets.get("follower")
        if off_l is not None:
            q_l = q_l + off_l
        if off_f is not None:
            q_f = q_f + off_f
        buses = self.buses
        if self.pool is None:
            timed = self._timed
            return [timed(buses["leader"].write_goal_position, q_l),
                    timed(buses["follower"].write_goal_position, q_f)]
        return self._both([(buses["leader"].write_goal_position, q_l),
                           (buses["follower"].write_goal_position, q_f)])

    # -- stopping -----------------------------------------------------------------------------------------
    def safe_stop(self) -> dict:
        """Goal current 0 and torque off on both arms; {arm: failures} of the stop itself. Once both
        arms confirmed the stop, a further call does nothing."""
        if self.stopped:
            return {}
        # A signal raised in the main thread while it waited for the bus threads: let their transfers
        # end first, so the stop packets do not collide with a read still on the wire.
        if self._inflight:
            concurrent.futures.wait(self._inflight, timeout=2.0)
            self._inflight = []
        failures = {}
        for name in ARMS:
            bus = self.buses.get(name)
            if bus is not None:
                try:
                    failures[name] = bus.safe_stop()
                except Exception as exc:  # noqa: BLE001 - the other arm must still stop
                    failures[name] = {"*": str(exc)}
        self.stopped = bool(self.buses) and not any(failures.values())
        return failures

    def torque_report(self) -> list[tuple[str, str]]:
        """(arm, sentence) on the torque state read back from the servos after the stop."""
        out = []
        for name in ARMS:
            bus = self.buses.get(name)
            if bus is None or not bus.is_open:
                continue
            try:
                rows = bus.servo_report()
            except Exception as exc:  # noqa: BLE001
                out.append((name, f"{name}: torque state could not be read ({exc})"))
                continue
            on = [f"{r['joint']} (ID {r['id']})" for r in rows
                  if r.get("answering") and r.get("torque_enabled")]
            silent = [f"{r['joint']} (ID {r['id']})" for r in rows if not r.get("answering")]
            n_off = sum(1 for r in rows if r.get("answering") and not r.get("torque_enabled"))
            msg = f"{name}: torque off on {n_off} of {len(rows)} servos"
            if on:
                msg += f"; TORQUE STILL ON: {', '.join(on)}"
            if silent:
                msg += f"; not answering: {', '.join(silent)}"
            out.append((name, msg))
        return out

    def close(self) -> None:
        """Let the bus threads end (the buses themselves are closed by whoever opened them)."""
        if self.pool is not None:
            self.pool.shutdown(wait=True)
