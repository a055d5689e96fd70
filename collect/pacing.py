"""Loop pacing at a fixed rate with absolute deadlines, and the loop's timing statistics.

Deadlines are t0 + k T (no drift however long the run). `wait()` sleeps until shortly before the
next deadline and busy-waits the rest (sleep alone overshoots by up to a scheduler tick). A cycle
that ends after its deadline is an overrun; if a cycle overran by more than a whole period, the grid
is re-anchored at that moment (the missed deadlines are counted and skipped) instead of firing a burst
of late cycles to catch up. In lockstep (simulated, faster
than real time) mode nothing sleeps: the loop runs as fast as it can and the statistics describe the
wall-clock speed.

Named sections (`with timer.section("compute"):`) or `timer.add(name, seconds)` accumulate the time
spent per cycle; the last cycle's values are in `timer.last`, the running statistics in `summary()`.
"""

from __future__ import annotations

import math
import time
from contextlib import contextmanager

import numpy as np

from crane_io.session_format import TIMING_SECTIONS as SECTIONS  # the sections /timing records


class CycleTimer:
    def __init__(self, rate_hz: float, *, lockstep: bool = False, spin_s: float = 2e-4,
                 window: int = 1000, clock=time.perf_counter, sleep=time.sleep):
        if not rate_hz > 0:
            raise ValueError("rate_hz must be positive")
        self.period = 1.0 / rate_hz
        self.rate_hz = rate_hz
        self.lockstep = lockstep
        self.spin_s = spin_s
        self._clock = clock
        self._sleep = sleep
        self._window = np.full(window, np.nan)  # recent periods, for the live status line
        self._all = np.empty(4096)  # every period, for the p99 of the summary
        self.cycles = 0
        self.overruns = 0
        self.skipped_deadlines = 0
        self.t0: float | None = None
        self._deadline = 0.0
        self._cycle_start = 0.0
        self.last: dict[str, float] = dict.fromkeys(SECTIONS, 0.0)
        self.last_period = 0.0
        self.last_overrun = False
        self._totals: dict[str, float] = dict.fromkeys(SECTIONS, 0.0)
        self._max_sections: dict[str, float] = dict.fromkeys(SECTIONS, 0.0)

    @property
    def deadline(self) -> float:
        """The current cycle's deadline, in `clock`'s seconds (meaningless in lockstep)."""
        return self._deadline

    @property
    def clock(self):
        """The clock the timer paces by (time.perf_counter unless given)."""
        return self._clock

    # ---- pacing -------------------------------------------------------------------------------------
    def start(self) -> float:
        """Begin the first cycle now; returns its start time (0.0, seconds since start)."""
        self.t0 = self._clock()
        self._cycle_start = self.t0
        self._deadline = self.t0 + self.period
        self.cycles = 1
        return 0.0

    def wait(self) -> float:
        """End the current cycle, wait for the next deadline and begin the next cycle.
        Returns the new cycle's start in seconds since start()."""
        if self.t0 is None:
            return self.start()
        now = self._clock()
        overrun = now > self._deadline
        if self.lockstep:  # nothing to wait for: the next cycle starts now
            start = now
            overrun = False
        else:
            if overrun:
                missed = math.floor((now - self._deadline) / self.period)
                if missed >= 1:  # more than a whole period late: re-anchor the grid at now
                    self._deadline = now
                    self.skipped_deadlines += missed
            else:
                remaining = self._deadline - now
                if remaining > self.spin_s:
                    self._sleep(remaining - self.spin_s)
                while self._clock() < self._deadline:
                    pass
            start = self._clock()
        period = start - self._cycle_start
        self._record(period, overrun)
        self._cycle_start = start
        self._deadline += self.period
        last = self.last
        for k in last:
            last[k] = 0.0
        return start - self.t0

    def _record(self, period: float, overrun: bool) -> None:
        i = self.cycles - 1
        if i >= self._all.size:
            self._all = np.concatenate([self._all, np.empty(self._all.size)])
        self._all[i] = period
        self._window[i % self._window.size] = period
        self.cycles += 1
        self.last_period = period
        self.last_overrun = overrun
        if overrun:
            self.overruns += 1

    # ---- sections -----------------------------------------------------------------------------------
    @contextmanager
    def section(self, name: str):
        t = self._clock()
        try:
            yield
        finally:
            self.add(name, self._clock() - t)

    def add(self, name: str, seconds: float) -> None:
        last, totals, peak = self.last, self._totals, self._max_sections
        last[name] = last.get(name, 0.0) + seconds
        totals[name] = totals.get(name, 0.0) + seconds
        if seconds > peak.get(name, 0.0):
            peak[name] = seconds

    def add_cycle(self, bus_leader: float, bus_follower: float, compute: float) -> None:
        """add("bus_leader", ...), add("bus_follower", ...) and add("compute", ...) of a whole cycle (its
        read and write on each bus together: the sections' maxima are those of a cycle)."""
        add = self.add
        add("bus_leader", bus_leader)
        add("bus_follower", bus_follower)
        add("compute", compute)

    def now(self) -> float:
        """Seconds since start()."""
        return self._clock() - (self.t0 if self.t0 is not None else self._clock())

    # ---- statistics ---------------------------------------------------------------------------------
    def recent(self) -> dict[str, float]:
        """Rate and jitter over the last `window` cycles (for the live status line)."""
        w = self._window[~np.isnan(self._window)]
        if w.size == 0:
            return {"rate_hz": 0.0, "jitter_s": 0.0, "max_s": 0.0}
        return {"rate_hz": 1.0 / float(w.mean()), "jitter_s": float(w.std()), "max_s": float(w.max())}

    def summary(self) -> dict[str, float]:
        """Period mean, std, p99 and max (s), achieved rate, overruns and mean section times."""
        n = max(self.cycles - 1, 0)
        p = self._all[:n]
        out = {"cycles": float(self.cycles), "overruns": float(self.overruns),
               "skipped_deadlines": float(self.skipped_deadlines), "nominal_period_s": self.period}
        if n:
            out.update(period_mean_s=float(p.mean()), period_std_s=float(p.std()),
                       period_p99_s=float(np.percentile(p, 99)), period_max_s=float(p.max()),
                       rate_hz=1.0 / float(p.mean()))
        else:
            out.update(period_mean_s=0.0, period_std_s=0.0, period_p99_s=0.0, period_max_s=0.0,
                       rate_hz=0.0)
        for k, total in self._totals.items():
            out[f"{k}_mean_s"] = total / max(self.cycles, 1)
            out[f"{k}_max_s"] = self._max_sections.get(k, 0.0)
        return out

    def periods(self) -> np.ndarray:
        return self._all[: max(self.cycles - 1, 0)].copy()
