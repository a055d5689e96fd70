"""The control loop over two U2D2 links: achieved rate, late cycles and worst cycle at 500 Hz and 1 kHz
with the FTDI latency timer at 1 ms and 16 ms (docs/rig-timing.md).

    python benchmarks/run_all.py rig_timing [--quick]     or     python benchmarks/bench_rig_timing.py

Two parts:

- "model": the loop's pacing (collect.pacing.CycleTimer, the loop's own) driven on a computed clock
  through two crane_io.sim.adapter_timing links, one per arm: each cycle reads both arms at once (the
  CRANE-X7's Fast Sync Read, 22 bytes out, 120 back), computes for COMPUTE_S and writes both (Goal
  Current Sync Write, 23 bytes, no reply). No machine in it: what the adapters alone allow a host that
  is never late itself. Deterministic; the only part of `--quick`.
- "pty": `crane-collect sim-serve --pair --clock wall --plant simple --latency-timer MS` in a subprocess
  (the simple plant: the least physics competing with the replies) and the run's own start-up check and
  loop (`crane-collect run`'s defaults) on its two links for DURATION_S, the loop forced past the check
  when the check refuses, to show what the refusal spares; a safety stop ends a run early (its cycles
  still count). This is this machine: the pseudo-terminals, the served physics and every other process
  add their delays, so each row's note gives the load average.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

CASES = ((500.0, 1), (1000.0, 1), (500.0, 16), (100.0, 16))  # (rate Hz, latency timer ms)
PTY_CASES = ((500.0, 0), *CASES)  # latency 0: no adapter model, the machine's and the pty's own delays
COMPUTE_S = 0.0003  # the host's own work per cycle in the model (controller, safety, recorder)
READ_OUT, READ_BACK, WRITE_OUT = 22, 120, 23  # bytes of the cycle's packets (benchmarks/bench_bus.py)
BAUD = 3_000_000
MODEL_CYCLES = 5000
PATIENCE_MS = 100.0
DURATION_S = 10.0
LEADER_PHASE_S, FOLLOWER_PHASE_S = 0.0, 0.00037  # where each adapter's timer grid starts (any value)


def _row(metric, value, unit, note=""):
    return {"benchmark": "rig_timing", "metric": metric, "value": float(value), "unit": unit, "note": note}


def _load() -> str:
    return "load average " + " ".join(f"{x:.2f}" for x in os.getloadavg())


def model_loop(rate_hz: float, latency_ms: int, cycles: int = MODEL_CYCLES, compute_s: float = COMPUTE_S):
    """CycleTimer's summary of `cycles` cycles through two modelled adapters (a computed clock)."""
    from collect.pacing import CycleTimer
    from crane_io.sim.adapter_timing import AdapterLink, AdapterTiming

    now = [0.0]

    def clock():
        now[0] += 1e-7  # the timer's busy-wait reads the clock until the deadline
        return now[0]

    def sleep(s):
        now[0] += s

    timing = AdapterTiming(latency_timer_s=latency_ms / 1000)
    links = [AdapterLink(timing, LEADER_PHASE_S), AdapterLink(timing, FOLLOWER_PHASE_S)]
    timer = CycleTimer(rate_hz, clock=clock, sleep=sleep)
    timer.start()
    for _ in range(cycles):
        t = now[0]
        replies = [link.exchange(t, READ_OUT, BAUD, [(READ_BACK, 0.0, BAUD)]) for link in links]
        now[0] = max(r[-1][0] for r in replies) + compute_s
        for link in links:
            link.instruction_end(now[0], WRITE_OUT, BAUD)
        timer.wait()
    return timer.summary()


def _model_rows() -> list[dict]:
    rows = []
    for rate, latency in CASES:
        s = model_loop(rate, latency)
        tag = f"model {rate:g} Hz, latency {latency} ms"
        note = f"adapters only, host work {COMPUTE_S * 1e3:g} ms/cycle"
        rows += [_row(f"{tag}: achieved rate", s["rate_hz"], "Hz", note),
                 _row(f"{tag}: late cycles", 100 * s["overruns"] / max(s["cycles"], 1), "%", note),
                 _row(f"{tag}: worst cycle", 1e3 * s["period_max_s"], "ms", note)]
    return rows


def _serve(folder: Path, latency_ms: int):
    links = {name: folder / name for name in ("leader", "follower")}
    exe = Path(sys.executable).parent / "crane-collect"
    proc = subprocess.Popen([str(exe), "sim-serve", "--pair", "--clock", "wall", "--plant", "simple",
                             "--latency-timer", str(latency_ms), "--leader-link", str(links["leader"]),
                             "--follower-link", str(links["follower"])],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while not all(p.is_symlink() for p in links.values()):
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise RuntimeError(f"sim-serve did not start: {proc.stderr.read().decode()[-300:]}")
        time.sleep(0.1)
    return proc, links


def _start_up_check(links, rate_hz):
    """The run's own check on the links (buses opened, servos configured, torque never on): (timing,
    verdict sentence or None, refused)."""
    from collect.config import load_config
    from collect.link_timing import LinkTooSlow, measure_cycle_transfer, verdict
    from collect.runner import run_arm
    from crane_io.dynamixel.bus import DynamixelBus

    arm = run_arm(load_config())
    # reply timeouts of PATIENCE_MS: a loaded machine's late reply must not be taken for the next one's
    buses = {n: DynamixelBus(str(p), arm, name=n, latency_ms=PATIENCE_MS) for n, p in links.items()}
    try:
        for bus in buses.values():
            bus.open()
            bus.ping_all()
            bus.configure()
        timing = measure_cycle_transfer(buses)
    finally:
        for bus in buses.values():
            bus.close()
    try:
        return timing, verdict(timing, 1 / rate_hz), False
    except LinkTooSlow as exc:
        return timing, str(exc), True


FORCED_RUN = """
import sys
import collect.link_timing as link_timing
link_timing.check_link_timing = lambda *a, **k: None  # forced past the start-up check
from collect.cli import main
main(sys.argv[1:])
"""


def _forced_run(links, rate_hz, duration_s, folder):
    """`crane-collect run` on the links for `duration_s` in its own process, forced past the start-up
    check: (the session's timing, how the run ended). A safety stop (a loop too late to hold the arms)
    ends it early; its recorded cycles still count."""
    import h5py

    out = folder / f"s{rate_hz:g}.h5"
    proc = subprocess.run([sys.executable, "-c", FORCED_RUN, "run", "--leader-port", str(links["leader"]),
                           "--follower-port", str(links["follower"]), "--rate", f"{rate_hz:g}", "--duration",
                           f"{duration_s:g}", "--no-calibration", "--quiet", "-o", str(out), "--force"],
                          capture_output=True, text=True, timeout=600)
    last = (proc.stderr.strip().splitlines() or ["ended"])[-1]
    if not out.exists():
        return {}, f"no session: {last}"
    with h5py.File(out, "r") as f:
        timing = {k: v for k, v in f["timing"].attrs.items()}
        ended = f"{f.attrs.get('end_reason', '?')}, {timing.get('cycles', 0):.0f} cycles"
    return timing, ended if proc.returncode == 0 else f"{ended}: {last}"


def _pty_case(rate, latency, duration_s) -> list[dict]:
    from crane_io.errors import CraneError

    tag = f"pty {rate:g} Hz, latency {latency} ms"
    with tempfile.TemporaryDirectory() as tmp:
        proc, links = _serve(Path(tmp), latency)
        before = _load()
        try:
            timing, sentence, refused = _start_up_check(links, rate)
            rows = [_row(f"{tag}: check best round", 1e3 * timing.best_s, "ms", before),
                    _row(f"{tag}: check median round", 1e3 * timing.median_s, "ms", before),
                    _row(f"{tag}: check refuses", 1.0 if refused else 0.0, "yes=1", sentence or "")]
            s, ended = _forced_run(links, rate, duration_s, Path(tmp))
        except CraneError as exc:  # a loaded machine can make a reply miss its timeout at start-up
            return [_row(f"{tag}: FAILED", float("nan"), "", f"{before}; {exc}")]
        finally:
            proc.terminate()
            proc.wait(timeout=30)
    note = f"{before}; run: {ended}"
    late = 100 * s.get("overruns", 0) / max(s.get("cycles", 1), 1)
    return rows + [_row(f"{tag}: achieved rate", s.get("rate_hz", 0.0), "Hz", note),
                   _row(f"{tag}: late cycles", late, "%", note),
                   _row(f"{tag}: worst cycle", 1e3 * s.get("period_max_s", 0.0), "ms", note)]


def _pty_rows(duration_s: float) -> list[dict]:
    return [row for rate, latency in PTY_CASES for row in _pty_case(rate, latency, duration_s)]


def run(quick: bool = False) -> list[dict]:
    rows = _model_rows()
    if not quick:
        rows += _pty_rows(DURATION_S)
    return rows


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from run_all import table

    print(table(run(quick="--quick" in sys.argv)))
