"""The collection loop: two arms under 4-channel bilateral control, safely, into one session file.

    result = run_session(RunOptions(output="session.h5", sim=True, duration=60))

Order of events:
1. configuration loaded; with `sim` two simulated arms (dxlsim://, lockstep or wall clock) are built;
2. both ports opened (a missing port is one clear error), latency timers checked (a warning), every
   servo pinged and its model checked, servos configured (return delay 0, modes, Bus Watchdog), torque
   on — no session file exists before all of this succeeded;
3. alignment: both arms under independent position control (DOB-compensated) while the follower is
   moved slowly (homing speed, minimum-jerk) to the leader's pose and the held joints to their held
   pose; if the arms differ by more than `max_start_difference` the start is refused;
4. bilateral loop at the configured rate: read both arms (concurrently on hardware: one thread per
   bus), controller, safety, write both arms, record; a live status line on stderr;
5. on the end of the duration, Ctrl+C, SIGTERM, a safety breach or any exception: a safe stop of both
   arms (goal current 0, torque off), an event, the torque state read back from the servos as a final
   event, the file closed (complete = True) and a summary printed.
"""

from __future__ import annotations

import concurrent.futures
import datetime as _dt
import os
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from crane_io.description import ArmDescription, default_arm
from crane_io.errors import ConfigError, CraneError, HardwareError, SessionFileError
from crane_io.shutdown import Terminated, handle_termination

from .config import Config, load_config
from .controller import ArmSignals, BilateralController
from .operator import SimulatedOperator, minimum_jerk
from .pacing import CycleTimer
from .recorder import SessionRecorder
from .safety import Breach, SafetyMonitor

ARMS = ("leader", "follower")
_STOP_SIGNALS = tuple(getattr(signal, n) for n in ("SIGTERM", "SIGHUP", "SIGINT") if hasattr(signal, n))


class SafetyStop(HardwareError):
    """The run ended in a safety stop (the session file is valid and says why)."""


class StartRefused(HardwareError):
    """The arms could not be brought into agreement safely."""


@dataclass
class RunOptions:
    output: str | Path
    sim: bool = False
    plant: str | None = None  # preset name or TOML path for the simulated arms ("simple": SimplePlant)
    seed: int = 0
    duration: float | None = None  # s of bilateral control; None: until Ctrl+C / SIGTERM
    rate: float | None = None  # Hz, overrides the configuration
    config: str | Path | None = None
    realtime: bool = False  # sim only: wall-clock simulation paced in real time
    leader_port: str | None = None
    follower_port: str | None = None
    force: bool = False
    status: bool = True  # live status line on stderr
    stream: object = None  # where status and summary go (default sys.stderr)
    # test hook: called every bilateral cycle with (cycle index, RunContext) before the bus reads
    on_cycle: Callable[[int, RunContext], None] | None = None


@dataclass
class RunResult:
    path: Path
    cycles: int
    duration_s: float  # session time covered
    wall_s: float
    end_reason: str  # "duration", "interrupted", "terminated", "safety_stop", "error"
    breach: Breach | None
    summary: dict
    tracking_rms: dict[str, float] = field(default_factory=dict)


@dataclass
class RunContext:
    """What a test hook can reach while the loop runs."""

    config: Config
    arm: ArmDescription
    buses: dict
    sims: dict  # arm name -> SimulatedArm (sim only)
    recorder: SessionRecorder | None = None


def software_version() -> str:
    try:
        from importlib.metadata import version

        return version("crane-x7")
    except Exception:  # noqa: BLE001 - not installed: still record something
        return "unknown"


# ---- simulated arms ---------------------------------------------------------------------------------

def make_plant(spec: str | None, seed: int, arm: ArmDescription):
    """The plant behind a simulated arm: ArmPlant from a preset/TOML (default "crane-x7"), or
    "simple" for the light SimplePlant."""
    from crane_io.sim.simple_plant import SimplePlant

    if spec == "simple":
        return SimplePlant.from_arm(arm)
    try:
        from crane_io.arm_plant import ArmPlant
        from crane_io.plant_config import load_plant_config
    except ImportError:
        if spec is None:
            return SimplePlant.from_arm(arm)
        raise ConfigError(f"--plant {spec} needs crane_io.arm_plant, which is not installed; "
                          "use --plant simple") from None
    return ArmPlant(load_plant_config(spec or "crane-x7"), seed=seed)


def make_sim_arms(opts: RunOptions, config: Config, arm: ArmDescription) -> dict:
    from crane_io.sim import simulated_arm

    # Start-up (ping, configure, torque on) always runs in lockstep so the simulated arms do not fall
    # under gravity while their torque is off; --realtime switches them to the wall clock afterwards.
    clock = "lockstep"
    sims = {}
    tag = f"{os.getpid()}-{id(opts) & 0xFFFF:x}"
    for k, name in enumerate(ARMS):
        plant = make_plant(opts.plant, opts.seed * 2 + k, arm)
        sims[name] = simulated_arm(name=f"{name}-{tag}", plant=plant, clock=clock,
                                   period_s=config.loop.period_s, arm=arm, return_delay_time=0)
    return sims


# ---- the loop -----------------------------------------------------------------------------------------

def _switch_to_wall_clock(sims: dict) -> None:
    """From now on the simulated arms follow real time, continuing from their present simulated time."""
    for sim in sims.values():
        sim.chain.set_clock("wall")


class _Loop:
    def __init__(self, opts: RunOptions, config: Config, arm: ArmDescription, buses: dict, sims: dict,
                 out):
        self.opts = opts
        self.config = config
        self.arm = arm
        self.buses = buses
        self.sims = sims
        self.out = out
        self.lockstep = bool(sims) and not opts.realtime
        self.period = config.loop.period_s
        self.ctl = BilateralController(config, arm)
        self.safety = SafetyMonitor(config, arm)
        self.kt = np.array([j.torque_constant for j in arm.joints])
        self.bil = np.array([n in arm.bilateral_joints for n in arm.joint_names])
        self.held_goal = np.array([config.held.get(n, 0.0) for n in arm.joint_names])
        self.q_goal_row = np.where(self.bil, np.nan, self.held_goal)
        # Hardware: one thread per bus, so the two arms' transfers overlap (they wait on I/O without the
        # GIL). Simulated arms live in this process and are pure CPU work: threads would only fight for
        # the GIL (5 ms switch interval), so they are driven one after the other, deterministically.
        self.pool = None if sims else concurrent.futures.ThreadPoolExecutor(2, "crane-bus")
        self._inflight: list = []  # bus transfers a signal may have left running in the pool
        self.tty = hasattr(out, "isatty") and out.isatty()
        self.recorder: SessionRecorder | None = None
        self.operator: SimulatedOperator | None = None
        self.timer = CycleTimer(config.loop.rate_hz, lockstep=self.lockstep, spin_s=config.loop.spin_s)
        self.cycles = 0
        self.t_session = 0.0
        self.err_sq = np.zeros(len(arm.joints))
        self.errors = 0
        self.breach: Breach | None = None
        self.ctx = RunContext(config, arm, buses, sims)

    def attach(self, buses: dict) -> None:
        """The opened, configured buses (torque on) this loop drives."""
        self.buses = buses
        self.ctx.buses = buses

    # -- bus access (concurrent on hardware, sequential and deterministic in lockstep) --
    def _timed(self, fn, *args):
        t = time.perf_counter()
        try:
            return fn(*args), None, time.perf_counter() - t
        except CraneError as exc:
            return None, exc, time.perf_counter() - t

    def _both(self, calls):
        if self.pool is None:
            return [self._timed(*c) for c in calls]
        futures = [self.pool.submit(self._timed, *c) for c in calls]
        self._inflight = futures
        return [f.result() for f in futures]

    def read_both(self):
        return self._both([(self.buses[a].read_state,) for a in ARMS])

    def write_currents(self, amps_l, amps_f):
        return self._both([(self.buses["leader"].write_goal_current, amps_l),
                           (self.buses["follower"].write_goal_current, amps_f)])

    def write_positions(self, q_l, q_f):
        return self._both([(self.buses["leader"].write_goal_position, q_l),
                           (self.buses["follower"].write_goal_position, q_f)])

    def event(self, t: float, kind: str, message: str, joint: str = "") -> None:
        if self.recorder is not None:
            self.recorder.event(t, kind, message, joint)

    # -- alignment ----------------------------------------------------------------------------------
    def align(self) -> None:
        s = self.config.safety
        results = self.read_both()
        for _state, exc, _ in results:
            if exc is not None:
                raise exc
        q_l0, q_f0 = results[0][0].position, results[1][0].position
        bil = self.bil
        if self.sims:
            start = self.config.operator.start
            target_l = np.array([start.get(n, 0.0) for n in self.arm.joint_names])
        else:
            target_l = q_l0.copy()
            diff = np.abs(q_l0 - q_f0) * bil
            if diff.max() > s.max_start_difference:
                i = int(np.argmax(diff))
                raise StartRefused(
                    f"leader and follower {self.arm.joint_names[i]} differ by {np.degrees(diff[i]):.0f} deg, "
                    f"more than the {np.degrees(s.max_start_difference):.0f} deg allowed at start; bring the "
                    "arms closer by hand (torque is off) and start again")
        target_l = np.where(bil, target_l, self.held_goal)
        target_f = target_l.copy()
        dist = max(np.abs(target_l - q_l0).max(), np.abs(target_f - q_f0).max())
        move_s = max(0.5, 1.875 * dist / s.homing_speed) if dist > s.agree_tolerance else 0.0
        settle_s = 0.3
        self.out_line(f"aligning the arms: {np.degrees(dist):.1f} deg at most, {move_s + settle_s:.1f} s")
        ticks = 2 if self.lockstep else 1  # in lockstep each goal sync write advances the plant
        t = 0.0
        timer = CycleTimer(self.config.loop.rate_hz, lockstep=self.lockstep, spin_s=self.config.loop.spin_s)
        timer.start()
        last = time.perf_counter()
        while t < move_s + settle_s:
            if move_s > 0:
                sj, dsj = minimum_jerk(np.array(min(t / move_s, 1.0)))
                ds = float(dsj) / move_s if t < move_s else 0.0
            else:
                sj, ds = np.array(1.0), 0.0
            ref_l = (q_l0 + (target_l - q_l0) * float(sj), (target_l - q_l0) * ds)
            ref_f = (q_f0 + (target_f - q_f0) * float(sj), (target_f - q_f0) * ds)
            results = self.read_both()
            for _state, exc, _ in results:
                if exc is not None:
                    raise exc
            sl, sf = results[0][0], results[1][0]
            for name, st in zip(ARMS, (sl, sf)):
                b = self.safety.check(name, st.position, st.velocity)
                if b is not None:
                    raise SafetyStop(f"safety stop while aligning: {b.message}")
            now = time.perf_counter()
            dt = ticks * self.period if self.lockstep else max(now - last, 1e-4)
            last = now
            cmd = self.ctl.hold(ArmSignals(sl.position), ArmSignals(sf.position), ref_l, ref_f, dt)
            tau_l = self.safety.limit_torque(sl.position, cmd.leader_tau, sl.velocity, spring=False)
            tau_f = self.safety.limit_torque(sf.position, cmd.follower_tau, sf.velocity, spring=False)
            self.ctl.applied(tau_l, tau_f)
            for _, exc, _ in self.write_positions(ref_l[0], ref_f[0]):
                if exc is not None:
                    raise exc
            for _, exc, _ in self.write_currents(tau_l / self.kt, tau_f / self.kt):
                if exc is not None:
                    raise exc
            timer.wait()
            t += dt
        final = self.read_both()
        ql, qf = final[0][0].position, final[1][0].position
        gap = float(np.abs(ql - qf)[bil].max())
        self.align_message = (f"arms aligned in {t:.1f} s; largest leader-follower difference "
                              f"{np.degrees(gap):.2f} deg")

    # -- bilateral control --------------------------------------------------------------------------
    def run(self, duration: float | None) -> str:
        cfg = self.config
        rec = self.recorder
        timer = self.timer
        ctl, safety = self.ctl, self.safety
        kt = self.kt
        bil = self.bil
        status_every = 1.0 / cfg.loop.status_hz if (cfg.loop.status_hz > 0 and self.opts.status) else None
        if status_every is not None and not self.tty:  # a pipe or a log file: do not flood it
            status_every = max(status_every, cfg.loop.status_log_s)
        next_status = time.perf_counter() + (status_every or 0.0)
        hooks = self.opts.on_cycle
        sim_leader = self.sims.get("leader")
        n_total = None if duration is None else int(round(duration / self.period))
        wall0 = time.perf_counter()
        t_start_mono = None
        last_t = None
        timer.start()
        k = 0
        while n_total is None or k < n_total:
            if hooks is not None:
                hooks(k, self.ctx)
            # ---- read both arms
            results = self.read_both()
            (sl, el, bt_l), (sf, ef, bt_f) = results
            timer.add("bus_leader", bt_l)
            timer.add("bus_follower", bt_f)
            if self.lockstep:
                t = k * self.period
            else:
                if t_start_mono is None:
                    t_start_mono = sl.t if sl is not None else time.monotonic()
                t = (sl.t if sl is not None else time.monotonic()) - t_start_mono
            failed = False
            for name, exc in (("leader", el), ("follower", ef)):
                if exc is None:
                    safety.bus_ok(name)
                    continue
                failed = True
                self.errors += 1
                breach = self._fault_breach(name, exc, t)
                if breach is not None:
                    return self._stop(breach, t)
            if failed:
                if self.lockstep:  # nothing was written: let the simulated time pass anyway
                    for sim in self.sims.values():
                        sim.chain.advance(self.period)
                timer.wait()
                k += 1
                continue
            # ---- compute
            tc = time.perf_counter()
            ql, qf = sl.position, sf.position
            if sim_leader is not None:
                sim_leader.plant.set_external_torque(self.operator.torque(t, ql, sl.velocity))
            dt = self.period if (self.lockstep or last_t is None) else max(t - last_t, 1e-4)
            last_t = t
            cmd = ctl.step(ArmSignals(ql, sl.velocity, sl.current), ArmSignals(qf, sf.velocity, sf.current),
                           dt)
            tau_l = safety.limit_torque(ql, cmd.leader_tau, sl.velocity)
            tau_f = safety.limit_torque(qf, cmd.follower_tau, sf.velocity)
            ctl.applied(tau_l, tau_f)
            breach = safety.check("leader", ql, sl.velocity) or safety.check("follower", qf, sf.velocity)
            timer.add("compute", time.perf_counter() - tc)
            if breach is not None:
                return self._stop(breach, t)
            # ---- write both arms
            (sent_l, wl, bw_l), (sent_f, wf, bw_f) = self.write_currents(tau_l / kt, tau_f / kt)
            timer.add("bus_leader", bw_l)
            timer.add("bus_follower", bw_f)
            for name, exc in (("leader", wl), ("follower", wf)):
                if exc is not None:
                    self.errors += 1
                    breach = self._fault_breach(name, exc, t)
                    if breach is not None:
                        return self._stop(breach, t)
            if sent_l is None:
                sent_l = tau_l / kt
            if sent_f is None:
                sent_f = tau_f / kt
            # ---- hardware-error poll
            if k and safety.poll_due(k):
                for name in ARMS:
                    try:
                        breach = safety.hardware(name, self.buses[name].read_hardware_errors())
                    except CraneError as exc:
                        breach = self._fault_breach(name, exc, t)
                    if breach is not None:
                        return self._stop(breach, t)
            # ---- record
            tr = time.perf_counter()
            e = ql - qf
            self.err_sq += e * e
            tl_rec = np.where(bil, sent_l * kt, sl.current * kt)
            tf_rec = np.where(bil, sent_f * kt, sf.current * kt)
            est_l, est_f = ctl.leader, ctl.follower
            rec.append({
                "leader/t": t, "leader/q": ql, "leader/tau": tl_rec, "leader/dq_servo": sl.velocity,
                "leader/current": sl.current, "leader/goal_current": sent_l, "leader/dq": est_l.dq,
                "leader/tau_dis": est_l.tau_dis, "leader/tau_res": est_l.tau_res,
                "leader/q_goal": self.q_goal_row,
                "follower/t": t if self.lockstep else sf.t - t_start_mono, "follower/q": qf,
                "follower/tau": tf_rec, "follower/dq_servo": sf.velocity, "follower/current": sf.current,
                "follower/goal_current": sent_f, "follower/dq": est_f.dq, "follower/tau_dis": est_f.tau_dis,
                "follower/tau_res": est_f.tau_res, "follower/q_goal": self.q_goal_row,
                "timing/cycle_start": timer.now(), "timing/period": timer.last_period,
                "timing/bus_time_leader": timer.last["bus_leader"],
                "timing/bus_time_follower": timer.last["bus_follower"],
                "timing/compute_time": timer.last["compute"], "timing/overrun": timer.last_overrun,
            })
            timer.add("record", time.perf_counter() - tr)
            self.cycles = k + 1
            self.t_session = t + self.period
            if status_every is not None:
                now = time.perf_counter()
                if now >= next_status:
                    next_status = now + status_every
                    self.status_line(t + self.period, now - wall0)
            timer.wait()
            k += 1
        return "duration"

    def _fault_breach(self, name: str, exc: Exception, t: float) -> Breach | None:
        from crane_io.faults import CommunicationError, ServoMissingError

        if isinstance(exc, ServoMissingError) or not isinstance(exc, CommunicationError):
            kind = "servo_missing" if isinstance(exc, ServoMissingError) else "hardware_error"
            return Breach(kind, name, "", f"{name}: {exc}")
        self.event(t, "comm_error", f"{name}: {exc}")
        return self.safety.bus_error(name, t, exc)

    def _stop(self, breach: Breach, t: float) -> str:
        self.breach = breach
        self.safe_stop()
        self.event(t, "safety_stop", breach.message, breach.joint)
        return "safety_stop"

    def safe_stop(self) -> dict:
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

    # -- output ---------------------------------------------------------------------------------------
    def out_line(self, text: str) -> None:
        if self.opts.status and self.out is not None:
            print(text, file=self.out, flush=True)

    def status_line(self, t_session: float, wall: float) -> None:
        r = self.timer.recent()
        err = np.degrees(np.sqrt(self.err_sq / max(self.cycles, 1)))[self.bil]
        speed = f" x{t_session / wall:.1f} real time" if self.lockstep and wall > 0 else ""
        text = (f"{t_session:7.1f} s | {r['rate_hz']:6.0f} Hz{speed} | jitter {r['jitter_s'] * 1e3:.3f} ms | "
                f"max {r['max_s'] * 1e3:.2f} ms | overruns {self.timer.overruns} | errors {self.errors} | "
                f"track rms {' '.join(f'{x:.2f}' for x in err)} deg")
        print(("\r" + text) if self.tty else text, end="" if self.tty else "\n", file=self.out, flush=True)

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True)


def _open_buses(opts: RunOptions, arm: ArmDescription, config: Config, ports: dict, out) -> tuple[dict, dict]:
    from crane_io.bus import DynamixelBus
    from crane_io.ports import port_warnings

    buses: dict = {}
    infos: dict = {}
    warnings_: list[str] = []
    try:
        for name in ARMS:
            port = ports[name]
            if not opts.sim:
                for w in port_warnings(port):
                    warnings_.append(w)
                    print(f"Warning: {w}", file=out or sys.stderr, flush=True)
            bus = DynamixelBus(port, arm, name=name)
            buses[name] = bus
            bus.open()
        for name in ARMS:
            infos[name] = buses[name].ping_all()
        for name in ARMS:
            buses[name].configure(watchdog_s=config.safety.watchdog_s)
        for name in ARMS:
            buses[name].torque_on()
    except BaseException:
        for bus in buses.values():
            bus.close()
        raise
    return buses, {"infos": infos, "warnings": warnings_}


def run_session(opts: RunOptions) -> RunResult:
    """Run one collection session (see the module docstring). Raises CraneError subclasses with one
    sentence for bad input and hardware problems; SafetyStop after a safety stop (file valid)."""
    out = opts.stream if opts.stream is not None else sys.stderr
    config = load_config(opts.config)
    if opts.rate is not None:
        config = config.with_rate(opts.rate)
    if opts.duration is not None and not opts.duration > 0:
        raise ConfigError(f"--duration must be positive, got {opts.duration}")
    if opts.realtime and not opts.sim:
        raise ConfigError("--realtime only applies to --sim (hardware always runs in real time)")
    arm = default_arm()
    output = Path(opts.output)
    if output.exists() and not opts.force:
        raise CraneError(f"{output} already exists; pass --force to overwrite it")
    _check_output_folder(output)
    sims: dict = {}
    if opts.sim:
        if opts.leader_port or opts.follower_port:
            raise ConfigError("--leader-port/--follower-port cannot be combined with --sim")
        sims = make_sim_arms(opts, config, arm)
        ports = {name: sims[name].url for name in ARMS}
    else:
        if not opts.leader_port or not opts.follower_port:
            raise ConfigError("without --sim both --leader-port and --follower-port are needed "
                              "(see `crane-collect ports`)")
        if opts.leader_port == opts.follower_port:
            raise ConfigError("--leader-port and --follower-port must be different ports")
        ports = {"leader": opts.leader_port, "follower": opts.follower_port}

    loop = None
    end_reason = "error"
    wall0 = time.perf_counter()
    buses: dict = {}
    try:
        # SIGINT too: the first Ctrl+C / SIGTERM / SIGHUP ends the run, any further one while the arms
        # are being stopped and the file closed is ignored (a second Ctrl+C must not cut the safe stop).
        with handle_termination(_STOP_SIGNALS):
            try:
                # The slow set-up (the dynamics model: ~0.4 s) comes before any torque is on: on hardware a
                # pause between torque-on and the first cycle would trip the servos' Bus Watchdog.
                loop = _Loop(opts, config, arm, {}, sims, out)
                buses, hw = _open_buses(opts, arm, config, ports, out)
                loop.attach(buses)
                if sims and opts.realtime:
                    _switch_to_wall_clock(sims)
                loop.align()
                if sims:
                    loop.operator = SimulatedOperator(opts.seed, arm, config.loop.rate_hz, config)
                    loop.operator.start(loop.read_both()[0][0].position, 0.0)
                loop.recorder = _make_recorder(opts, output, config, arm, hw)
                loop.ctx.recorder = loop.recorder
                for w in hw["warnings"]:
                    loop.event(0.0, "warning", w)
                loop.event(0.0, "start", loop.align_message)
                mode = "lockstep simulation" if loop.lockstep else "real time"
                loop.out_line(f"recording to {output} ({mode}, {config.loop.rate_hz:g} Hz); "
                              "Ctrl+C ends the session")
                end_reason = loop.run(opts.duration)
                if end_reason == "duration":
                    loop.safe_stop()
                    loop.event(loop.t_session, "end", f"duration of {opts.duration:g} s reached")
            except KeyboardInterrupt as exc:
                signum = exc.signum if isinstance(exc, Terminated) else signal.SIGINT
                end_reason = "interrupted" if signum == signal.SIGINT else "terminated"
                if loop is not None:
                    loop.safe_stop()
                    what = "Ctrl+C (SIGINT)" if signum == signal.SIGINT else signal.Signals(signum).name
                    loop.event(loop.t_session, "interrupted", f"stopped by {what}")
            except BaseException as exc:
                end_reason = "error"
                if loop is not None:
                    loop.safe_stop()
                    loop.event(loop.t_session, "error", f"{exc.__class__.__name__}: {exc}")
                raise
            finally:
                if loop is not None:
                    if loop.recorder is not None:
                        for _name, msg in loop.torque_report():
                            loop.event(loop.t_session, "torque_state", msg)
                    loop.close()
                for bus in buses.values():
                    bus.close()
                result = _finish(loop, opts, output, end_reason, wall0, out)
                for sim in sims.values():
                    sim.close()
    except Terminated:  # a second signal while closing: the file is already safe
        pass
    if loop is not None and loop.breach is not None:
        raise SafetyStop(f"safety stop: {loop.breach.message} (session saved in {output})")
    return result


def _check_output_folder(output: Path) -> None:
    """A session file that cannot be written is found out before any torque is on, not after the
    alignment. Missing folders are created."""
    folder = output.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SessionFileError(f"cannot create session file {output}: folder {folder} cannot be created "
                               f"({exc.strerror or exc})") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise SessionFileError(f"cannot create session file {output}: folder {folder} is not writable")


def _make_recorder(opts: RunOptions, output: Path, config: Config, arm: ArmDescription, hw: dict):
    infos = hw["infos"]
    attrs = {
        "tau_source": ["goal_current" if n in arm.bilateral_joints else "present_current"
                       for n in arm.joint_names],
        "torque_constants": np.array([j.torque_constant for j in arm.joints]),
        "servo_ids": np.array(arm.servo_ids),
        "bilateral_joints": list(arm.bilateral_joints),
        "software_version": software_version(),
        "start_time": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "config_toml": config.to_toml(),
        "gravity_model": config.controller.gravity_model,
        "lockstep": bool(opts.sim and not opts.realtime),
    }
    for name in ARMS:
        by_id = infos.get(name, {})
        attrs[f"{name}_firmware_versions"] = np.array([by_id[i].firmware if i in by_id else -1
                                                       for i in arm.servo_ids])
    attrs["firmware_versions"] = attrs["follower_firmware_versions"]
    # the models the servos reported when pinged (start-up refused any other than the description's)
    reported = infos.get("follower", {})
    attrs["servo_models"] = [reported[i].model if i in reported else j.model
                             for i, j in zip(arm.servo_ids, arm.joints)]
    if opts.sim:
        attrs["seed"] = int(opts.seed)  # the plant preset is not stored: "hidden-*" names give it away
    return SessionRecorder(output, joint_names=arm.joint_names, rate_hz=config.loop.rate_hz,
                           source="sim" if opts.sim else "hardware", attrs=attrs, force=opts.force)


def _finish(loop, opts, output, end_reason, wall0, out) -> RunResult:
    wall = time.perf_counter() - wall0
    if loop is None or loop.recorder is None:  # ended before recording started: no session file
        stopped = end_reason in ("interrupted", "terminated")
        if loop is not None and stopped and opts.status and out is not None:
            print(f"{end_reason} before recording started; no session file was written", file=out, flush=True)
        return RunResult(output, 0, 0.0, wall, end_reason, None, {})
    summary = loop.timer.summary() if loop.timer.t0 is not None else {}
    rms = {}
    if loop.cycles:
        err = np.sqrt(loop.err_sq / loop.cycles)
        rms = {n: float(err[i]) for i, n in enumerate(loop.arm.joint_names) if loop.bil[i]}
    if loop.recorder is not None:
        achieved = loop.cycles / loop.t_session if loop.t_session > 0 else 0.0
        timing_attrs = {k: float(v) for k, v in summary.items()}
        timing_attrs["lockstep"] = loop.lockstep
        loop.recorder.close(complete=True, attrs={"rate_hz_achieved": achieved, "end_reason": end_reason},
                            group_attrs={"timing": timing_attrs})
    result = RunResult(output, loop.cycles, loop.t_session, wall, end_reason, loop.breach, summary, rms)
    if opts.status and out is not None:
        _print_summary(result, loop, out)
    return result


def _print_summary(r: RunResult, loop, out) -> None:
    s = r.summary
    tty = hasattr(out, "isatty") and out.isatty()
    lines = [("\n" if tty else "") + f"session {r.path}: {r.end_reason}, {r.cycles} cycles, "
             f"{r.duration_s:.1f} s recorded in {r.wall_s:.1f} s wall"]
    if s.get("period_mean_s"):
        lines.append(f"  loop: {s['rate_hz']:.0f} Hz achieved, "
                     f"period mean {s['period_mean_s'] * 1e3:.3f} ms, "
                     f"std {s['period_std_s'] * 1e3:.3f} ms, p99 {s['period_p99_s'] * 1e3:.3f} ms, "
                     f"max {s['period_max_s'] * 1e3:.3f} ms, overruns {int(s['overruns'])}")
        lines.append(f"  bus: leader {s.get('bus_leader_mean_s', 0) * 1e3:.3f} ms, follower "
                     f"{s.get('bus_follower_mean_s', 0) * 1e3:.3f} ms per cycle; compute "
                     f"{s.get('compute_mean_s', 0) * 1e6:.0f} us, "
                     f"record {s.get('record_mean_s', 0) * 1e6:.0f} us; bus errors {loop.errors}")
    if r.tracking_rms:
        lines.append("  tracking rms (leader - follower): " + ", ".join(
            f"{n} {np.degrees(v):.2f} deg" for n, v in r.tracking_rms.items()))
    if r.breach is not None:
        lines.append(f"  SAFETY STOP: {r.breach.message}")
    print("\n".join(lines), file=out, flush=True)
