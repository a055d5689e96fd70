"""Stop requests (Ctrl+C, SIGTERM, SIGHUP) that are never lost, and clean-ups they cannot cut short.

Python's default SIGTERM action kills the process at once: no `finally`, no `__exit__`, so the servos
keep their last goal current with torque on (the Bus Watchdog, if armed, is the only thing that stops
them). And an exception raised by a signal handler while Python runs a weakref or garbage-collection
callback is printed and thrown away ("Exception ignored in ..."): a handler that only raises can lose
a stop request. Here every signal is first *recorded* in a `StopRequest` (the signal number, how many
arrived); raising is only a way to break out of blocking code, never the only carrier.

Inside `handle_termination()` the stop signals behave according to the phase the program declares:

- by default (start-up, plain scripts): the signal raises `Terminated` (a KeyboardInterrupt) in the main
  thread, which unwinds the stack like Ctrl+C does; if that exception is swallowed, the request stays
  recorded, `check()` raises it again at the next checkpoint, and any further signal raises again;
- inside `deferred()` (a control loop that checks every cycle): the first signal is only recorded, the
  loop sees `requested` and ends cleanly between two cycles; a further signal raises (the loop may be
  stuck);
- inside `stopping()` (the safe stop and the file close): signals are recorded, never raised, and each
  one prints `notice` ("a stop is in progress ...") so the person knows why nothing else happens.

    with handle_termination() as stop, DynamixelBus(port) as bus:   # bus.close() runs in stopping()
        with stop.deferred():
            while not stop.requested:
                run_one_cycle(bus)
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading

DEFAULT_NOTICE = "a stop is in progress (goal current 0, torque off, files closed); please wait"


class Terminated(KeyboardInterrupt):
    """Raised in the main thread for a stop signal (SIGINT, SIGTERM, SIGHUP) inside
    `handle_termination()`; `signum` says which."""

    def __init__(self, signum: int):
        super().__init__(f"received {signal.Signals(signum).name}")
        self.signum = signum


def _default_signals() -> tuple[int, ...]:
    sigs = [signal.SIGTERM]
    if hasattr(signal, "SIGHUP"):
        sigs.append(signal.SIGHUP)
    return tuple(sigs)


_RAISE, _DEFER, _STOPPING = "raise", "defer", "stopping"


class StopRequest:
    """What the stop signals said so far, and how the next one is taken (see the module docstring)."""

    def __init__(self, notice: str | None = DEFAULT_NOTICE):
        self.signum: int | None = None  # the first stop signal received
        self.count = 0  # stop signals received in all
        self.notice = notice
        self._phases: list[str] = []

    @property
    def requested(self) -> bool:
        """A stop signal arrived."""
        return self.signum is not None

    @property
    def in_stop(self) -> bool:
        """Inside `stopping()`."""
        return _STOPPING in self._phases

    def check(self) -> None:
        """A checkpoint: raises Terminated if a stop was requested (outside `stopping()`)."""
        if self.signum is not None and not self.in_stop:
            raise Terminated(self.signum)

    def request(self, signum: int) -> None:
        """Record a stop as if `signum` had arrived (never raises)."""
        self.count += 1
        if self.signum is None:
            self.signum = signum

    @contextlib.contextmanager
    def _phase(self, phase: str):
        self._phases.append(phase)
        try:
            yield self
        finally:
            self._phases.pop()

    def deferred(self):
        """A loop that checks `requested` every cycle: the first signal is only recorded."""
        return self._phase(_DEFER)

    def stopping(self):
        """The clean-up: no signal raises inside; each prints the notice."""
        return self._phase(_STOPPING)

    def begin_stop(self) -> None:
        """Enter the stop for good: from now on no signal raises (each prints the notice). Idempotent;
        for a clean-up that must run to its end and is not left before `handle_termination()` ends."""
        if not self.in_stop:
            self._phases.append(_STOPPING)

    def _on_signal(self, signum, frame) -> None:
        first = self.signum is None
        self.request(signum)
        phase = self._phases[-1] if self._phases else _RAISE
        if _STOPPING in self._phases:
            if self.notice:
                _write_stderr(self.notice)
            return
        if phase == _DEFER and first:
            return
        raise Terminated(self.signum if first else signum)


def _write_stderr(text: str) -> None:
    # os.write, not print: a signal handler may run while the main thread is inside print() itself
    try:
        os.write(2, ("\n" + text + "\n").encode())
    except OSError:
        pass


_active: list[StopRequest] = []


def current() -> StopRequest | None:
    """The StopRequest of the innermost active `handle_termination()`, if any."""
    return _active[-1] if _active else None


@contextlib.contextmanager
def stopping():
    """`current().stopping()` if a handle_termination() is active, else nothing: for library clean-ups
    (DynamixelBus.close) that must not be cut short by a stop signal."""
    req = current()
    if req is None:
        yield None
        return
    with req.stopping():
        yield req


@contextlib.contextmanager
def handle_termination(signals=None, *, notice: str | None = DEFAULT_NOTICE):
    """While active, the given signals (default SIGTERM and SIGHUP; pass SIGINT too to take Ctrl+C the
    same way) are recorded in the yielded StopRequest and taken as the current phase says; the previous
    handlers come back on exit. Outside the main thread it yields a StopRequest no signal reaches,
    since Python only delivers signals there."""
    req = StopRequest(notice)
    if threading.current_thread() is not threading.main_thread():
        yield req
        return
    signals = _default_signals() if signals is None else tuple(signals)
    previous = {}
    _active.append(req)
    try:
        for sig in signals:
            previous[sig] = signal.signal(sig, req._on_signal)
        yield req
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        _active.remove(req)
