"""Real-time scheduling and garbage-collection handling: period error of the paced 500 Hz loop.

    python benchmarks/run_all.py realtime [--quick]        or       python benchmarks/bench_realtime.py
    ../shared/tools/under-load -n 8 -- .venv/bin/python benchmarks/run_all.py realtime    # loaded

`collect.pacing.CycleTimer` paces a realistic cycle of the bilateral loop without the bus: both arms'
controller (pinocchio gravity and pose-dependent inertia), safety clamps and checks, and a recorder-
like row (a dict of arrays appended to a buffer that is dropped every second, as the recorder.s
flushes do), in a process that holds the whole collect stack (a heap of the size the real loop has).
Four variants, each `collect.realtime.enter_realtime` with a different [realtime] configuration,
restored afterwards: normal scheduling or SCHED_FIFO (+ memory locked + pinned to the last core),
each with the collector automatic or frozen out of the cycle (a generation-0 collection between
cycles). Reported: p50 / p99 / max of |period - nominal| and the overrun share, and the longest
garbage collection that happened inside the loop. The note says the load average: figures from a
shared machine only mean something beside it.

The machine's floor (`--floor SECONDS`, and a 10 s row in the table): the same pacing under SCHED_FIFO,
pinned, collector frozen, with no work at all but reading the pinned core's steal time from /proc/stat
every cycle. Whatever period errors it shows come from the machine (a virtual machine's host taking the
core away, interrupts), not from the loop; each late period is checked against the steal ticks counted
within two cycles of it.

    python benchmarks/bench_realtime.py --floor 600 [--cpu N]   # ten minutes of the floor alone
"""

from __future__ import annotations

import gc
import os
import sys
import time
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

RATE_HZ = 500.0
VARIANTS = (  # name, [realtime] settings
    ("normal, gc automatic", dict(scheduling="off", lock_memory=False, freeze_gc=False)),
    ("normal, gc frozen", dict(scheduling="off", lock_memory=False, freeze_gc=True)),
    ("SCHED_FIFO, gc automatic", dict(scheduling="fifo", lock_memory=True, freeze_gc=False)),
    ("SCHED_FIFO, gc frozen", dict(scheduling="fifo", lock_memory=True, freeze_gc=True)),
)


def _row(metric, value, unit, note=""):
    return {"benchmark": "realtime", "metric": metric, "value": float(value), "unit": unit, "note": note}


def _workload():
    """One cycle of the loop's computing and recording (no bus), as a callable of the cycle index."""
    from collect.config import load_config
    from collect.controller import ArmSignals, BilateralController
    from collect.safety import SafetyMonitor
    from crane_io.description import default_arm

    arm = default_arm()
    cfg = load_config()
    ctl = BilateralController(cfg, arm)
    safety = SafetyMonitor(cfg, arm)
    rng = np.random.default_rng(0)
    q0 = np.array([0.0, 0.2, 0.0, -1.2, 0, 0, 0, 0])
    buffer: list[dict] = []
    flush_every = int(RATE_HZ)  # rows live up to 1 s: some reach the older generations

    def cycle(k: int) -> None:
        q = q0 + 0.01 * np.sin(k * 0.01) + rng.normal(0, 1e-4, 8)
        dq = rng.normal(0, 0.05, 8)
        cmd = ctl.step(ArmSignals(q, dq), ArmSignals(q, dq), 1.0 / RATE_HZ)
        tl = safety.limit_torque(q, cmd.leader_tau, dq)
        tf = safety.limit_torque(q, cmd.follower_tau, dq)
        ctl.applied(tl, tf)
        safety.check("leader", q, dq)
        safety.check("follower", q, dq)
        est = ctl.follower
        buffer.append({"t": k / RATE_HZ, "q": q, "tau": tf, "dq": est.dq, "tau_dis": est.tau_dis,
                       "tau_res": est.tau_res, "events": [("cycle", k)]})
        if len(buffer) >= flush_every:
            np.stack([r["q"] for r in buffer])  # what a flush copies out
            buffer.clear()

    return cycle


class _GcWatch:
    """The longest garbage collection (any generation) while installed."""

    def __init__(self):
        self.longest = 0.0
        self.count = 0
        self._t = 0.0

    def __call__(self, phase, info):
        if phase == "start":
            self._t = time.perf_counter()
        else:
            self.count += 1
            self.longest = max(self.longest, time.perf_counter() - self._t)


def measure(cycles: int, settings: dict, workload) -> dict:
    """Pace `cycles` cycles of `workload` at 500 Hz under `settings`; period errors and gc pauses."""
    from collect.config import RealtimeConfig
    from collect.pacing import CycleTimer
    from collect.realtime import enter_realtime

    gc.collect()  # every variant starts from the same heap (no garbage left from the one before)
    rt = enter_realtime(RealtimeConfig(**settings))
    watch = _GcWatch()
    gc.callbacks.append(watch)
    try:
        timer = CycleTimer(RATE_HZ, spin_s=2e-4, window=100)
        timer.start()
        for k in range(cycles):
            workload(k)
            rt.collect_garbage()
            timer.wait()
        periods = timer.periods()
        granted = rt.fifo
        sentence = rt.sentence()
    finally:
        gc.callbacks.remove(watch)
        rt.restore()
    err = np.abs(periods - 1.0 / RATE_HZ)
    return {"p50": float(np.percentile(err, 50)), "p99": float(np.percentile(err, 99)),
            "max": float(err.max()), "overruns": timer.overruns / max(timer.cycles - 1, 1),
            "gc_longest": watch.longest, "gc_count": watch.count, "fifo": granted, "sentence": sentence}


class _Steal:
    """Steal-time ticks (USER_HZ, 10 ms) of one core, read from /proc/stat with one kept descriptor."""

    def __init__(self, cpu: int):
        self._prefix = f"cpu{cpu} ".encode()
        try:
            self._f = open("/proc/stat", "rb", buffering=0)
        except OSError:
            self._f = None

    def __call__(self) -> int:
        if self._f is None:
            return 0
        self._f.seek(0)
        for line in self._f.read(1 << 16).split(b"\n"):
            if line.startswith(self._prefix):
                fields = line.split()
                return int(fields[8]) if len(fields) > 8 else 0
        return 0


def floor(seconds: float, cpu: int = -1) -> dict:
    """The bare paced loop (module docstring): period errors the machine alone causes."""
    from collect.config import RealtimeConfig
    from collect.pacing import CycleTimer
    from collect.realtime import enter_realtime

    cycles = int(seconds * RATE_HZ)
    gc.collect()
    rt = enter_realtime(RealtimeConfig(scheduling="fifo", lock_memory=True, freeze_gc=True, cpu=cpu))
    try:
        cpu = rt.cpu if rt.cpu is not None else max(os.sched_getaffinity(0))
        steal = _Steal(int(cpu))
        ticks = np.zeros(cycles, dtype=np.int64)
        timer = CycleTimer(RATE_HZ, spin_s=2e-4, window=100)
        timer.start()
        for k in range(cycles):
            ticks[k] = steal()
            timer.wait()
        periods = timer.periods()
        granted, sentence = rt.fifo, rt.sentence()
    finally:
        rt.restore()
    err = np.abs(periods - 1.0 / RATE_HZ)
    late = np.nonzero(periods - 1.0 / RATE_HZ > 2e-3)[0]  # period k ends at cycle k + 1
    stolen = np.nonzero(np.diff(ticks) > 0)[0] + 1  # cycles whose read saw a new tick
    near = sum(1 for i in late if np.any(np.abs(stolen - (i + 1)) <= 2))
    return {"p50": float(np.percentile(err, 50)), "p99": float(np.percentile(err, 99)),
            "max": float(err.max()), "late": int(late.size), "late_near_steal": int(near),
            "steal_ticks": int(ticks[-1] - ticks[0]), "cycles": cycles, "cpu": int(cpu),
            "chance": float(min(1.0, 5 * stolen.size / max(cycles, 1))), "fifo": granted,
            "sentence": sentence}


def floor_rows(seconds: float, cpu: int = -1) -> list[dict]:
    m = floor(seconds, cpu)
    note = (f"{seconds:g} s on CPU {m['cpu']}, load average {os.getloadavg()[0]:.1f}; "
            f"{m['late']} periods > 2 ms late, {m['late_near_steal']} of them within 2 cycles of a steal "
            f"tick ({m['steal_ticks']} ticks of 10 ms; chance {m['chance'] * 100:.2f} % of cycles)")
    if not m["fifo"]:
        note += "; SCHED_FIFO refused: " + m["sentence"]
    return [_row("machine floor (no work, SCHED_FIFO): p99 |period - 2 ms|", m["p99"] * 1e3, "ms", note),
            _row("machine floor (no work, SCHED_FIFO): max |period - 2 ms|", m["max"] * 1e3, "ms",
                 f"p50 {m['p50'] * 1e6:.0f} us")]


def run(quick: bool) -> list[dict]:
    import collect.runner  # noqa: F401 - the whole collect stack in the heap, as in a real run

    cycles = 500 if quick else 5000
    workload = _workload()
    for k in range(50):  # warm-up: first-call costs (pinocchio, numpy) out of the figures
        workload(k)
    rows = []
    for name, settings in VARIANTS:
        m = measure(cycles, settings, workload)
        note = f"load average {os.getloadavg()[0]:.1f} (1 min, after), {os.cpu_count()} CPUs, {cycles} cycles"
        if settings["scheduling"] == "fifo" and not m["fifo"]:
            note += "; SCHED_FIFO refused: " + m["sentence"]
        rows.append(_row(f"{name}: p99 |period - 2 ms|", m["p99"] * 1e3, "ms", note))
        rows.append(_row(f"{name}: max |period - 2 ms|", m["max"] * 1e3, "ms",
                         f"p50 {m['p50'] * 1e6:.0f} us"))
        rows.append(_row(f"{name}: overruns", m["overruns"] * 100, "%", ""))
        rows.append(_row(f"{name}: longest gc in the loop", m["gc_longest"] * 1e3, "ms",
                         f"{m['gc_count']} collections"))
    return rows + floor_rows(1.0 if quick else 10.0)


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from run_all import table

    if "--floor" in sys.argv:
        cpu = int(sys.argv[sys.argv.index("--cpu") + 1]) if "--cpu" in sys.argv else -1
        print(table(floor_rows(float(sys.argv[sys.argv.index("--floor") + 1]), cpu)))
    else:
        print(table(run("--quick" in sys.argv)))
