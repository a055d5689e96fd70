"""crane-collect benchmarks: per-cycle cost of the controller and the recorder (no bus), the loop's
achieved rate and jitter in real-time simulation, and the wall time of a lockstep session.

    python benchmarks/run_all.py collect [--quick]      or      python benchmarks/bench_collect.py

Lockstep speed alone, and a before/after comparison on a shared machine: each session runs in
its own process, the trees alternate, and the best of `--repeat` runs of each is compared:

    python benchmarks/bench_collect.py --lockstep 60 --repeat 3
    git archive OLD | tar -x -C /tmp/old      # any other source tree of the project
    python benchmarks/bench_collect.py --lockstep 60 --repeat 3 --against /tmp/old
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _row(metric, value, unit, note=""):
    return {"benchmark": "collect", "metric": metric, "value": float(value), "unit": unit, "note": note}


def _per_cycle_us(fn, n):
    fn(0)
    t = time.perf_counter()
    for k in range(n):
        fn(k)
    return (time.perf_counter() - t) / n * 1e6


def bench_compute(n: int) -> list[dict]:
    from collect.config import load_config
    from collect.controller import ArmSignals, BilateralController
    from collect.operator import SimulatedOperator
    from collect.recorder import SessionRecorder
    from collect.safety import SafetyMonitor
    from crane_io.description import default_arm

    arm = default_arm()
    cfg = load_config()
    ctl = BilateralController(cfg, arm)
    safety = SafetyMonitor(cfg, arm)
    op = SimulatedOperator(0, arm, cfg.loop.rate_hz, cfg)
    rng = np.random.default_rng(0)
    q = np.array([0.0, 0.2, 0.0, -1.2, 0, 0, 0, 0]) + rng.normal(0, 0.01, (n + 1, 8))
    dq = rng.normal(0, 0.1, (n + 1, 8))
    op.start(q[0])

    def control(k):
        cmd = ctl.step(ArmSignals(q[k], dq[k]), ArmSignals(q[k], dq[k]), 0.002)
        tl = safety.limit_torque(q[k], cmd.leader_tau, dq[k])
        tf = safety.limit_torque(q[k], cmd.follower_tau, dq[k])
        ctl.applied(tl, tf)
        safety.check("leader", q[k], dq[k])
        safety.check("follower", q[k], dq[k])

    rows = [_row("controller + safety per cycle", _per_cycle_us(control, n), "us",
                 f"both arms, gravity model {ctl.gravity.kind}")]
    op_us = _per_cycle_us(lambda k: op.torque(k * 0.002, q[k], dq[k]), n)
    rows.append(_row("simulated operator per cycle", op_us, "us"))
    with tempfile.TemporaryDirectory() as d:
        rec = SessionRecorder(Path(d) / "b.h5", joint_names=arm.joint_names, rate_hz=500, source="bench")
        zeros = np.zeros(8)

        def record(k):
            row = {}
            for a in ("leader", "follower"):
                row.update({f"{a}/t": k * 0.002, f"{a}/q": q[k], f"{a}/tau": zeros, f"{a}/dq_servo": dq[k],
                            f"{a}/current": zeros, f"{a}/goal_current": zeros, f"{a}/dq": dq[k],
                            f"{a}/tau_dis": zeros, f"{a}/tau_res": zeros, f"{a}/q_goal": zeros})
            row.update({"timing/cycle_start": k * 0.002, "timing/period": 0.002,
                        "timing/bus_time_leader": 0.0, "timing/bus_time_follower": 0.0,
                        "timing/compute_time": 0.0, "timing/overrun": False})
            rec.append(row)

        rows.append(_row("recorder append per cycle", _per_cycle_us(record, n), "us",
                         "incl. flushes (every 0.5 s of data), gzip 1"))
        rec.close()
        size = os.path.getsize(Path(d) / "b.h5")
    rows.append(_row("session size", size / (n + 1) * 500 * 60 / 1e6, "MB per minute", "500 Hz, random data"))
    return rows


def _session(duration: float, realtime: bool, plant: str | None) -> dict:
    """Run one simulated session; a safety stop (a loop that cannot keep up in real time makes the
    control unstable) still reports the loop timing of what ran, read back from the session file."""
    import h5py

    from collect.runner import RunOptions, run_session
    from crane_io.errors import CraneError

    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "s.h5"
        t = time.perf_counter()
        cpu = time.process_time()
        try:
            r = run_session(RunOptions(output=out, sim=True, plant=plant, duration=duration,
                                       realtime=realtime, status=False))
            return {"wall": r.wall_s, "cpu": time.process_time() - cpu, "summary": r.summary,
                    "cycles": r.cycles, "note": ""}
        except CraneError as exc:
            summary, cycles = {}, 0
            if out.exists():
                with h5py.File(out, "r") as f:
                    summary = {k: float(v) for k, v in f["timing"].attrs.items()}
                    cycles = f["follower/t"].shape[0]
            return {"wall": time.perf_counter() - t, "cpu": time.process_time() - cpu, "summary": summary,
                    "cycles": cycles,
                    "note": f"; ended early after {cycles} cycles: {exc}"}


def run(quick: bool = False) -> list[dict]:
    rows = bench_compute(2000 if quick else 20000)
    rt = 5.0 if quick else 60.0
    s = _session(rt, True, "simple")
    m = {k: s["summary"].get(k, float("nan")) for k in ("rate_hz", "period_std_s", "period_p99_s",
                                                         "period_max_s", "overruns", "cycles",
                                                         "bus_leader_mean_s")}
    note = f"{rt:g} s, --sim --realtime --plant simple (wall-clock sim arms in this process){s['note']}"
    rows += [_row("real-time loop rate", m["rate_hz"], "Hz", note),
             _row("real-time period std (jitter)", m["period_std_s"] * 1e3, "ms", note),
             _row("real-time period p99", m["period_p99_s"] * 1e3, "ms", note),
             _row("real-time period max", m["period_max_s"] * 1e3, "ms", note),
             _row("real-time overruns", m["overruns"] / max(m["cycles"], 1) * 100, "%", note),
             _row("real-time bus time per cycle (leader)", m["bus_leader_mean_s"] * 1e3, "ms", note)]
    lock = 10.0 if quick else 180.0
    load_before = os.getloadavg()[0]
    s = _session(lock, False, None)
    load = f"load average {load_before:.1f}-{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    m = {k: s["summary"].get(k, float("nan")) for k in ("bus_leader_mean_s", "bus_follower_mean_s",
                                                         "compute_mean_s", "record_mean_s")}
    note = (f"{lock:g} s session, two arms, --sim lockstep, default plant, incl. start-up and alignment, "
            f"{load}{s['note']}")
    rows += [_row("lockstep session wall time", s["wall"], "s", note),
             _row("lockstep speed", lock / s["wall"], "x real time", f"{note}; goal >= 10x"),
             _row("lockstep speed per CPU s", lock / s["cpu"], "x real time",
                  f"simulated s per CPU s of this process (less inflated by other jobs); {load}"),
             _row("lockstep session CPU time", s["cpu"], "s",
                  "what the wall time would be on a free core (the wall time grows with the machine's load)"),
             _row("lockstep bus time per cycle (both arms)",
                  (m["bus_leader_mean_s"] + m["bus_follower_mean_s"]) * 1e6, "us", "sim chain + SDK"),
             _row("lockstep compute per cycle", m["compute_mean_s"] * 1e6, "us",
                  "operator+controller+safety"),
             _row("lockstep record per cycle", m["record_mean_s"] * 1e6, "us", note)]
    return rows


def lockstep_once(seconds: float, seed: int = 0) -> dict:
    """One lockstep `crane-collect run --sim` session in this process: wall and CPU seconds of the whole
    run (start-up, alignment, file) and the loop's CPU time per bilateral cycle."""
    from collect.runner import RunOptions, run_session

    mark = {}

    def at_cycle(k, _ctx):
        if k == 0:
            mark["cpu"] = time.process_time()

    with tempfile.TemporaryDirectory() as d:
        t, cpu = time.perf_counter(), time.process_time()
        r = run_session(RunOptions(output=Path(d) / "s.h5", sim=True, seed=seed, duration=seconds,
                                   status=False, on_cycle=at_cycle))
        end_cpu = time.process_time()
        return {"wall": time.perf_counter() - t, "cpu": end_cpu - cpu, "cycles": r.cycles,
                "loop_cpu_us": (end_cpu - mark["cpu"]) / max(r.cycles, 1) * 1e6}


def _in_process(tree: str | None, seconds: float, seed: int) -> dict:
    """lockstep_once in a fresh process whose `crane_io` and `collect` come from `tree` (None: these)."""
    import json
    import subprocess

    env = dict(os.environ)
    env.pop("CRANE_BENCH_TREE", None)
    if tree is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(tree)] + [p for p in [env.get("PYTHONPATH")] if p])
        env["CRANE_BENCH_TREE"] = str(Path(tree).resolve())
    out = subprocess.run([sys.executable, __file__, "--one", str(seconds), str(seed)], env=env,
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def compare_lockstep(seconds: float, repeat: int, against: str | None, seed: int = 0) -> None:
    """Print the lockstep speed of this tree (and of `against`), runs alternated, best of `repeat`."""
    trees = {"this tree": None} if against is None else {"against": against, "this tree": None}
    best: dict[str, dict] = {name: {} for name in trees}
    for _ in range(repeat):
        for name, tree in trees.items():
            load = os.getloadavg()[0]
            r = _in_process(tree, seconds, seed)
            print(f"{name:<10} wall {r['wall']:6.2f} s  CPU {r['cpu']:6.2f} s  loop CPU "
                  f"{r['loop_cpu_us']:6.0f} us/cycle  ({seconds / r['wall']:.2f}x real time; "
                  f"load {load:.1f})")
            for k, v in r.items():
                best[name][k] = min(best[name].get(k, v), v)
    for name, b in best.items():
        print(f"best {name:<10} {seconds / b['wall']:.2f}x real time (wall), "
              f"{seconds / b['cpu']:.2f}x per CPU s, loop {b['loop_cpu_us']:.0f} us CPU per two-arm cycle")
    if against is not None:
        a, t = best["against"], best["this tree"]
        print(f"this tree / against: wall x{a['wall'] / t['wall']:.3f}, CPU x{a['cpu'] / t['cpu']:.3f}, "
              f"loop CPU x{a['loop_cpu_us'] / t['loop_cpu_us']:.3f}")


if __name__ == "__main__":
    args = sys.argv[1:]
    if args[:1] == ["--one"]:
        import json

        tree = os.environ.get("CRANE_BENCH_TREE")
        if tree:  # check that the other tree's code runs (not this one's, e.g. from the working directory)
            import crane_io

            assert Path(crane_io.__file__).resolve().is_relative_to(tree), crane_io.__file__

        print(json.dumps(lockstep_once(float(args[1]), int(args[2]))))
    elif "--lockstep" in args:
        def _opt(name, default):
            return args[args.index(name) + 1] if name in args else default

        compare_lockstep(float(_opt("--lockstep", 60)), int(_opt("--repeat", 3)), _opt("--against", None))
    else:
        for r in run(quick="--quick" in args):
            print(f"{r['metric']:<42} {r['value']:>10.3f} {r['unit']:<14} {r['note']}")
