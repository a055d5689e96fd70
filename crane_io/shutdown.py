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

import _thread
import contextlib
import os
import signal
import sys
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
    # os.write, not print: a signal handler may run while the main thread is inside print() itself. On a
    # terminal the line starts on a line of its own (after the echoed ^C or a status line); in a pipe or a
    # log it is exactly one line.
    try:
        os.write(2, (("\n" if os.isatty(2) else "") + text + "\n").encode())
    except OSError:
        pass


_active: list[StopRequest] = []
_activity: list[str | None] = [None]


def set_activity(phrase: str | None) -> None:
    """Say what the program is doing now ("compiling the control kernels"), for the line a command prints
    when a stop signal ends it there (`interrupted_line`); None: nothing worth naming."""
    _activity[0] = phrase


def current_activity() -> str | None:
    """The phrase of the latest `set_activity`."""
    return _activity[0]


def interrupt_until_main(prog: str, note: str | None = None) -> None:
    """For a command line's first lines, before its imports: a Ctrl+C ends the program at once with the
    line of `interrupted_line` ("starting up") and 130, not a traceback from inside an import. The
    command's group puts Python's own handler back when it starts (`restore_interrupt`). Only in the
    program `prog` itself (its entry script), never in a process that merely imports the command line."""
    def handler(signum, frame):
        set_activity(current_activity() or "starting up")
        _write_stderr(f"{prog}: {interrupted_line(KeyboardInterrupt(), note)[0]}")
        os._exit(128 + signum)

    if not is_program(prog):
        return
    if threading.current_thread() is threading.main_thread() and \
            signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, handler)


def is_program(prog: str) -> bool:
    """This process is the command `prog` itself (its entry script), not one that imported it (a test)."""
    return os.path.basename(sys.argv[0] if sys.argv else "") == prog


def restore_interrupt() -> None:
    """Ctrl+C raises KeyboardInterrupt again (Python's own handler), after `interrupt_until_main`."""
    if threading.current_thread() is threading.main_thread() and \
            getattr(signal.getsignal(signal.SIGINT), "__qualname__", "").startswith("interrupt_until_main"):
        signal.signal(signal.SIGINT, signal.default_int_handler)


def interrupted_line(exc: BaseException, note: str | None = None) -> tuple[str, int]:
    """(the one line that says what a stop signal interrupted, the exit status 128 + signal number) for a
    KeyboardInterrupt `exc` (Terminated says which signal; a plain KeyboardInterrupt is SIGINT):
    "interrupted while compiling the control kernels; no torque was on", 130."""
    signum = getattr(exc, "signum", None) or signal.SIGINT
    word = "interrupted" if signum == signal.SIGINT else f"stopped by {signal.Signals(signum).name}"
    doing = current_activity()
    line = word + (f" while {doing}" if doing else "") + (f"; {note}" if note else "")
    return line, 128 + int(signum)


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
    _previous_unraisable.append(sys.unraisablehook)
    sys.unraisablehook = _unraisable
    try:
        for sig in signals:
            previous[sig] = signal.signal(sig, req._on_signal)
        yield req
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        _active.remove(req)
        sys.unraisablehook = _previous_unraisable.pop()


# ---- a prompt end for a start-up stuck in C code ------------------------------------------------------
# Python runs a signal's handler only between two bytecodes of the main thread: inside a long C call (an
# LLVM compile of a numba kernel, a slow import) a Ctrl+C waits for that call to return, which on a busy
# machine can be seconds. While armed (a command's start-up, before any torque is on), a watcher thread
# woken by the signal itself (signal.set_wakeup_fd) ends the program `grace_s` after a stop signal that
# the main thread has not turned into its exit by then: the same one line, the same exit status.

_prompt: dict = {"armed": False, "prog": "", "note": None, "grace_s": 0.5, "fd": None, "previous": -1}
_prompt_lock = threading.Lock()


def _watch(read_fd: int) -> None:
    while True:
        try:
            data = os.read(read_fd, 64)
        except InterruptedError:
            continue
        except OSError:
            return
        stops = [b for b in data if b in _stop_numbers()]
        if not stops or not _prompt["armed"]:
            continue
        threading.Event().wait(_prompt["grace_s"])
        with _prompt_lock:
            if _prompt["armed"]:  # else the main thread took it (or torque went on meanwhile)
                _exit_now(stops[0])


def _exit_now(signum: int) -> None:
    """The armed prompt exit: the line and the exit status, at once."""
    exc = Terminated(signum) if signum != signal.SIGINT else KeyboardInterrupt()
    line, code = interrupted_line(exc, _prompt["note"])
    _write_stderr(f"{_prompt['prog']}: {line}")
    os._exit(code)


def _unraisable(args) -> None:
    """sys.unraisablehook inside handle_termination(): a stop signal's exception raised where Python can
    only print it and throw it away (a weakref or garbage-collection callback, a ctypes callback such as
    numba's compiler calls) is not printed, since the request stays recorded and is taken at the next
    checkpoint; with the prompt exit armed it ends the program right here. Anything else goes to the
    previous hook."""
    req = current()
    if isinstance(args.exc_value, KeyboardInterrupt) and req is not None and req.requested:
        if _prompt["armed"]:
            _exit_now(req.signum)
        return
    _previous_unraisable[-1](args)


_previous_unraisable: list = []


@contextlib.contextmanager
def resurface_lost_interrupts(delay_s: float = 0.02):
    """While active, a Ctrl+C whose KeyboardInterrupt was raised where Python can only print it and throw
    it away (a weakref callback of the import machinery, a garbage-collection callback) is not lost: it
    is delivered again to the main thread `delay_s` later (from a timer thread), by then back in ordinary
    code, where it ends the command as any Ctrl+C does. Nothing is printed for the lost one. A stop
    signal an active handle_termination() already recorded is left to it. Anything else goes to the
    previous hook. Main thread only (elsewhere nothing is installed)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = sys.unraisablehook

    def hook(args):
        if isinstance(args.exc_value, KeyboardInterrupt) and not isinstance(args.exc_value, Terminated):
            timer = threading.Timer(delay_s, _thread.interrupt_main)
            timer.daemon = True
            timer.start()
            return
        previous(args)

    sys.unraisablehook = hook
    try:
        yield
    finally:
        if sys.unraisablehook is hook:
            sys.unraisablehook = previous


def _stop_numbers() -> set[int]:
    return {int(getattr(signal, n)) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n)}


def arm_prompt_exit(prog: str, note: str | None = None, grace_s: float = 0.5) -> bool:
    """Until `disarm_prompt_exit()`, a stop signal not taken by the main thread within `grace_s` ends the
    program from a watcher thread (see above), printing "<prog>: interrupted while ...[; note]". For a
    command line's start-up only (nothing to clean up yet). False (nothing armed) outside the main thread,
    in a process that is not the program `prog` itself (a test invoking the command line), or where no
    wakeup descriptor can be set."""
    if threading.current_thread() is not threading.main_thread() or not is_program(prog):
        return False
    with _prompt_lock:
        if _prompt["fd"] is None:
            read_fd, write_fd = os.pipe()
            os.set_blocking(write_fd, False)
            _prompt["fd"] = write_fd
            threading.Thread(target=_watch, args=(read_fd,), name="stop-watcher", daemon=True).start()
        try:
            _prompt["previous"] = signal.set_wakeup_fd(_prompt["fd"], warn_on_full_buffer=False)
        except (ValueError, OSError):
            return False
        _prompt.update(armed=True, prog=prog, note=note, grace_s=grace_s)
    return True


def disarm_prompt_exit() -> None:
    """Stop signals are the main thread's alone again (torque is about to go on, or the command ends)."""
    with _prompt_lock:
        if not _prompt["armed"]:
            return
        _prompt["armed"] = False
        if threading.current_thread() is threading.main_thread():
            try:
                signal.set_wakeup_fd(_prompt["previous"])
            except (ValueError, OSError):
                pass
