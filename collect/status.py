"""What `crane-collect run` prints while it runs (stderr by default): a few plain lines, the live
status line and the summary at the end.

On a terminal the status line is rewritten in place `loop.status_hz` times a second; into a pipe or a
log file it is printed as a line of its own at most once per `loop.status_log_s` of wall time.
"""

from __future__ import annotations

import time

import numpy as np

from .config import LoopConfig


def is_terminal(out) -> bool:
    return hasattr(out, "isatty") and out.isatty()


class StatusLine:
    def __init__(self, out, loop: LoopConfig, enabled: bool = True):
        self.out = out
        self.enabled = enabled and out is not None
        self.tty = is_terminal(out)
        every = 1.0 / loop.status_hz if (loop.status_hz > 0 and enabled) else None
        if every is not None and not self.tty:  # a pipe or a log file: do not flood it
            every = max(every, loop.status_log_s)
        self.every = every
        self.wall0 = time.perf_counter()
        self.next = self.wall0

    def say(self, text: str) -> None:
        """One line of its own (nothing with --quiet)."""
        if self.enabled:
            print(text, file=self.out, flush=True)

    def start(self) -> None:
        """The loop starts now: the first status line is due one interval from now."""
        self.wall0 = time.perf_counter()
        self.next = self.wall0 + (self.every or 0.0)

    def due(self) -> float | None:
        """Wall seconds since start() when a status line is due now (the next one then waits one
        interval), else None."""
        if self.every is None:
            return None
        now = time.perf_counter()
        if now < self.next:
            return None
        self.next = now + self.every
        return now - self.wall0

    def show(self, t_session: float, wall: float, timer, tracking_rms_deg, errors: int,
             lockstep: bool, realtime: str = "", models: str = "", joints=None) -> None:
        """`tracking_rms_deg` per bilateral joint; `joints` their names, shown short ("1 0.35 2 0.50 ...",
        "g" for the gripper) so that a line of seven numbers says which is which."""
        r = timer.recent()
        speed = f" x{t_session / wall:.1f} real time" if lockstep and wall > 0 else ""
        if joints is None:
            track = " ".join(f"{x:.2f}" for x in tracking_rms_deg)
        else:
            track = " ".join(f"{_short(n)} {x:.2f}" for n, x in zip(joints, tracking_rms_deg))
        text = (f"{t_session:7.1f} s | {r['rate_hz']:6.0f} Hz{speed} | jitter {r['jitter_s'] * 1e3:.3f} ms | "
                f"max {r['max_s'] * 1e3:.2f} ms | overruns {timer.overruns} | errors {errors} | "
                f"track rms {track} deg")
        if realtime:  # what the OS granted the loop, e.g. "FIFO 40" or "no RT"
            text += f" | {realtime}"
        if models:  # the observers' models, e.g. "model L nominal F rigid-body 3j (fallback 0)"
            text += f" | {models}"
        print(("\r" + text) if self.tty else text, end="" if self.tty else "\n", file=self.out, flush=True)


def _short(joint: str) -> str:
    """A joint's short name on the status line: joint4 -> j4, gripper -> g."""
    return f"j{joint[5:]}" if joint.startswith("joint") else joint[:1]


# How the summary's first line says why the run ended (RunResult.end_reason).
_END_WORDS = {"duration": "ended after the requested duration", "interrupted": "stopped by Ctrl+C",
              "terminated": "stopped by SIGTERM", "safety_stop": "safety stop",
              "error": "stopped by an error"}


def print_summary(r, bus_errors: int, out, lockstep: bool = False, realtime: str | None = None,
                  extra: list[str] | None = None) -> None:
    """The summary of a finished run (r: RunResult). In lockstep the loop's own rate is the nominal one
    (one period of simulated time per cycle); the wall-clock rate is how fast the machine simulated."""
    s = r.summary
    ended = _END_WORDS.get(r.end_reason, r.end_reason.replace("_", " "))
    lines = [("\n" if is_terminal(out) else "") + f"session {r.path}: {ended}; {r.cycles} cycles, "
             f"{r.duration_s:.1f} s recorded in {r.wall_s:.1f} s wall"]
    if s.get("period_mean_s"):
        if lockstep:
            nominal = 1.0 / s["nominal_period_s"]
            rate = (f"lockstep, {nominal:.0f} Hz of simulated time at "
                    f"x{s['rate_hz'] / nominal:.1f} real time "
                    f"({s['rate_hz']:.0f} cycles per wall second); wall ")
        else:
            rate = f"{s['rate_hz']:.0f} Hz achieved, "
        lines.append(f"  loop: {rate}"
                     f"period mean {s['period_mean_s'] * 1e3:.3f} ms, "
                     f"std {s['period_std_s'] * 1e3:.3f} ms, p99 {s['period_p99_s'] * 1e3:.3f} ms, "
                     f"max {s['period_max_s'] * 1e3:.3f} ms, overruns {int(s['overruns'])}")
        lines.append(f"  bus: leader {s.get('bus_leader_mean_s', 0) * 1e3:.3f} ms, follower "
                     f"{s.get('bus_follower_mean_s', 0) * 1e3:.3f} ms per cycle; compute "
                     f"{s.get('compute_mean_s', 0) * 1e6:.0f} us, "
                     f"record {s.get('record_mean_s', 0) * 1e6:.0f} us; bus errors {bus_errors}")
    if realtime:
        lines.append(f"  {realtime}")
    if r.tracking_rms:
        lines.append("  tracking rms (leader - follower): " + ", ".join(
            f"{n} {np.degrees(v):.2f} deg" for n, v in r.tracking_rms.items()))
    lines.extend(f"  {line}" for line in extra or ())
    if r.breach is not None:
        lines.append(f"  SAFETY STOP: {r.breach.message}")
    print("\n".join(lines), file=out, flush=True)
