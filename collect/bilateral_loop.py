"""The bilateral loop of a collection run: both arms read, the controller, the safety checks, both arms
written, one row recorded, every cycle (collect/runner.py runs it inside `BilateralRun`).

A cycle: read both arms (concurrently on hardware: one thread per bus; every read is a checkpoint for a
stop request), the simulated operator's push, the 4-channel controller (collect/controller.py), the
safety clamps and checks (collect/safety.py), write both arms, poll the servos' hardware errors now
and then, record the row (collect/recorder.py), the live status line and view. A breach stops both
arms at once (goal current 0, torque off) and ends the loop with its event.
"""

from __future__ import annotations

import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from crane_io import session_format as fmt
from crane_io.description import ArmDescription
from crane_io.errors import CraneError

from .alignment import align
from .arm_pair import ARMS, ArmPair
from .config import Config
from .controller import ArmSignals, BilateralController
from .loop_models import observer_sentence, reaction_factories
from .operator import SimulatedOperator
from .pacing import CycleTimer
from .realtime import RealtimeState
from .recorder import SessionRecorder
from .safety import Breach, SafetyMonitor
from .status import StatusLine

__all__ = ["BilateralLoop", "RunContext"]

# the recorded row's keys ("leader/q", "timing/period", ...), by member name: _LEADER.q
_LEADER, _FOLLOWER = (SimpleNamespace(**{m.name: fmt.arm_path(arm, m.name) for m in fmt.ARM_MEMBERS})
                      for arm in ARMS)
_TIMING = SimpleNamespace(**{m.name: fmt.timing_path(m.name) for m in fmt.TIMING_MEMBERS})
# a paced loop stops the recorder's deferred writes this long before the next deadline (the wait's
# final spin is 0.2 ms): what is left waits for the next cycle's slack
WRITE_MARGIN_S = 3e-4
# the members of a recorded row, in the order _record gives their values
_ROW_MEMBERS = ("t", "q", "tau", "dq_servo", "current", "goal_current", "dq", "tau_dis", "tau_res", "q_goal")
_ROW_TIMING = ("cycle_start", "period", "bus_time_leader", "bus_time_follower", "compute_time", "overrun")
_ROW_KEYS = (tuple(getattr(arm, m) for arm in (_LEADER, _FOLLOWER) for m in _ROW_MEMBERS)
             + tuple(getattr(_TIMING, m) for m in _ROW_TIMING))


def record_numbers(ql, qf, err_sq, bil, sent_l, current_l, sent_f, current_f, kt, out):
    """A row's numbers, as `BilateralLoop._record`'s numpy path computes them (the same float operations):
    err_sq += (ql - qf) ** 2 as e * e, and out[0], out[1] = the recorded torques of leader and follower,
    np.where(bil, sent, current) * kt."""
    for j in range(ql.shape[0]):
        e = ql[j] - qf[j]
        err_sq[j] += e * e
        if bil[j]:
            out[0, j] = sent_l[j] * kt[j]
            out[1, j] = sent_f[j] * kt[j]
        else:
            out[0, j] = current_l[j] * kt[j]
            out[1, j] = current_f[j] * kt[j]


_F = "float64[::1]"
_RECORD_SIGNATURES = {"record_numbers": (f"void({_F}, {_F}, {_F}, boolean[::1], {_F}, {_F}, {_F}, {_F}, "
                                         f"{_F}, float64[:, ::1])",)}
_RECORD_KERNEL = None


def _record_kernel():
    """record_numbers compiled (crane_io.jit; or loaded from numba's cache) for float64 arrays only: an
    argument of another kind raises TypeError (it is never compiled lazily) and the numpy path takes it.
    None without numba."""
    global _RECORD_KERNEL
    if _RECORD_KERNEL is None:
        try:
            from crane_io.jit import compile_functions

            fns = compile_functions(globals(), ("record_numbers",), _RECORD_SIGNATURES,
                                    qualname_prefix="bilateral_loop.")
            if fns is not None:
                fns["record_numbers"].disable_compile()
        except Exception:  # noqa: BLE001 - a broken numba install: the numpy path, as without numba
            fns = None
        _RECORD_KERNEL = False if fns is None else fns["record_numbers"]
    return _RECORD_KERNEL or None


@dataclass
class RunContext:
    """What a test hook can reach while the loop runs."""

    config: Config
    arm: ArmDescription
    buses: dict
    sims: dict  # arm name -> SimulatedArm (sim only)
    recorder: SessionRecorder | None = None


class BilateralLoop:
    """The bilateral loop and what it keeps between cycles; built before any torque is on.

    `models`: {arm: ArmModel} learned models for the observers (collect/loop_models.py, loaded and
    checked before); `hand_on`: the arm the simulated operator's hand moves; `realtime`: paced by the
    wall clock although the arms are simulated; `status`: the live status line on `out`; `on_cycle`:
    the test hook called every cycle with (k, RunContext)."""

    def __init__(self, config: Config, arm: ArmDescription, sims: dict, out, stop=None, *,
                 models: dict | None = None, hand_on: str = "leader", realtime: bool = False,
                 status: bool = True, on_cycle: Callable[[int, RunContext], None] | None = None,
                 arm_model=None):
        self.on_cycle = on_cycle
        self.stop = stop  # crane_io.shutdown.StopRequest: checked at the top of every cycle
        self.config = config
        self.arm = arm
        self.sims = sims
        # Simulated arms in this process advance one period per cycle, also with `realtime`, which paces
        # the loop by the wall clock (collect/sim_arms.py says why): their time is the session's time.
        self.lockstep = bool(sims)
        self.paced = not sims or realtime  # wait for the wall clock between cycles
        self.realtime: RealtimeState | None = None  # what the OS granted the paced loop
        self.period = config.loop.period_s
        self.models = models or {}  # learned models in the observers
        self.ctl = BilateralController(config, arm, models=reaction_factories(self.models, arm, config),
                                       arm_model=arm_model)
        self.fallback_on = {name: None for name in self.models}  # joints on the nominal model now
        self.fallback_events = 0
        self.hand_arm = hand_on  # the arm the simulated operator's hand moves
        self.truth_trace = None  # collect.truth_trace.TruthTraceWriter (RunOptions.truth_trace)
        self._hand_torque = None  # the hand's torque acting when this cycle's angles were read
        self.safety = SafetyMonitor(config, arm)
        self.kt = np.array([j.torque_constant for j in arm.joints])
        self.bil = np.array([n in arm.bilateral_joints for n in arm.joint_names])
        held_goal = np.array([config.held.get(n, 0.0) for n in arm.joint_names])
        self.q_goal_row = np.where(self.bil, np.nan, held_goal)
        # hardware: one thread per bus; every read of both arms is a checkpoint for a stop request
        self.pair = ArmPair(concurrent_io=not sims, checkpoint=stop.check if stop is not None else None)
        self.status = StatusLine(out, config.loop, status)
        self.recorder: SessionRecorder | None = None
        self._columns: tuple = (None, None)  # (the recorder, its row_writer of _ROW_KEYS)
        self.operator: SimulatedOperator | None = None
        # a reference motion that takes the place of the bilateral law: `control(t, sl, sf, dt, ctl, safety)`
        # gives (tau_l, tau_f, breach) as BilateralController.control does (collect/excitation_motion.py)
        self.reference = None
        self.timer = CycleTimer(config.loop.rate_hz, lockstep=not self.paced, spin_s=config.loop.spin_s)
        self.cycles = 0
        self.t_session = 0.0
        self.t_start_mono: float | None = None  # hardware: the leader's clock at the first cycle
        self.last_t: float | None = None
        self.err_sq = np.zeros(len(arm.joints))
        self._numbers = _record_kernel()  # compiled now, not at the first row
        self.errors = 0
        self.breach: Breach | None = None
        self.last_event_t = 0.0
        self.ctx = RunContext(config, arm, {}, sims)
        self.view = None  # collect.live_view.LiveView (open_view): rerun imported, its sink open

    def open_view(self, save=None, every: int = 10) -> None:
        """The live view (rerun imported, a viewer spawned or the .rrd file `save` opened); it logs every
        `every`-th cycle."""
        from .live_view import make_live_view

        self.view = make_live_view(self.arm, save=save, every=every, warn=self._view_warning)

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

    def align(self, own_pose: bool = False) -> str:
        return align(self.pair, self.ctl, self.safety, self.config, self.arm, simulated=bool(self.sims),
                     lockstep=self.lockstep, paced=self.paced, say=self.status.say,
                     between_cycles=self.between_cycles, own_pose=own_pose)

    def between_cycles(self) -> None:
        """After a cycle's writes, before the wait: the small garbage collection kept out of the cycle,
        and the recorder's deferred chunk writes that fit before the next deadline."""
        if self.realtime is not None:
            self.realtime.collect_garbage()
        recorder = self.recorder
        if recorder is not None and recorder.deferred_writes:
            timer = self.timer
            recorder.write_pending(timer.deadline - WRITE_MARGIN_S, timer.clock)

    # -- bilateral control --------------------------------------------------------------------------
    def run(self, duration: float | None) -> str:
        """Cycles until the duration is over ("duration") or a breach stops both arms ("safety_stop")."""
        hooks = self.on_cycle
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
        t = k * self.period if self.lockstep else self._session_time(k, sl)
        if el is None and ef is None:  # the usual case of `_transfer_faults`: both reads went through
            self.safety.bus_ok("leader")
            self.safety.bus_ok("follower")
        else:
            ended, breach = self._read_failed((el, ef), (bt_l, bt_f), t)
            if ended:
                return breach, t
            bt_l = bt_f = 0.0  # counted
        tc = time.perf_counter()
        tau_l, tau_f, breach = self._control(t, sl, sf)
        tc = time.perf_counter() - tc
        if breach is not None:
            timer.add_cycle(bt_l, bt_f, tc)
            return breach, t
        (sent_l, wl, bw_l), (sent_f, wf, bw_f) = self.pair.write_currents(tau_l / kt, tau_f / kt)
        timer.add_cycle(bt_l + bw_l, bt_f + bw_f, tc)  # each bus's read and write, the cycle's compute
        if wl is not None or wf is not None:
            _, breach = self._transfer_faults((wl, wf), t, reading=False)
        if breach is None and k and self.safety.poll_due(k):
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

    def _read_failed(self, errors, bus_times, t: float) -> tuple[bool, Breach | None]:
        """A read of (leader, follower) failed on some bus: count the reads' bus times and the faults;
        (whether the cycle ends here, the breach that ends the run)."""
        self.timer.add("bus_leader", bus_times[0])
        self.timer.add("bus_follower", bus_times[1])
        failed, breach = self._transfer_faults(errors, t, reading=True)
        if breach is not None:
            return True, breach
        if failed:
            if self.lockstep:  # nothing was written: let the simulated time pass anyway
                for sim in self.sims.values():
                    sim.chain.advance(self.period)
            return True, None
        return False, None

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
        dt = self.period if (self.lockstep or self.last_t is None) else max(t - self.last_t, 1e-4)
        self.last_t = t
        if self.reference is not None:
            return self.reference.control(t, sl, sf, dt, self.ctl, self.safety)
        ql, qf = sl.position, sf.position
        sim_hand = self.sims.get(self.hand_arm)
        if sim_hand is not None:
            plant = sim_hand.plant
            if self.truth_trace is not None:
                self._hand_torque = plant.external_torque()
            s = sl if self.hand_arm == "leader" else sf
            plant.set_external_torque(self.operator.torque(t, s.position, s.velocity))
        # step, both safety clamps, applied, both checks: one compiled call where it can be
        # (BilateralController.control); the breach is logged by the caller, after the model's events
        leader, follower = ArmSignals(ql, sl.velocity, sl.current), ArmSignals(qf, sf.velocity, sf.current)
        _cmd, tau_l, tau_f, breach = self.ctl.control(leader, follower, dt, self.safety)
        if self.models:
            self._model_fallbacks(t)
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
        # the torque recorded: the commanded one of the current-mode joints, the measured one of the held
        # joints (np.where(bil, sent * kt, current * kt), selected before the product: the same numbers)
        numbers = self._numbers
        if numbers is not None:
            out = np.empty((2, kt.shape[0]))
            try:
                numbers(sl.position, sf.position, self.err_sq, bil, sent_l, sl.current, sent_f, sf.current,
                        kt, out)
                tl_rec, tf_rec = out[0], out[1]
            except TypeError:  # arrays of another kind than it was compiled for: the numpy path
                numbers = None
        if numbers is None:
            e = sl.position - sf.position
            self.err_sq += e * e
            tl_rec = np.where(bil, sent_l, sl.current) * kt
            tf_rec = np.where(bil, sent_f, sf.current) * kt
        est_l, est_f = self.ctl.leader, self.ctl.follower
        recorder = self.recorder
        if self._columns[0] is not recorder:
            self._columns = (recorder, recorder.row_writer(_ROW_KEYS))
        last = timer.last
        self._columns[1]((  # in _ROW_KEYS order
            t, sl.position, tl_rec, sl.velocity, sl.current, sent_l, est_l.dq, est_l.tau_dis, est_l.tau_res,
            self.q_goal_row,
            t if self.lockstep else sf.t - self.t_start_mono, sf.position, tf_rec, sf.velocity, sf.current,
            sent_f, est_f.dq, est_f.tau_dis, est_f.tau_res, self.q_goal_row,
            timer.now(), timer.last_period, last["bus_leader"], last["bus_follower"], last["compute"],
            timer.last_overrun,
        ))
        if self.truth_trace is not None:
            self._record_truth(t)
        timer.add("record", time.perf_counter() - tr)
        if self.view is not None:  # copies a sample every view_every cycles; idle() logs it
            self.view.log_cycle(t, sl.position, sf.position, tl_rec, tf_rec, est_l, est_f, timer.last_period)

    def _record_truth(self, t: float) -> None:
        """The plants' true external torques in this row (the truth trace): contact, and the hand that was
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

    def summary_lines(self) -> list[str]:
        """The summary's lines on the reference motion (its own `summary_lines`) and on the learned models
        in the observers (none without a model)."""
        lines = list(self.reference.summary_lines()) if self.reference is not None else []
        if not self.models:
            return lines
        lines.append(observer_sentence(self.models, self.arm))
        for name, m in self.models.items():
            reaction = self.ctl.reaction(name)
            if reaction is None:
                continue
            cycles = {j: int(c) for j, c in zip(m.joints, reaction.fallback_cycles) if c}
            if cycles:
                lines.append(f"{name} model fell back to the nominal one in " + ", ".join(
                    f"{j} {c} cycles" for j, c in cycles.items()) + f" ({self.fallback_events} events)")
        return lines

    def _stop(self, breach: Breach, t: float) -> str:
        self.breach = breach
        self.pair.safe_stop()
        self.event(t, "safety_stop", breach.message, breach.joint)
        return "safety_stop"
