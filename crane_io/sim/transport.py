"""Transports that put a SimulatedChain on a serial line the unchanged dynamixel-sdk client can use.

1. In-process: a pyserial URL handler. After `register_chain("arm", chain)`,
   `serial.serial_for_url("dxlsim://arm", baudrate=3_000_000, timeout=0)` is a port whose writes
   go to the chain and whose reads return its replies (`in_waiting`, `read`, `reset_input_buffer`
   behave like a real port). Importing this module registers the handler package with pyserial.
2. A pseudo-terminal: `PtyServer(chain, link="/tmp/crane_x7")` opens a pty pair, links the slave
   side at `link` and serves the chain from a thread until `stop()` (or the `with` block ends).
   Any program that opens a serial port (Dynamixel Wizard, the SDK, `screen`) can use the link.
   On the wall clock the server's one thread both answers the line and keeps the plant up to real
   time, in slices of at most the chain's `step_budget_s` with a look at the line between them, so
   an instruction never waits for more than one slice of physics (see SimulatedChain.touch).
   With `adapter=AdapterTiming(...)` the replies of a wall-clock chain reach the line when a U2D2 would
   hand them to the host: after the bytes' time on the RS-485 line, the servos' Return Delay Times and
   the adapter's USB packets and latency timer (crane_io.sim.adapter_timing); meanwhile the thread
   keeps the plant up to real time. The lockstep clock is never delayed.
"""

from __future__ import annotations

import errno
import os
import select
import threading
import time
import tty
from collections import deque
from pathlib import Path

import serial

from crane_io.errors import ConfigError, HardwareError
from crane_io.sim.adapter_timing import AdapterLink, AdapterTiming, status_packets
from crane_io.sim.chain import SimulatedChain

URL_SCHEME = "dxlsim"
DEFAULT_BAUDRATE = 3_000_000  # the line's speed when no servo is left to tell it
# With an adapter's timing, replies are due at set times; a process serving several links (sim-serve
# --pair) sets the interpreter's thread switch interval to this (its default is 5 ms), so a server thread
# waits at most about this long for another one's physics to hand over.
ADAPTER_SWITCH_INTERVAL_S = 0.0002
_HANDLER_PACKAGE = "crane_io.sim"

if _HANDLER_PACKAGE not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append(_HANDLER_PACKAGE)

_chains: dict[str, SimulatedChain] = {}
_registry_lock = threading.Lock()


def url_for(name: str) -> str:
    return f"{URL_SCHEME}://{name}"


def register_chain(name: str, chain: SimulatedChain) -> str:
    """Make `chain` reachable as dxlsim://NAME; returns the URL."""
    if not name or "/" in name or "?" in name:
        raise HardwareError(f"simulated chain name {name!r} must be a non-empty word without '/' or '?'")
    with _registry_lock:
        if name in _chains and _chains[name] is not chain:
            raise HardwareError(f"a simulated chain named {name!r} is already registered")
        _chains[name] = chain
    return url_for(name)


def unregister_chain(name: str) -> None:
    with _registry_lock:
        _chains.pop(name, None)


def lookup_chain(name: str) -> SimulatedChain | None:
    with _registry_lock:
        return _chains.get(name)


def registered_names() -> list[str]:
    with _registry_lock:
        return sorted(_chains)


class PtyServer:
    """Serve a SimulatedChain on a pseudo-terminal whose slave side is symlinked at `link`."""

    def __init__(self, chain: SimulatedChain, link: str | os.PathLike, idle_touch_s: float = 0.005,
                 adapter: AdapterTiming | None = None):
        self.chain = chain
        self.link = Path(link)
        self.idle_touch_s = idle_touch_s
        self.adapter = adapter  # None: replies go on the line as soon as the chain gives them
        self._adapter_link: AdapterLink | None = None
        self._pending: deque = deque()  # (time.monotonic() due, bytes): replies the adapter still holds
        self._master = self._slave = None
        self._wake_r = self._wake_w = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.error: BaseException | None = None

    @property
    def slave_path(self) -> str:
        return os.ttyname(self._slave)

    def start(self) -> PtyServer:
        if self._thread is not None:
            return self
        if self.link.is_symlink():
            target = os.readlink(self.link)
            if not target.startswith("/dev/pts/"):  # only a stale link to a pty is ours to replace
                raise ConfigError(f"{self.link} already exists and links to {target}, not to a "
                                  "pseudo-terminal; choose another `link` path")
            self.link.unlink()
        elif self.link.exists():
            raise ConfigError(f"{self.link} already exists and is not a link; choose another `link` path")
        if not self.link.parent.is_dir():
            raise ConfigError(f"cannot create {self.link}: folder {self.link.parent} does not exist")
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no newline translation: the line carries binary packets
        os.set_blocking(self._master, False)
        self._wake_r, self._wake_w = os.pipe()
        try:
            os.symlink(os.ttyname(self._slave), self.link)
        except OSError as exc:
            self._close_fds()
            raise ConfigError(f"cannot create the link {self.link}: {exc.strerror}") from None
        self._stop.clear()
        self._pending.clear()
        if self.adapter is not None:
            self._adapter_link = AdapterLink(self.adapter, time.monotonic())
        self._thread = threading.Thread(target=self._serve, name=f"pty-server {self.link}", daemon=True)
        self._thread.start()
        return self

    def _serve(self) -> None:
        behind = False  # the plant is behind real time: look at the line, then keep stepping
        try:
            while not self._stop.is_set():
                ready, _, _ = select.select([self._master, self._wake_r], [], [], self._wait_s(behind))
                if self._pending:
                    self._deliver_due()
                if self._master in ready:
                    try:
                        data = os.read(self._master, 65536)
                    except OSError as exc:
                        if exc.errno in (errno.EAGAIN, errno.EIO):
                            continue
                        raise
                    if data:
                        self._answer(data)
                    behind = self.chain.lag_s >= self.chain.max_substep_s
                elif not self._delivery_near():
                    behind = self.chain.touch() >= self.chain.max_substep_s
        except BaseException as exc:  # reported through .error; the thread must not die silently
            self.error = exc

    def _wait_s(self, behind: bool) -> float:
        """How long to wait for the line: not at all when the plant is behind, else until the next touch
        or a held reply's time, whichever comes first; a reply due within a slice of physics is waited
        for rather than risk the slice delaying it."""
        wait = 0.0 if behind else self.idle_touch_s
        if self._pending:
            until_due = max(0.0, self._pending[0][0] - time.monotonic())
            wait = until_due if until_due < self.chain.step_budget_s else min(wait, until_due)
        return wait

    def _answer(self, data: bytes) -> None:
        """The chain's reply to `data`, on the line now or held as the adapter would hold it."""
        written = time.monotonic()
        reply = self.chain.feed(data)
        if self._adapter_link is not None and self.chain.clock == "wall":
            self._schedule(written, len(data), reply)
        elif reply:
            self._send(reply)

    def _servo_timing(self, servo_id: int) -> tuple[float, int]:
        """(Return Delay Time s, baud rate) of a servo on the chain, from its control table."""
        servos = self.chain.servos
        servo = servos.get(servo_id) or next(iter(servos.values()), None)
        if servo is None or not servo.baudrate:
            return 0.0, DEFAULT_BAUDRATE
        return servo.return_delay_s, servo.baudrate

    def _schedule(self, written: float, n_out: int, reply: bytes) -> None:
        """The adapter's deliveries of `reply` to an instruction of `n_out` bytes read at `written`."""
        replies = []
        for size, sid in status_packets(reply):
            delay_s, baudrate = self._servo_timing(sid)
            replies.append((size, delay_s, baudrate))
        baudrate = self._servo_timing(-1)[1]
        at = 0
        for due, size in self._adapter_link.exchange(written, n_out, baudrate, replies):
            self._pending.append((due, reply[at:at + size]))
            at += size

    def _delivery_near(self) -> bool:
        """A held reply is due within one slice of physics: stepping now could make it late."""
        return bool(self._pending) and self._pending[0][0] - time.monotonic() < self.chain.step_budget_s

    def _deliver_due(self) -> None:
        now = time.monotonic()
        while self._pending and self._pending[0][0] <= now:
            self._send(self._pending.popleft()[1])

    def _send(self, reply: bytes) -> None:
        """Put a reply on the line (a hook for test fakes that deliver replies late)."""
        self._write_all(reply)

    def _write_all(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                n = os.write(self._master, view)
            except BlockingIOError:
                select.select([], [self._master], [], 0.01)
                continue
            view = view[n:]

    def stop(self) -> None:
        if self._thread is None:
            return
        self._stop.set()
        os.write(self._wake_w, b"x")
        self._thread.join(timeout=5)
        self._thread = None
        try:
            if self.link.is_symlink():
                self.link.unlink()
        except OSError:
            pass
        self._close_fds()

    def _close_fds(self) -> None:
        for fd in (self._master, self._slave, self._wake_r, self._wake_w):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = self._wake_r = self._wake_w = None

    def __enter__(self) -> PtyServer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
