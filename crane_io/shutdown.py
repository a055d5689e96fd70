"""Turning SIGTERM (and SIGHUP) into an exception, so `with DynamixelBus(...)` blocks still close.

Python's default SIGTERM action kills the process at once: no `finally`, no `__exit__`, so the servos
keep their last goal current with torque on (the Bus Watchdog, if armed, is the only thing that stops
them). Inside `handle_termination()` the signal raises `Terminated` (a KeyboardInterrupt) in the main
thread instead, which unwinds the stack like Ctrl+C does: every bus zeroes its goal current and turns
torque off on the way out.

    with handle_termination(), DynamixelBus(port) as bus:
        run_loop(bus)
"""

from __future__ import annotations

import contextlib
import signal
import threading


class Terminated(KeyboardInterrupt):
    """Raised in the main thread when the process receives SIGTERM or SIGHUP."""

    def __init__(self, signum: int):
        super().__init__(f"received {signal.Signals(signum).name}")
        self.signum = signum


def _default_signals() -> tuple[int, ...]:
    sigs = [signal.SIGTERM]
    if hasattr(signal, "SIGHUP"):
        sigs.append(signal.SIGHUP)
    return tuple(sigs)


@contextlib.contextmanager
def handle_termination(signals=None):
    """While active, the given signals (default SIGTERM and SIGHUP) raise `Terminated` in the main
    thread; the previous handlers come back on exit. Outside the main thread it does nothing, since
    Python only delivers signals there."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    signals = _default_signals() if signals is None else tuple(signals)
    fired: list[int] = []

    def _raise(signum, frame):
        if fired:  # a second signal while unwinding: do not interrupt the clean-up
            return
        fired.append(signum)
        raise Terminated(signum)

    previous = {}
    try:
        for sig in signals:
            previous[sig] = signal.signal(sig, _raise)
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
