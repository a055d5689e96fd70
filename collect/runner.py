"""The collection run: two arms under 4-channel bilateral control, safely, into one session file.

    result = run_session(RunOptions(output="session.h5", sim=True, duration=60))

or, phase by phase:

    with BilateralRun(options) as run:   # the options checked; stop signals recorded, never lost
        run.start()                       # simulated arms, learned models, both buses open, torque on
        run.align()                       # the follower moved slowly to the leader's pose
        run.record()                      # the session file opened, the bilateral loop
    result = run.result                   # the safe stop and the close have run, whatever happened

Order of events:
1. configuration loaded, options, output file and ports checked (`BilateralRun(options)`: nothing is
   opened yet); with `sim` two simulated arms (dxlsim://, lockstep) are built (`start`);
2. both ports opened (a missing port is one clear error), latency timers checked (a warning), every
   servo pinged and its model checked, servos configured (return delay 0, modes, Bus Watchdog), torque
   on — no session file exists before all of this succeeded (`start`);
3. alignment: both arms under independent position control (DOB-compensated) while the follower is
   moved slowly (homing speed, minimum-jerk) to the leader's pose and the held joints to their held
   pose; if the arms differ by more than `max_start_difference` the start is refused (`align`);
4. bilateral loop at the configured rate: read both arms (concurrently on hardware: one thread per
   bus), controller, safety, write both arms, record; a live status line on stderr (`record`);
5. on the end of the duration, Ctrl+C, SIGTERM, a safety breach or any exception (`__exit__`): the safe
   stop of both arms (goal current 0, torque off), an event, the torque state read back from the
   servos as a final event, the buses and the file closed (complete = True) and a summary printed
   (`safe_stop`); then the simulated arms, the real-time settings and the signal handlers (`close`).

This module runs the phases; the steps live in collect/startup.py (1, 2 and the session file),
collect/sim_arms.py (the simulated arms), collect/alignment.py (3), collect/bilateral_loop.py (4),
collect/arm_pair.py (both arms' transfers, the safe stop and torque read-back) and collect/status.py
(the status line and the summary); the options in collect/run_options.py.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from crane_io import session_format as fmt
from crane_io.description import ArmDescription, default_arm
from crane_io.jit import compile_notice
from crane_io.shutdown import StopRequest, disarm_prompt_exit, handle_termination, set_activity

from .alignment import SafetyStop, StartRefused, checked
from .arm_calibration import calibration_offsets, calibration_sentence, resolve_calibrations
from .arm_pair import ARMS
from .bilateral_loop import BilateralLoop, RunContext
from .config import Config, load_config
from .kernels import compile_kernels, compile_sentence
from .loop_models import load_reaction_models, observer_sentence
from .realtime import enter_realtime
from .run_options import RunOptions, RunResult, check_run_outputs
from .selftest_record import require_selftest
from .sim_arms import make_operator, make_sim_arms, write_truth
from .startup import check_options, check_output, check_ports, make_recorder, open_buses
from .status import print_summary
from .truth_trace import TruthTraceWriter

__all__ = ["BilateralRun", "RunContext", "RunOptions", "RunResult", "SafetyStop", "StartRefused", "run_arm",
           "run_session", "run_with"]

_STOP_SIGNALS = tuple(getattr(signal, n) for n in ("SIGTERM", "SIGHUP", "SIGINT") if hasattr(signal, n))

STOP_NOTICE = ("crane-collect: a stop is in progress (goal current 0, torque off, session file closed); "
               "please wait")


def run_session(opts: RunOptions) -> RunResult:
    """Run one collection session (see the module docstring). Raises CraneError subclasses with one
    sentence for bad input and hardware problems; SafetyStop after a safety stop (file valid).

    Stop signals (Ctrl+C, SIGTERM, SIGHUP) are recorded, never lost (crane_io.shutdown): the first one is
    taken at the next checkpoint (between the start-up's steps, between two cycles of the alignment and
    the loop); the clean-up (safe stop, torque read-back, file close, summary) always runs to its end, and
    a signal meanwhile only prints that the stop is in progress."""
    return run_with(BilateralRun(opts))


def run_with(run: BilateralRun) -> RunResult:
    """`run` (a BilateralRun or a subclass, constructed) through its phases, as `run_session` does."""
    try:
        with run:
            run.start()
            run.align()
            run.record()
    except KeyboardInterrupt as exc:
        if run.stop is None:  # the signal came while the stop handling was being set up: nothing started
            raise
        # A further signal landed in __exit__ before its clean-up shielded itself: the clean-up starts
        # again (it runs each step once) and the run's outcome is raised as it would have been. Before
        # any torque was on, the signal itself is raised on: the start-up was cut short.
        if not run.__exit__(type(exc), exc, exc.__traceback__):
            raise
    return run.result


def run_arm(config: Config) -> ArmDescription:
    """The arm description of a run: the CRANE-X7 with the configuration's bilateral joints."""
    return replace(default_arm(), bilateral_joints=tuple(config.bilateral))


class BilateralRun:
    """One collection session; its phases are methods (see the module docstring).

    Constructing it checks the options, the output file and the ports and opens nothing. Entering it
    (`with`) takes the stop signals (crane_io.shutdown: the first one is recorded and taken at the next
    checkpoint; a further one raises, since something may be stuck). Leaving it, whatever happened (the
    end of the phases, an exception, a stop signal, a safety breach), runs `safe_stop` and `close` to
    their end, each step whatever an earlier one raised, a stop signal meanwhile only printing that the
    stop is in progress; then it raises what ended the run (the exception, the first error of the
    clean-up, or SafetyStop after a breach) and takes a stop signal as a normal end. `result` is the
    RunResult afterwards."""

    def __init__(self, options: RunOptions):
        self.options = opts = options
        self.out = opts.stream if opts.stream is not None else sys.stderr
        set_activity("loading the configuration")
        config = load_config(opts.config)
        if opts.rate is not None:
            config = config.with_rate(opts.rate)
        if opts.task is not None:
            config = config.with_operator_task(opts.task)
        if opts.joints is not None:
            config = config.with_bilateral_joints(opts.joints)
        check_options(opts, config.loop.period_s)
        self.config = config
        self.arm = run_arm(config)
        self.output = Path(opts.output)
        check_run_outputs(opts)  # no output is an input or another output
        check_output(self.output, opts.force)
        check_ports(opts.sim, opts.leader_port, opts.follower_port)
        self.arm_model = None  # an identified arm model for the nominal observers: data, checked now
        if opts.arm_model is not None:
            from crane_io.physics.identified_model import IdentifiedArm

            self.arm_model = IdentifiedArm.from_toml(opts.arm_model)
        self.stop: StopRequest | None = None  # while entered: what the stop signals said
        self._signals = contextlib.ExitStack()  # the stop handling, left last
        self.sims: dict = {}  # arm name -> crane_io.sim.SimulatedArm (sim only)
        self.calibrations: dict = {}  # arm -> crane_io.dynamixel.calibration.Calibration or None
        self.buses: dict = {}
        self.hw: dict = {"infos": {}, "warnings": []}  # what start-up learned from the servos
        self.loop: BilateralLoop | None = None
        self.align_message = ""
        self.duration: float | None = opts.duration  # s to record (`start_motion`); None: until a stop
        self.end_reason: str | None = None  # set by the loop when it ends by itself
        self.exc: BaseException | None = None  # what ended the phases by raising
        self.result: RunResult | None = None
        self.clean_up_error: Exception | None = None
        self.closed = False
        self.torque_was_on = False  # set right before the first servo's torque goes on
        self.wall0 = time.perf_counter()

    # -- entering and leaving ---------------------------------------------------------------------------
    def __enter__(self) -> BilateralRun:
        try:
            # Until torque goes on a stop signal raises at once (start-up ends within a moment, whatever
            # it was doing); from then on the first one is taken at the next checkpoint (_torque_going_on).
            stop = self._signals.enter_context(handle_termination(_STOP_SIGNALS, notice=STOP_NOTICE))
        except BaseException:
            self._signals.close()
            raise
        self.stop = stop
        self.wall0 = time.perf_counter()
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if self.exc is None:
            self.exc = exc
        self._clean_up()
        if self.exc is not None and not isinstance(self.exc, KeyboardInterrupt):
            if self.exc is exc:
                return False  # the with statement raises it on
            raise self.exc
        if self.clean_up_error is not None:
            raise self.clean_up_error
        if self.loop is not None and self.loop.breach is not None:
            raise SafetyStop(f"safety stop: {self.loop.breach.message} (session saved in {self.output})")
        if not self.torque_was_on:
            return False  # a stop signal ended the start-up: raised on (the command line says what it cut)
        return True  # a stop signal ended the run: both arms are stopped and the file is closed

    def _clean_up(self) -> None:
        """`safe_stop` and `close` to their end, then the stop handling left. A stop signal raised
        before the clean-up shielded itself only makes it start again."""
        while not self.closed:
            try:
                self.stop.begin_stop()  # from here on no signal raises; each prints STOP_NOTICE
                self.safe_stop()
                self.close()
            except KeyboardInterrupt:
                continue
        self._signals.close()  # the previous signal handlers back

    # -- the phases -------------------------------------------------------------------------------------
    def start(self) -> None:
        """Start-up: the simulated arms, the calibrations, the learned models, the loop, the real-time
        settings, both buses open, every servo checked and configured, torque on. Everything slow comes
        before torque on: on hardware a pause between torque on and the first cycle would trip the
        servos' Bus Watchdog."""
        opts, config, arm, stop = self.options, self.config, self.arm, self.stop
        if opts.sim:  # every kernel at once, said when it is a compilation (setup.sh compiles them before)
            set_activity("loading or compiling the simulator's kernels")
            with compile_notice(self._say_compiling):
                compile_kernels()
            stop.check()
            set_activity("building the simulated arms")
            self.sims = make_sim_arms(opts.plant, opts.seed, config, arm)
            ports = {name: self.sims[name].url for name in ARMS}
        else:
            ports = {"leader": opts.leader_port, "follower": opts.follower_port}
        files = {"leader": opts.leader_calibration, "follower": opts.follower_calibration}
        set_activity("reading the calibrations")
        self.calibrations = resolve_calibrations(ports, files, lookup=opts.calibrate and not opts.sim)
        stop.check()
        if opts.truth is not None:  # its own file, asked for; before any torque is on
            set_activity("writing the truth file")
            write_truth(self.sims, opts.truth)
        # learned models in the observers (the dynamics model: ~0.4 s), loaded and checked here
        set_activity("loading the learned models")
        models = load_reaction_models({"leader": opts.leader_model, "follower": opts.model}, arm)
        arm_model = self.arm_model
        set_activity("compiling the control kernels")
        loop = BilateralLoop(config, arm, self.sims, self.out, stop, models=models, hand_on=opts.hand_on,
                             realtime=opts.realtime, status=opts.status, on_cycle=opts.on_cycle,
                             arm_model=arm_model)
        self.loop = loop
        if opts.view or opts.view_save is not None:
            loop.open_view(save=opts.view_save, every=opts.view_every)
        loop.pair.offsets = calibration_offsets(self.calibrations, arm.joint_names)
        stop.check()
        if loop.paced:  # before any torque is on: freezing the collector and locking memory take ~0.3 s
            set_activity("entering real-time scheduling")
            loop.realtime = enter_realtime(config.realtime)
            stop.check()
        set_activity("opening the ports and configuring the servos")
        self.buses, self.hw = open_buses(arm, config, ports, self.out, simulated=opts.sim,
                                         checkpoint=stop.check, torque_going_on=self._before_torque)
        loop.attach(self.buses)
        if loop.realtime is not None:  # said once the arms answered (a missing port stays one line)
            loop.status.say(loop.realtime.sentence())
        if loop.models:
            loop.status.say(observer_sentence(loop.models, arm))
        if self.arm_model is not None:
            loop.status.say(f"nominal observers: the identified arm model {opts.arm_model}")
        if not opts.sim or any(self.calibrations.values()):
            loop.status.say(calibration_sentence(self.calibrations))

    def align(self) -> None:
        """Both arms brought into agreement slowly (collect/alignment.py); StartRefused or SafetyStop
        when they cannot be. From here a stop is taken between two cycles."""
        self.align_message = self.loop.align()

    def record(self) -> None:
        """The session file opened (with the truth trace and the live view), then the bilateral loop
        until the duration is over, a stop is requested or a breach stops both arms."""
        opts, config, arm, loop = self.options, self.config, self.arm, self.loop
        self.duration = self.start_motion()
        loop.recorder = make_recorder(self.output, config, arm, self.hw, simulated=opts.sim,
                                      lockstep=not loop.paced, seed=opts.seed, hand_on=opts.hand_on,
                                      force=opts.force, models=loop.models, calibrations=self.calibrations,
                                      arm_model_toml=self.arm_model.to_toml() if self.arm_model else "",
                                      extra_attrs=self.session_attrs())
        if opts.truth_trace is not None:
            loop.truth_trace = TruthTraceWriter(opts.truth_trace, arm.joint_names, self.output.name)
        loop.ctx.recorder = loop.recorder
        if loop.view is not None:
            loop.view.start()
        for w in self.hw["warnings"]:
            loop.event(0.0, "warning", w)
        loop.event(0.0, "start", self.align_message)
        mode = "lockstep simulation" if not loop.paced else "real time"
        loop.status.say(f"recording to {self.output} ({mode}, {config.loop.rate_hz:g} Hz); "
                        "Ctrl+C ends the session")
        self.end_reason = loop.run(self.duration)

    def start_motion(self) -> float | None:
        """What moves the arms while recording, set up right before the session file opens: the
        simulated operator's hand (sim only). Returns the seconds to record (None: until a stop)."""
        loop = self.loop
        if self.sims:
            loop.operator = make_operator(self.options.seed, self.config, self.arm, self.sims)
            states = checked(loop.pair.read_both(), "reading the arms before recording")
            loop.operator.start(states[ARMS.index(loop.hand_arm)].position, 0.0)
        return self.options.duration

    def session_attrs(self) -> dict:
        """Root attributes of the session file beyond the run's own (none for a bilateral run)."""
        return {}

    def safe_stop(self) -> None:
        """Both arms stopped (goal current 0, torque off), the event that says why the run ended, the
        torque state read back from the servos as events, the buses closed, the session file closed
        and the summary printed. Every step runs whatever an earlier one raised (the first such error
        is kept in `clean_up_error`)."""
        if self.result is not None:
            return
        loop, reason = self.loop, self._reason()
        if loop is not None:
            self._step(loop.pair.safe_stop)
            self._step(loop.end_event, reason, self.exc, self.duration)
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
        self.result = self._step(self._finish, reason)
        if self.result is None:
            self.result = RunResult(self.output, 0, 0.0, time.perf_counter() - self.wall0, reason, None, {})

    def close(self) -> None:
        """After the safe stop: the simulated arms closed, normal scheduling, memory and garbage
        collection again."""
        if self.closed:
            return
        for sim in self.sims.values():
            self._step(sim.close)
        if self.loop is not None and self.loop.realtime is not None:
            self._step(self.loop.realtime.restore)
        self.closed = True

    # -- helpers ----------------------------------------------------------------------------------------
    def _say_compiling(self) -> None:
        if self.options.status and self.out is not None:
            print(compile_sentence(), file=self.out, flush=True)

    def _before_torque(self) -> None:
        """Hardware arms (found and configured, torque off) must each have passed a self-test with the
        calibration they run with (collect/selftest_record.py), unless `skip_selftest`."""
        opts = self.options
        if not opts.sim and not opts.skip_selftest:
            ports = {"leader": opts.leader_port, "follower": opts.follower_port}
            for name in ARMS:
                require_selftest(name, ports[name], self.calibrations[name])
        self._torque_going_on()

    def _torque_going_on(self) -> None:
        """From the first torque on, a stop is taken between two steps (the safe stop then runs)."""
        disarm_prompt_exit()  # from here the clean-up must run: no end from outside the main thread
        self.torque_was_on = True
        set_activity(None)
        self._signals.enter_context(self.stop.deferred())

    def _reason(self) -> str:
        if self.end_reason is not None:
            return self.end_reason
        if isinstance(self.exc, KeyboardInterrupt) or (self.exc is None and self.stop.requested):
            signum = getattr(self.exc, "signum", None) or self.stop.signum or signal.SIGINT
            return "interrupted" if signum == signal.SIGINT else "terminated"
        return "error"

    def _step(self, fn, *args):
        try:
            return fn(*args)
        except Exception as exc:  # noqa: BLE001 - the remaining steps must still run
            if self.clean_up_error is None and self.exc is None:
                self.clean_up_error = exc
            return None

    def _finish(self, end_reason: str) -> RunResult:
        """Close the session file with its timing and end reason, print the summary: the RunResult."""
        loop, output, out = self.loop, self.output, self.out
        wall = time.perf_counter() - self.wall0
        if loop is None or loop.recorder is None:  # ended before recording started: no session file
            if loop is not None and end_reason in ("interrupted", "terminated") and self.torque_was_on:
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
            result = RunResult(output, loop.cycles, loop.t_session, wall, end_reason, loop.breach, summary,
                               rms)
            if self.options.status and out is not None:
                print_summary(result, loop.errors, out, lockstep=not loop.paced,
                              realtime=loop.realtime.sentence() if loop.realtime is not None else None,
                              extra=loop.summary_lines())
        return result
