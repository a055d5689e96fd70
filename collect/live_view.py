"""The live view of `crane-collect run --view` / `--view-save FILE.rrd` (rerun; crane_io/view.py has the
entities): both arms' angles, torques, tau_dis and tau_res, the tracking error, the loop period and the two
arms in 3D.

It must not disturb the loop. Two calls per cycle:
- `log_cycle` (after the cycle's row is recorded) only copies a sample every `every` cycles (default 10:
  50 samples a second at 500 Hz) into buffers kept for it: a few microseconds, nothing sent;
- `idle(timer)` (after the cycle's writes, just before the loop waits for its next deadline) logs that
  sample's parts, one rerun call each (10 time series and two 3D arms: a time series costs 20-100 us, a 3D
  arm with its forward kinematics 130-400 us, the more the busier the machine), in the time the loop would
  otherwise sleep: a part is logged only while the time left to the deadline exceeds what that kind of
  part took recently (a decaying maximum) plus a margin (`margin_s`, default 0.4 ms). So the view's work
  does not make a cycle late (unless the machine stalls the loop mid-part), it only fills the wait. In
  lockstep (the
  simulation runs as fast as it can, nothing waits) at most `parts_per_cycle` parts (default 2) per cycle.
rerun sends the data from its own threads (file or viewer); nothing here waits for them. If the next
sample is due before the previous one's parts are all logged (no slack: an overloaded machine), the rest
of the previous one is skipped (counted in `skipped_parts`): the view gets sparser, the loop stays on time.
Each sample starts with another part (round robin), so what is skipped is spread over all the entities.

Any failure inside the view (rerun, the viewer, the file) is reported once through `warn`, and the view
turns itself off; the recording goes on. `close()` never raises either.

The sink (the .rrd file, or the spawned viewer) is opened when the view is made, before any torque is on
and before the loop asks for real-time scheduling: rerun writes from threads of its own, and a thread
started after that would inherit the loop's SCHED_FIFO priority and its core (Linux threads inherit both)
and compete with the loop. A run that ends before recording starts removes the .rrd it had opened (it
would hold only the static parts).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from crane_io.view import ARMS, SessionView, ViewError

DEFAULT_EVERY = 10
DEFAULT_PARTS_PER_CYCLE = 2
DEFAULT_MARGIN_S = 4e-4
_FIRST_GUESS_S = 5e-4  # cost assumed for a kind of part never logged yet
_DECAY = 0.98  # per logged part: how fast a one-off slow call is forgotten


def check_save_path(path) -> Path:
    """Refuse (ViewError, one sentence) an .rrd path that cannot be written, before anything starts."""
    path = Path(path)
    if path.is_dir():
        raise ViewError(f"`view_save` {path} is a directory; give a file name such as {path / 'view.rrd'}")
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise ViewError(f"`view_save` {path} cannot be written: {parent} is not a writable folder")
    return path


class LiveView:
    """See the module docstring. `start()` says the recording has started (the sink was opened when the
    view was made); `log_cycle` and `idle` are called by the loop; `close()` at the end."""

    def __init__(self, view: SessionView, every: int = DEFAULT_EVERY,
                 parts_per_cycle: int = DEFAULT_PARTS_PER_CYCLE, warn=None,
                 margin_s: float = DEFAULT_MARGIN_S, clock=time.perf_counter):
        if every < 1 or parts_per_cycle < 1:
            raise ViewError("the view logs every N >= 1 cycles, at least one part per cycle")
        self.view = view
        self.every = int(every)
        self.parts_per_cycle = int(parts_per_cycle)
        self.warn = warn
        self.margin_s = float(margin_s)
        self._clock = clock
        self._cost = {"series": _FIRST_GUESS_S, "arm": _FIRST_GUESS_S}  # recent cost per kind of part, s
        self.on = True
        self.failure: str | None = None
        n = len(view.joint_names)
        self._bil = view.bil_cols
        self._sample = {f"{arm}/{sig}": np.full(n, np.nan) for arm in ARMS
                        for sig in ("q", "tau", "tau_dis", "tau_res")}
        self._sample["loop/tracking_error"] = np.zeros(len(self._bil))
        self._sample["loop/period"] = np.zeros(2)
        self._parts = list(view.keys) + list(view.arm_keys)
        self._next = len(self._parts)  # how many of the sample's parts are done; all at first
        self._first = 0  # the part this sample starts with
        self._count = self.every - 1  # the first cycle is sampled
        self._t = 0.0
        self._period_max = 0.0
        self.samples = 0
        self.skipped_parts = 0
        self.started = False

    def start(self) -> None:
        """The recording starts: samples go to the sink from now on."""
        self.started = True

    def log_cycle(self, t: float, q_l, q_f, tau_l, tau_f, est_l, est_f, period: float) -> None:
        """One recorded cycle: session time t, both arms' angles (J,) rad, recorded torques (J,) N m,
        the controller's estimates (`.tau_dis`, `.tau_res`) and the loop period (s) before this cycle.
        Copies a sample every `every` cycles; logs nothing."""
        if not self.on:
            return
        try:
            if period > self._period_max:
                self._period_max = period
            self._count += 1
            if self._count >= self.every:
                self._count = 0
                self._take(t, q_l, q_f, tau_l, tau_f, est_l, est_f, period)
        except Exception as exc:  # noqa: BLE001 - a view failure never reaches the control loop
            self._fail(exc)

    def idle(self, timer) -> None:
        """Between two cycles, before the wait for the next deadline (collect.pacing.CycleTimer `timer`):
        log the pending parts that fit in the time left (all of it in lockstep, up to parts_per_cycle)."""
        parts = self._parts
        if not self.on or self._next >= len(parts):
            return
        try:
            view, clock, cost = self.view, self._clock, self._cost
            deadline = None if timer.lockstep else getattr(timer, "_deadline", None)
            reserve = self.margin_s
            done = 0
            n = len(parts)
            while self._next < n:
                key = parts[(self._first + self._next) % n]
                kind = "arm" if key.startswith("arms/") else "series"
                if deadline is None:
                    if done >= self.parts_per_cycle:
                        break
                elif deadline - clock() < cost[kind] + reserve:
                    break
                t0 = clock()
                view.log_part(key, self._t, self._sample)
                took = clock() - t0
                cost[kind] = max(took, cost[kind] * _DECAY)
                self._next += 1
                done += 1
        except Exception as exc:  # noqa: BLE001 - a view failure never reaches the control loop
            self._fail(exc)

    def _take(self, t, q_l, q_f, tau_l, tau_f, est_l, est_f, period) -> None:
        s = self._sample
        self.skipped_parts += len(self._parts) - self._next
        np.copyto(s["leader/q"], q_l)
        np.copyto(s["follower/q"], q_f)
        np.copyto(s["leader/tau"], tau_l)
        np.copyto(s["follower/tau"], tau_f)
        np.copyto(s["leader/tau_dis"], est_l.tau_dis)
        np.copyto(s["leader/tau_res"], est_l.tau_res)
        np.copyto(s["follower/tau_dis"], est_f.tau_dis)
        np.copyto(s["follower/tau_res"], est_f.tau_res)
        bil = self._bil
        np.subtract(s["leader/q"][bil], s["follower/q"][bil], out=s["loop/tracking_error"])
        s["loop/period"][0] = period
        s["loop/period"][1] = self._period_max
        self._period_max = 0.0
        self._t = t
        self._next = 0
        self._first = self.samples % len(self._parts)
        self.samples += 1

    def _fail(self, exc: BaseException) -> None:
        self.on = False
        self.failure = f"the live view stopped ({exc.__class__.__name__}: {exc}); the recording goes on"
        if self.warn is not None:
            try:
                self.warn(self.failure)
            except Exception:  # noqa: BLE001, S110 - a warning must not fail the loop either
                pass

    def close(self) -> None:
        """Flush and close the view (the .rrd file is complete afterwards); never raises."""
        try:
            self.view.close()
            path = self.view.save_path
            if not self.started and path is not None:  # nothing was recorded: no file, as for the session
                path.unlink(missing_ok=True)
        except Exception as exc:  # noqa: BLE001
            if self.on:
                self._fail(exc)
        self.on = False


def make_live_view(arm, *, save=None, spawn: bool = True, every: int = DEFAULT_EVERY,
                   parts_per_cycle: int = DEFAULT_PARTS_PER_CYCLE, warn=None,
                   margin_s: float = DEFAULT_MARGIN_S) -> LiveView:
    """The live view of a run on `arm` (crane_io.description.ArmDescription), made before any torque is on
    and before real-time scheduling: rerun imported (ViewUnavailableError without it), the .rrd file
    opened or the viewer spawned (ViewError, one sentence, when it cannot be)."""
    if save is not None:
        check_save_path(save)
    view = SessionView(arm.joint_names, arm.bilateral_joints, save=save, spawn=spawn and save is None,
                       recording_name="crane-collect run")
    view.open()  # rerun's sink threads start now, at normal priority (see the module docstring)
    return LiveView(view, every=every, parts_per_cycle=parts_per_cycle, warn=warn, margin_s=margin_s)
