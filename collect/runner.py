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

This module runs the session and its bilateral loop; the other steps live in
collect/sim_arms.py (1), collect/startup.py (2 and the session file), collect/alignment.py (3),
collect/arm_pair.py (both arms' transfers, the safe stop and torque read-back) and collect/status.py
(the status line and the summary).
"""

from __future__ import annotations

import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from crane_io import session_format as fmt
from crane_io.description import ArmDescription, default_arm
from crane_io.errors import CraneError
from crane_io.shutdown import handle_termination

from .alignment import SafetyStop, StartRefused, align
from .arm_calibration import calibration_offsets, calibration_sentence, resolve_calibrations
from .arm_pair import ARMS, ArmPair
from .config import Config, load_config
from .controller import ArmSignals, BilateralController
from .loop_models import load_reaction_models, observer_sentence, reaction_factories
from .operator import SimulatedOperator
from .pacing import CycleTimer
from .realtime import RealtimeState, enter_realtime
from .recorder import SessionRecorder
from .safety import Breach, SafetyMonitor
from .sim_arms import make_operator, make_plant, make_sim_arms, write_truth
from .startup import check_options, check_output, check_ports, make_recorder, open_buses, software_version
from .status import StatusLine, print_summary
from .truth_trace import TruthTraceWriter

__all__ = ["ARMS", "RunContext", "RunOptions", "RunResult", "SafetyStop", "StartRefused", "make_plant",
           "make_sim_arms", "run_arm", "run_session", "software_version"]

# the recorded row's keys ("leader/q", "timing/period", ...), by member name: _LEADER.q
_LEADER, _FOLLOWER = (SimpleNamespace(**{m.name: fmt.arm_path(arm, m.name) for m in fmt.ARM_MEMBERS})
                      for arm in ARMS)
_TIMING = SimpleNamespace(**{m.name: fmt.timing_path(m.name) for m in fmt.TIMING_MEMBERS})

_STOP_SIGNALS = tuple(getattr(signal, n) for n in ("SIGTERM", "SIGHUP", "SIGINT") if hasattr(signal, n))


@dataclass
class RunOptions:
    output: str | Path
    sim: bool = False
    plant: str | None = None  # preset name or TOML path for the simulated arms ("simple": SimplePlant)
    seed: int = 0
    duration: float | None = None  # s of bilateral control; None: until Ctrl+C / SIGTERM
    rate: float | None = None  # Hz, overrides the configuration
    config: str | Path | None = None
    realtime: bool = False  # sim only: the loop paced by the wall clock (the simulated arms stay lockstep)
    leader_port: str | None = None
    follower_port: str | None = None
    force: bool = False
    status: bool = True  # live status line on stderr
    stream: object = None  # where status and summary go (default sys.stderr)
    truth: str | Path | None = None  # sim only: write the follower plant's truth (JSON) here
    truth_trace: str | Path | None = None  # sim only: the plants' true external torques per row (HDF5)
    model: str | Path | None = None  # learned model directory for the follower's reaction-force observer
    leader_model: str | Path | None = None  # ... for the leader's
    hand_on: str = "leader"  # the arm the operator's hand moves ("follower": leader data free of a hand)
    task: str | None = None  # sim only: the simulated operator's task ("free", "contact"); None: config's
    joints: str | list | tuple | None = None  # the bilateral joints (--joints text or names); None: config's
    view: bool = False  # live view in a spawned rerun viewer (collect/live_view.py)
    view_save: str | Path | None = None  # live view written to this .rrd file instead of a viewer
    view_every: int = 10  # the view samples every N-th cycle
    leader_calibration: str | Path | None = None  # the leader's calibration file (crane_io.dynamixel)
    follower_calibration: str | Path | None = None  # ... for the follower
    calibrate: bool = True  # hardware: use each adapter's stored calibration (False: --no-calibration)
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


class _Loop:
    """The bilateral loop and what it keeps between cycles; built before any torque is on."""

    def __init__(self, opts: RunOptions, config: Config, arm: ArmDescription, sims: dict, out, stop=None):
        self.opts = opts
        self.stop = stop  # crane_io.shutdown.StopRequest: checked at the top of every cycle
        self.config = config
        self.arm = arm
        self.sims = sims
        # Simulated arms in this process advance one period per cycle, also with --realtime, which paces
        # the loop by the wall clock (collect/sim_arms.py says why): their time is the session's time.
        self.lockstep = bool(sims)
        self.paced = not sims or opts.realtime  # wait for the wall clock between cycles
        self.realtime: RealtimeState | None = None  # what the OS granted the paced loop
        self.period = config.loop.period_s
        # learned models in the observers: loaded and checked here, before any torque is on
        self.models = load_reaction_models({"leader": opts.leader_model, "follower": opts.model}, arm)
        self.ctl = BilateralController(config, arm, models=reaction_factories(self.models, arm, config))
        self.fallback_on = {name: None for name in self.models}  # joints on the nominal model now
        self.fallback_events = 0
        self.hand_arm = opts.hand_on  # the arm the simulated operator's hand moves
        self.truth_trace = None  # collect.truth_trace.TruthTraceWriter (--truth-trace)
        self._hand_torque = None  # the hand's torque acting when this cycle's angles were read
        self.safety = SafetyMonitor(config, arm)
        self.kt = np.array([j.torque_constant for j in arm.joints])
        self.bil = np.array([n in arm.bilateral_joints for n in arm.joint_names])
        held_goal = np.array([config.held.get(n, 0.0) for n in arm.joint_names])
        self.q_goal_row = np.where(self.bil, np.nan, held_goal)
        # hardware: one thread per bus; every read of both arms is a checkpoint for a stop request
        self.pair = ArmPair(concurrent_io=not sims, checkpoint=stop.check if stop is not None else None)
        self.status = StatusLine(out, config.loop, opts.status)
        self.recorder: SessionRecorder | None = None
        self.operator: SimulatedOperator | None = None
        self.timer = CycleTimer(config.loop.rate_hz, lockstep=not self.paced, spin_s=config.loop.spin_s)
        self.cycles = 0
        self.t_session = 0.0
        self.t_start_mono: float | None = None  # hardware: the leader's clock at the first cycle
        self.last_t: float | None = None
        self.err_sq = np.zeros(len(arm.joints))
        self.errors = 0
        self.breach: Breach | None = None
        self.last_event_t = 0.0
        self.ctx = RunContext(config, arm, {}, sims)
        self.view = None  # collect.live_view.LiveView (--view, --view-save): rerun imported, its sink open
        if opts.view or opts.view_save is not None:
            from .live_view import make_live_view

            self.view = make_live_view(arm, save=opts.view_save, every=opts.view_every,
                                       warn=self._view_warning)

    def _view_warning(self, message: str) -> None:
        """The live view failed (it turned itself off; the recording goes on): said once, and an event."""
        self.status.say(f"warning: {message}")
        self.event(self.now(), "warning", message)

    def attach(self, buses: dict) -> None:
        """The opened, configured buses (torque on) this loop drives."""
        self.pair.attach(buses)
        self.ctx.buses = buses

    def event(self, t: float, kind: str, message: str, joint: str = "") -> None:
        """Record an event; event times never go backwards (an event caused by another comes after it)."""
        if self.recorder is not None:
            t = max(float(t), self.last_event_t)
            self.last_event_t = t
            self.recorder.event(t, kind, message, joint)

    def now(self) -> float:
        """Session time now: the simulated time reached in lockstep, else the leader's clock since the
        first cycle (never before the last recorded cycle)."""
        if self.lockstep or self.t_start_mono is None:
            return self.t_session
        return max(self.t_session, time.monotonic() - self.t_start_mono)

    def end_event(self, reason: str, exc: BaseException | None, duration: float | None) -> None:
        """The event that says why the run ended (a safety stop wrote its own when it happened)."""
        if reason == "duration":
            self.event(self.now(), "end", f"duration of {duration:g} s reached")
        elif reason in ("interrupted", "terminated"):
            signum = getattr(exc, "signum", None) or getattr(self.stop, "signum", None) or signal.SIGINT
            what = "Ctrl+C (SIGINT)" if signum == signal.SIGINT else signal.Signals(signum).name
            self.event(self.now(), "interrupted", f"stopped by {what}")
        elif reason == "error" and exc is not None:
            self.event(self.now(), "error", f"{exc.__class__.__name__}: {exc}")

    def align(self) -> str:
        return align(self.pair, self.ctl, self.safety, self.config, self.arm, simulated=bool(self.sims),
                     lockstep=self.lockstep, paced=self.paced, say=self.status.say,
                     between_cycles=self.between_cycles)

    def between_cycles(self) -> None:
        """After a cycle's writes, before the wait: the small garbage collection kept out of the cycle."""
        if self.realtime is not None:
            self.realtime.collect_garbage()

    # -- bilateral control --------------------------------------------------------------------------
    def run(self, duration: float | None) -> str:
        """Cycles until the duration is over ("duration") or a breach stops both arms ("safety_stop")."""
        hooks = self.opts.on_cycle
        n_total = None if duration is None else int(round(duration / self.period))
        self.status.start()
        self.timer.start()
        k = 0
        stop = self.stop
        while n_total is None or k < n_total:
            if stop is not None and stop.requested:
                return "interrupted" if stop.signum == signal.SIGINT else "terminated"
            if hooks is not None:
                hooks(k, self.ctx)
            breach, t = self._cycle(k)
            if breach is not None:
                return self._stop(breach, t)
            self.between_cycles()
            if self.view is not None:  # the live view logs in the time the loop would wait anyway
                self.view.idle(self.timer)
            self.timer.wait()
            k += 1
        return "duration"

    def _cycle(self, k: int) -> tuple[Breach | None, float]:
        """Read both arms, control, write both arms, poll, record: (the breach that ends the run, t)."""
        timer, kt = self.timer, self.kt
        (sl, el, bt_l), (sf, ef, bt_f) = self.pair.read_both()
        timer.add("bus_leader", bt_l)
        timer.add("bus_follower", bt_f)
        t = self._session_time(k, sl)
        failed, breach = self._transfer_faults((el, ef), t, reading=True)
        if breach is not None:
            return breach, t
        if failed:
            if self.lockstep:  # nothing was written: let the simulated time pass anyway
                for sim in self.sims.values():
                    sim.chain.advance(self.period)
            return None, t
        tc = time.perf_counter()
        tau_l, tau_f, breach = self._control(t, sl, sf)
        timer.add("compute", time.perf_counter() - tc)
        if breach is not None:
            return breach, t
        (sent_l, wl, bw_l), (sent_f, wf, bw_f) = self.pair.write_currents(tau_l / kt, tau_f / kt)
        timer.add("bus_leader", bw_l)
        timer.add("bus_follower", bw_f)
        _, breach = self._transfer_faults((wl, wf), t, reading=False)
        if breach is None:
            breach = self._poll_hardware(k, t)
        if breach is not None:
            return breach, t
        self._record(t, sl, sf, tau_l / kt if sent_l is None else sent_l,
                     tau_f / kt if sent_f is None else sent_f)
        self.cycles = k + 1
        self.t_session = t + self.period
        wall = self.status.due()
        if wall is not None:
            rms_deg = np.degrees(np.sqrt(self.err_sq / max(self.cycles, 1)))[self.bil]
            self.status.show(self.t_session, wall, timer, rms_deg, self.errors, not self.paced,
                             self.realtime.short() if self.realtime is not None else "", self._model_tag(),
                             joints=self.arm.bilateral_joints)
        return None, t

    def _session_time(self, k: int, leader_state) -> float:
        """Session time of cycle k: k periods in lockstep, else the leader's read time since the start."""
        if self.lockstep:
            return k * self.period
        now = leader_state.t if leader_state is not None else time.monotonic()
        if self.t_start_mono is None:
            self.t_start_mono = now
        return now - self.t_start_mono

    def _transfer_faults(self, errors, t: float, *, reading: bool) -> tuple[bool, Breach | None]:
        """Count the failed transfers of (leader, follower): (any failed, the breach they amount to)."""
        failed = False
        for name, exc in zip(ARMS, errors):
            if exc is None:
                if reading:
                    self.safety.bus_ok(name)
                continue
            failed = True
            self.errors += 1
            breach = self._fault_breach(name, exc, t)
            if breach is not None:
                return failed, breach
        return failed, None

    def _control(self, t: float, sl, sf):
        """The simulated operator's push, the controller and the safety clamps: (tau_l, tau_f, breach)."""
        ql, qf = sl.position, sf.position
        sim_hand = self.sims.get(self.hand_arm)
        if sim_hand is not None:
            plant = sim_hand.plant
            if self.truth_trace is not None:
                self._hand_torque = plant.external_torque()
            s = sl if self.hand_arm == "leader" else sf
            plant.set_external_torque(self.operator.torque(t, s.position, s.velocity))
        dt = self.period if (self.lockstep or self.last_t is None) else max(t - self.last_t, 1e-4)
        self.last_t = t
        cmd = self.ctl.step(ArmSignals(ql, sl.velocity, sl.current), ArmSignals(qf, sf.velocity, sf.current),
                            dt)
        tau_l = self.safety.limit_torque(ql, cmd.leader_tau, sl.velocity)
        tau_f = self.safety.limit_torque(qf, cmd.follower_tau, sf.velocity)
        self.ctl.applied(tau_l, tau_f)
        if self.models:
            self._model_fallbacks(t)
        breach = self.safety.check("leader", ql, sl.velocity)
        if breach is None:
            breach = self.safety.check("follower", qf, sf.velocity)
        return tau_l, tau_f, breach

    def _model_tag(self) -> str:
        """The status line's short word on the observers' models ("" with the nominal ones only)."""
        if not self.models:
            return ""
        words = []
        for name in ("leader", "follower"):
            m = self.models.get(name)
            words.append(f"{name[0].upper()} " + (f"{m.model.method} {len(m.joints)}j" if m else "nominal"))
        return f"model {' '.join(words)} (fallback events {self.fallback_events})"

    def _model_fallbacks(self, t: float) -> None:
        """An event when a joint's learned model starts falling back to the nominal one (a prediction
        that is not finite or beyond the joint's maximum motor torque), and when it recovers."""
        for name, now in self.ctl.model_fallbacks().items():
            before = self.fallback_on.get(name)
            self.fallback_on[name] = now
            if now is None or (before is not None and np.array_equal(before, now)):
                continue
            m = self.models[name]
            for j, joint in enumerate(m.joints):
                was = before is not None and before[j]
                if now[j] and not was:
                    self.fallback_events += 1
                    why = ("the arm is outside the poses the model was trained on"
                           if self.ctl.reaction(name).out_of_range
                           else f"the model's prediction is not finite or beyond {m.limit[j]:.2f} N m")
                    self.event(t, "model_fallback", f"{name} {joint}: {why}; the nominal model is used",
                               joint)
                elif was and not now[j]:
                    self.event(t, "model_resumed", f"{name} {joint}: the model's prediction is usable again",
                               joint)

    def _poll_hardware(self, k: int, t: float) -> Breach | None:
        """The servos' hardware-error registers, every safety.hardware_poll_cycles cycles."""
        if not (k and self.safety.poll_due(k)):
            return None
        for name in ARMS:
            try:
                breach = self.safety.hardware(name, self.pair.buses[name].read_hardware_errors())
            except CraneError as exc:
                breach = self._fault_breach(name, exc, t)
            if breach is not None:
                return breach
        return None

    def _record(self, t: float, sl, sf, sent_l, sent_f) -> None:
        tr = time.perf_counter()
        timer, kt, bil = self.timer, self.kt, self.bil
        e = sl.position - sf.position
        self.err_sq += e * e
        tl_rec = np.where(bil, sent_l * kt, sl.current * kt)
        tf_rec = np.where(bil, sent_f * kt, sf.current * kt)
        est_l, est_f = self.ctl.leader, self.ctl.follower
        L, F, T = _LEADER, _FOLLOWER, _TIMING
        self.recorder.append({
            L.t: t, L.q: sl.position, L.tau: tl_rec, L.dq_servo: sl.velocity, L.current: sl.current,
            L.goal_current: sent_l, L.dq: est_l.dq, L.tau_dis: est_l.tau_dis, L.tau_res: est_l.tau_res,
            L.q_goal: self.q_goal_row,
            F.t: t if self.lockstep else sf.t - self.t_start_mono, F.q: sf.position, F.tau: tf_rec,
            F.dq_servo: sf.velocity, F.current: sf.current, F.goal_current: sent_f, F.dq: est_f.dq,
            F.tau_dis: est_f.tau_dis, F.tau_res: est_f.tau_res, F.q_goal: self.q_goal_row,
            T.cycle_start: timer.now(), T.period: timer.last_period,
            T.bus_time_leader: timer.last["bus_leader"], T.bus_time_follower: timer.last["bus_follower"],
            T.compute_time: timer.last["compute"], T.overrun: timer.last_overrun,
        })
        if self.truth_trace is not None:
            self._record_truth(t)
        timer.add("record", time.perf_counter() - tr)
        if self.view is not None:  # copies a sample every view_every cycles; idle() logs it
            self.view.log_cycle(t, sl.position, sf.position, tl_rec, tf_rec, est_l, est_f, timer.last_period)

    def _record_truth(self, t: float) -> None:
        """The plants' true external torques in this row (--truth-trace): contact, and the hand that was
        acting when the angles were read."""
        fol, lead = self.sims["follower"].plant, self.sims["leader"].plant
        hand = self._hand_torque
        ext_l, ext_f = lead.external_torque(), fol.external_torque()
        if hand is not None:  # the hand's torque was replaced after the read: use the one read against
            if self.hand_arm == "leader":
                ext_l = hand
            else:
                ext_f = hand
        self.truth_trace.append(t, fol.contact_torque() + ext_f, lead.contact_torque() + ext_l,
                                fol.in_contact)

    def _fault_breach(self, name: str, exc: Exception, t: float) -> Breach | None:
        from crane_io.dynamixel.faults import CommunicationError, ServoMissingError

        if isinstance(exc, ServoMissingError) or not isinstance(exc, CommunicationError):
            kind = "servo_missing" if isinstance(exc, ServoMissingError) else "hardware_error"
            return Breach(kind, name, "", f"{name}: {exc}")
        self.event(t, "comm_error", f"{name}: {exc}")
        return self.safety.bus_error(name, t, exc)

    def _stop(self, breach: Breach, t: float) -> str:
        self.breach = breach
        self.pair.safe_stop()
        self.event(t, "safety_stop", breach.message, breach.joint)
        return "safety_stop"


STOP_NOTICE = ("crane-collect: a stop is in progress (goal current 0, torque off, session file closed); "
               "please wait")


def run_session(opts: RunOptions) -> RunResult:
    """Run one collection session (see the module docstring). Raises CraneError subclasses with one
    sentence for bad input and hardware problems; SafetyStop after a safety stop (file valid).

    Stop signals (Ctrl+C, SIGTERM, SIGHUP) are recorded, never lost (crane_io.shutdown): the first one is
    taken at the next checkpoint (between the start-up's steps, between two cycles of the alignment and
    the loop); the clean-up (safe stop, torque read-back, file close, summary) always runs to its end, and
    a signal meanwhile only prints that the stop is in progress."""
    out = opts.stream if opts.stream is not None else sys.stderr
    config = load_config(opts.config)
    if opts.rate is not None:
        config = config.with_rate(opts.rate)
    if opts.task is not None:
        config = config.with_operator_task(opts.task)
    if opts.joints is not None:
        config = config.with_bilateral_joints(opts.joints)
    check_options(opts, config.loop.period_s)
    arm = run_arm(config)
    output = Path(opts.output)
    check_output(output, opts.force)
    check_ports(opts)
    # The first stop signal never raises: it is taken at the next checkpoint (between the start-up's steps,
    # before every read of both arms). A further one raises (something may be stuck), and a raise that
    # lands before the clean-up has shielded itself only makes the clean-up start again.
    with handle_termination(_STOP_SIGNALS, notice=STOP_NOTICE) as stop, stop.deferred():
        session = _Session(opts, config, arm, output, out, stop)
        try:
            try:
                session.start_and_run()
            except BaseException as exc:
                session.exc = exc
                raise
            finally:
                while True:
                    try:
                        session.clean_up()
                        break
                    except KeyboardInterrupt:
                        continue
        except KeyboardInterrupt:
            pass  # a stop signal: both arms are stopped and the file is closed
    if session.exc is not None and not isinstance(session.exc, KeyboardInterrupt):
        raise session.exc
    if session.clean_up_error is not None:
        raise session.clean_up_error
    loop = session.loop
    if loop is not None and loop.breach is not None:
        raise SafetyStop(f"safety stop: {loop.breach.message} (session saved in {output})")
    return session.result


def run_arm(config: Config) -> ArmDescription:
    """The arm description of a run: the CRANE-X7 with the configuration's bilateral joints."""
    return replace(default_arm(), bilateral_joints=tuple(config.bilateral))


class _Session:
    """One run: start-up, alignment and loop (`start_and_run`), then the clean-up that always runs to its
    end (`clean_up`)."""

    def __init__(self, opts: RunOptions, config: Config, arm: ArmDescription, output: Path, out, stop):
        self.opts, self.config, self.arm, self.output, self.out = opts, config, arm, output, out
        self.stop = stop
        self.sims: dict = {}
        self.calibrations: dict = {}  # arm -> crane_io.dynamixel.calibration.Calibration or None
        self.buses: dict = {}
        self.loop: _Loop | None = None
        self.end_reason: str | None = None  # set by the loop when it ends by itself
        self.exc: BaseException | None = None  # what ended start_and_run by raising
        self.result: RunResult | None = None
        self.clean_up_error: Exception | None = None
        self.wall0 = time.perf_counter()

    def start_and_run(self) -> None:
        opts, config, arm, stop = self.opts, self.config, self.arm, self.stop
        if opts.sim:
            self.sims = make_sim_arms(opts, config, arm)
            ports = {name: self.sims[name].url for name in ARMS}
        else:
            ports = {"leader": opts.leader_port, "follower": opts.follower_port}
        files = {"leader": opts.leader_calibration, "follower": opts.follower_calibration}
        self.calibrations = resolve_calibrations(ports, files, lookup=opts.calibrate and not opts.sim)
        stop.check()
        if opts.truth is not None:  # its own file, asked for; before any torque is on
            write_truth(self.sims, opts.truth)
        # The slow set-up (the dynamics model: ~0.4 s) comes before any torque is on: on hardware a
        # pause between torque-on and the first cycle would trip the servos' Bus Watchdog.
        loop = _Loop(opts, config, arm, self.sims, self.out, stop)
        self.loop = loop
        loop.pair.offsets = calibration_offsets(self.calibrations, arm.joint_names)
        stop.check()
        if loop.paced:  # before any torque is on: freezing the collector and locking memory take ~0.3 s
            loop.realtime = enter_realtime(config.realtime)
            stop.check()
        self.buses, hw = open_buses(opts, arm, config, ports, self.out, checkpoint=stop.check)
        loop.attach(self.buses)
        if loop.realtime is not None:  # said once the arms answered (a missing port stays one line)
            loop.status.say(loop.realtime.sentence())
        if loop.models:
            loop.status.say(observer_sentence(loop.models, arm))
        if not opts.sim or any(self.calibrations.values()):
            loop.status.say(calibration_sentence(self.calibrations))
        # from here a stop is taken between two cycles (ArmPair.read_both) and in the loop
        align_message = loop.align()
        if self.sims:
            loop.operator = make_operator(opts, config, arm, self.sims)
            states = loop.pair.read_both()
            loop.operator.start(states[ARMS.index(loop.hand_arm)][0].position, 0.0)
        loop.recorder = make_recorder(opts, self.output, config, arm, hw, loop.models, self.calibrations)
        if opts.truth_trace is not None:
            loop.truth_trace = TruthTraceWriter(opts.truth_trace, arm.joint_names, self.output.name)
        loop.ctx.recorder = loop.recorder
        if loop.view is not None:
            loop.view.start()
        for w in hw["warnings"]:
            loop.event(0.0, "warning", w)
        loop.event(0.0, "start", align_message)
        mode = "lockstep simulation" if not loop.paced else "real time"
        loop.status.say(f"recording to {self.output} ({mode}, {config.loop.rate_hz:g} Hz); "
                        "Ctrl+C ends the session")
        self.end_reason = loop.run(opts.duration)

    def _reason(self) -> str:
        if self.end_reason is not None:
            return self.end_reason
        if isinstance(self.exc, KeyboardInterrupt) or (self.exc is None and self.stop.requested):
            signum = getattr(self.exc, "signum", None) or self.stop.signum or signal.SIGINT
            return "interrupted" if signum == signal.SIGINT else "terminated"
        return "error"

    def clean_up(self) -> None:
        """Both arms stopped, the events written, buses and file closed, the summary printed: every step
        runs whatever arrives meanwhile (a stop signal only prints that the stop is in progress) and
        whatever an earlier step raised (the first such error is kept in `clean_up_error`)."""
        self.stop.begin_stop()  # a signal landing before this line makes run_session call us again
        if self.result is not None:
            return
        loop, reason = self.loop, self._reason()
        if loop is not None:
            self._step(loop.pair.safe_stop)
            self._step(loop.end_event, reason, self.exc, self.opts.duration)
            if loop.recorder is not None:
                for _name, msg in self._step(loop.pair.torque_report) or []:
                    self._step(loop.event, loop.now(), "torque_state", msg)
            self._step(loop.pair.close)
            if loop.truth_trace is not None:
                self._step(loop.truth_trace.close)
            if loop.view is not None:
                self._step(loop.view.close)
        for bus in self.buses.values():
            self._step(bus.close)
        self.result = self._step(_finish, loop, self.opts, self.output, reason, self.wall0, self.out)
        if self.result is None:
            self.result = RunResult(self.output, 0, 0.0, time.perf_counter() - self.wall0, reason, None, {})
        for sim in self.sims.values():
            self._step(sim.close)
        if loop is not None and loop.realtime is not None:  # normal scheduling, memory, collector again
            self._step(loop.realtime.restore)

    def _step(self, fn, *args):
        try:
            return fn(*args)
        except Exception as exc:  # noqa: BLE001 - the remaining steps must still run
            if self.clean_up_error is None and self.exc is None:
                self.clean_up_error = exc
            return None


def _model_lines(loop) -> list[str]:
    """The summary's lines on the learned models in the observers (none without a model)."""
    if not loop.models:
        return []
    lines = [observer_sentence(loop.models, loop.arm)]
    for name, m in loop.models.items():
        reaction = loop.ctl.reaction(name)
        if reaction is None:
            continue
        cycles = {j: int(c) for j, c in zip(m.joints, reaction.fallback_cycles) if c}
        if cycles:
            lines.append(f"{name} model fell back to the nominal one in " + ", ".join(
                f"{j} {c} cycles" for j, c in cycles.items()) + f" ({loop.fallback_events} events)")
    return lines


def _finish(loop, opts, output, end_reason, wall0, out) -> RunResult:
    """Close the session file with its timing and end reason, print the summary: the RunResult."""
    wall = time.perf_counter() - wall0
    if loop is None or loop.recorder is None:  # ended before recording started: no session file
        if loop is not None and end_reason in ("interrupted", "terminated"):
            loop.status.say(f"{end_reason} before recording started; no session file was written")
        return RunResult(output, 0, 0.0, wall, end_reason, None, {})
    summary = loop.timer.summary() if loop.timer.t0 is not None else {}
    rms = {}
    if loop.cycles:
        err = np.sqrt(loop.err_sq / loop.cycles)
        rms = {n: float(err[i]) for i, n in enumerate(loop.arm.joint_names) if loop.bil[i]}
    achieved = loop.cycles / loop.t_session if loop.t_session > 0 else 0.0
    timing_attrs = {k: float(v) for k, v in summary.items()}
    timing_attrs[fmt.TIMING_LOCKSTEP] = not loop.paced
    if loop.realtime is not None:
        timing_attrs.update(loop.realtime.attrs())
    try:
        loop.recorder.close(complete=True,
                            attrs={fmt.RATE_ACHIEVED_ATTR: achieved, fmt.END_REASON_ATTR: end_reason},
                            group_attrs={fmt.TIMING: timing_attrs})
    finally:  # the summary is printed even when the end of the file could not be written
        result = RunResult(output, loop.cycles, loop.t_session, wall, end_reason, loop.breach, summary, rms)
        if opts.status and out is not None:
            print_summary(result, loop.errors, out, lockstep=not loop.paced,
                          realtime=loop.realtime.sentence() if loop.realtime is not None else None,
                          extra=_model_lines(loop))
    return result
