"""Before torque-on on real ports: can the two links carry one control cycle's traffic in one period?

A CRANE-X7 cycle reads both arms (one Fast Sync Read of current, velocity and position per bus, the two
buses at once, one thread each: collect/arm_pair.py) and writes both (one Sync Write of Goal Current
each, no reply). The reads are what can take long: the host waits for each reply, and a U2D2 hands a
reply to the host only when its USB packet fills or its latency timer expires (FTDI AN232B-04;
crane_io.sim.adapter_timing). With the ftdi_sio default of 16 ms a read takes up to 16 ms, so no rate
of the loop's range (100..2000 Hz) can be kept.

`check_link_timing(buses, period_s)` sends the cycle's real read, on both buses at once, a few times
while the torque is still off (reads change nothing on the servos; the writes are left out, since a goal
written now would act at torque-on, and their bytes take about 0.1 ms at 3 Mbps), each round at the start
of a period as the loop paces its reads, and times each round.
When the median round exceeds `REFUSE_SHARE` of the period the run is refused (LinkTooSlow, one
sentence: the measured time, the rate and what to do); when it exceeds `WARN_SHARE` it gives a warning
sentence. Paced rounds meet the adapter's timer where the loop's reads will meet it (a read that cannot
end within its period is followed at once, as the loop's next one would be); the median keeps a busy
machine's delays and the odd round that catches the timer just before it expires in the tails. Why
refuse rather than warn (docs/rig-timing.md): such a loop is late every cycle, its controller's filters
assume a period it never keeps and its session's time base is irregular, so the recording is of no use,
while refusing before any torque is on costs nothing.

Servos whose Realtime Tick (addr 120, 1 ms) stands still while real time passes are a lockstep
simulation (crane_io.sim: time advances one period per Goal Current write, and waits for the host), so
no rate is impossible there and nothing is timed.
"""

from __future__ import annotations

import concurrent.futures
import statistics
import time
from dataclasses import dataclass

from crane_io.dynamixel.control_table import X_SERIES
from crane_io.errors import HardwareError

from .config import MIN_RATE_HZ

# of the period: the rest is the controller's and the writes' (about 0.3 ms and 0.08 ms a cycle, so a 500 Hz
# loop over 1 ms adapters, whose paced reads take up to about 1.6 ms, still fits)
REFUSE_SHARE = 0.9
WARN_SHARE = 0.5  # of the period: little room left for a busy machine's delays
ROUNDS = 20  # measured rounds of reading both arms
WARM_UP_ROUNDS = 2  # unmeasured rounds first (the first read settles the bus's fast-read choice)
TICK = X_SERIES["realtime_tick"]  # 2 bytes, 1 ms per LSB, wraps at 32767 (e-manual, control table)
TICK_WRAP = 32768
TICK_PAUSE_S = 0.02  # s of real time between the two readings of the Realtime Tick
TICK_TRIES = 10  # pauses a servo's tick may stand still before the servos count as a lockstep simulation
SLOW_LINK_S = 0.002  # s: a cycle's reads slower than a 1 ms latency timer explains: the timer is the cause

LATENCY_ADVICE = ("set each U2D2's latency timer to 1 ms (udev/99-crane-x7.rules, or "
                  "`echo 1 > /sys/bus/usb-serial/devices/ttyUSB0/latency_timer`)")


class LinkTooSlow(HardwareError):
    """The ports cannot carry one control cycle's traffic within the requested period."""


@dataclass(frozen=True)
class LinkTiming:
    """Measured times of one round of reading both arms at once (s): the best, the median, the worst."""

    best_s: float
    median_s: float
    worst_s: float
    rounds: int


def measure_cycle_transfer(buses: dict, rounds: int = ROUNDS, warm_up: int = WARM_UP_ROUNDS,
                           period_s: float | None = None) -> LinkTiming:
    """Read every bus in `buses` at once (one thread each, as the loop does), `warm_up` + `rounds` times,
    each round at the start of a period of `period_s` as the loop paces its reads (a round that ends late
    is followed at once; None: back to back): the best, median and worst time of a measured round. A
    failed read raises its bus's error."""
    if rounds < 1:
        raise ValueError("rounds must be at least 1")
    reads = [bus.read_state for bus in buses.values()]
    times = []
    start = time.perf_counter()
    with concurrent.futures.ThreadPoolExecutor(len(reads), "crane-link-timing") as pool:
        for k in range(warm_up + rounds):
            if period_s is not None:
                start = max(start, time.perf_counter())
                time.sleep(max(0.0, start - time.perf_counter()))
                start += period_s
            t0 = time.perf_counter()
            for future in [pool.submit(read, check_faults=False) for read in reads]:
                future.result()
            if k >= warm_up:
                times.append(time.perf_counter() - t0)
    return LinkTiming(min(times), statistics.median(times), max(times), len(times))


def servos_keep_real_time(buses: dict, pause_s: float = TICK_PAUSE_S, tries: int = TICK_TRIES) -> bool:
    """Whether the first servo of the first bus counts real time: its Realtime Tick read before and after
    `pause_s` of real time, up to `tries` times. False for a lockstep simulation, whose servos' time
    stands still while only reads arrive; a real servo's tick moves in every pause, and a wall-clock
    simulation's moves as soon as its plant gets a turn (a busy machine may delay that by a few pauses)."""
    bus = next(iter(buses.values()))
    sid, joint = bus.ids[0], bus.joint_names[0]

    def tick() -> int:
        return int.from_bytes(bus.read_block(sid, TICK.address, TICK.size, joint), "little")

    first = tick()
    for _ in range(tries):
        time.sleep(pause_s)
        if (tick() - first) % TICK_WRAP:
            return True
    return False


def verdict(timing: LinkTiming, period_s: float) -> str | None:
    """None when the links leave room for the cycle; a warning sentence when they leave little (the
    median round above WARN_SHARE of the period); raises LinkTooSlow when they cannot carry it (above
    REFUSE_SHARE)."""
    rate = 1.0 / period_s
    period = f"the {period_s * 1e3:g} ms period of"
    took = (f"one control cycle's reads of both arms take {timing.median_s * 1e3:.2f} ms over these ports "
            f"(median of {timing.rounds} before torque-on, best {timing.best_s * 1e3:.2f} ms)")
    if timing.median_s > REFUSE_SHARE * period_s:
        fits = _rate_for(timing.median_s)
        lower = (f"lower `rate` to at most {fits:g} Hz" if fits >= MIN_RATE_HZ else
                 f"no rate from {MIN_RATE_HZ:g} Hz up fits this link")
        advice = f"{LATENCY_ADVICE}, or {lower}" if timing.median_s > SLOW_LINK_S else lower
        raise LinkTooSlow(f"{took}, more than {REFUSE_SHARE:.0%} of {period} `rate` {rate:g} Hz, so the loop "
                          f"cannot keep that rate: {advice}")
    if timing.median_s > WARN_SHARE * period_s:
        return (f"{took}, {timing.median_s / period_s:.0%} of {period} {rate:g} Hz: a busy machine will make "
                "cycles late")
    return None


def _rate_for(transfer_s: float) -> float:
    """The highest whole-ten rate whose period `transfer_s` fits by REFUSE_SHARE."""
    return 10.0 * int(REFUSE_SHARE / transfer_s / 10.0)


def check_link_timing(buses: dict, period_s: float, rounds: int = ROUNDS) -> str | None:
    """On servos that keep real time: measure the cycle's reads (`measure_cycle_transfer`) and judge
    them (`verdict`): None, a warning sentence, or LinkTooSlow. None for a lockstep simulation."""
    if not servos_keep_real_time(buses):
        return None
    return verdict(measure_cycle_transfer(buses, rounds, period_s=period_s), period_s)
