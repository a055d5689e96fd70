"""Real-time scheduling for the paced control loop: ask, report what was granted, give it back.

    rt = enter_realtime(config.realtime)     # before the alignment (see docs/collect.md)
    say(rt.sentence())                        # "real-time: SCHED_FIFO 40, memory locked, ..."
    ...                                       # the loop; rt.collect_garbage() between cycles
    rt.restore()                              # in the clean-up; idempotent

Four requests, each of which may be refused without permission; none raises:
- SCHED_FIFO at `priority` for the calling thread (`os.sched_setscheduler`; threads started later,
  such as the bus threads, inherit it). Needs RLIMIT_RTPRIO >= priority (limits.conf `rtprio`) or
  CAP_SYS_NICE.
- all memory locked (`mlockall(MCL_CURRENT | MCL_FUTURE)`), so no page fault stalls a cycle. Needs
  an unlimited RLIMIT_MEMLOCK (limits.conf `memlock unlimited`) or CAP_IPC_LOCK: with a finite
  limit every later allocation past it would fail, so a finite limit is refused up front.
- the thread pinned to one core (`os.sched_setaffinity`), only when SCHED_FIFO was granted: a
  normal-priority loop pinned to one core would wait for whatever else runs there.
- the garbage collector kept out of the cycle: every object alive at the start is frozen out of
  collection (`gc.freeze`), automatic collection is off, and the loop calls `collect_garbage()`
  (a generation-0 collection, tens of microseconds) at a point outside its timed section.

Each request gives a `Grant` (granted, one sentence why not); `restore()` undoes what was granted:
previous policy and priority, affinity, memory unlocked, collector as it was.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import os
import resource
from dataclasses import dataclass, field

from crane_io import session_format as sf

from .config import RealtimeConfig

MCL_CURRENT = 1
MCL_FUTURE = 2
LIMITS_HINT = "/etc/security/limits.conf"


@dataclass(frozen=True)
class Grant:
    """One request's outcome: what was asked, whether it was granted, one sentence if not."""

    what: str  # e.g. "SCHED_FIFO 40", "memory locked", "pinned to CPU 1", "gc frozen"
    granted: bool
    why_not: str = ""  # one sentence naming the missing permission and how to grant it

    def __str__(self) -> str:
        return self.what if self.granted else f"no {self.what} ({self.why_not})"


def _errno_name(exc: OSError) -> str:
    return os.strerror(exc.errno) if exc.errno else str(exc)


def _limit_text(value: int) -> str:
    return "unlimited" if value == resource.RLIM_INFINITY else str(value)


# ---- the four requests --------------------------------------------------------------------------------

def request_fifo(priority: int) -> tuple[Grant, tuple[int, int] | None]:
    """SCHED_FIFO at `priority` for this thread: (grant, previous (policy, priority) to restore)."""
    what = f"SCHED_FIFO {priority}"
    if not hasattr(os, "sched_setscheduler"):
        return Grant(what, False, "this system has no POSIX real-time scheduling"), None
    try:
        previous = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError:
        soft, _hard = resource.getrlimit(resource.RLIMIT_RTPRIO)
        if soft != resource.RLIM_INFINITY and soft < priority:
            why = (f"no rtprio permission: RLIMIT_RTPRIO is {_limit_text(soft)}; add "
                   f"'@realtime - rtprio 90' to {LIMITS_HINT}, put the user in group realtime and "
                   "log in again, or give the interpreter cap_sys_nice")
        else:
            why = ("refused although RLIMIT_RTPRIO allows it: a container without CAP_SYS_NICE or a "
                   "cgroup without a real-time budget (cpu.rt_runtime_us)")
        return Grant(what, False, why), None
    except OSError as exc:
        return Grant(what, False, f"sched_setscheduler failed: {_errno_name(exc)}"), None
    return Grant(what, True), previous


def _libc():
    name = ctypes.util.find_library("c")
    return ctypes.CDLL(name, use_errno=True) if name else None


def request_memory_lock() -> Grant:
    """mlockall(MCL_CURRENT | MCL_FUTURE), refused up front when a finite limit would later make
    allocations fail."""
    what = "memory locked"
    libc = _libc()
    if libc is None or not hasattr(libc, "mlockall"):
        return Grant(what, False, "this system's C library has no mlockall")
    soft, _hard = resource.getrlimit(resource.RLIMIT_MEMLOCK)
    if soft != resource.RLIM_INFINITY and os.geteuid() != 0:
        return Grant(what, False, f"RLIMIT_MEMLOCK is {soft // 1024} KiB, not unlimited: add "
                                  f"'@realtime - memlock unlimited' to {LIMITS_HINT} and log in again")
    if libc.mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
        err = ctypes.get_errno()
        return Grant(what, False, f"mlockall failed: {os.strerror(err)} (a container without "
                                  "CAP_IPC_LOCK, or not enough free memory)")
    return Grant(what, True)


def unlock_memory() -> None:
    libc = _libc()
    if libc is not None and hasattr(libc, "munlockall"):
        libc.munlockall()


def request_pin(cpu: int) -> tuple[Grant, set[int] | None]:
    """This thread on one core (`cpu`, -1: the last core it may use): (grant, previous affinity)."""
    if not hasattr(os, "sched_setaffinity"):
        return Grant("pinned to a core", False, "this system cannot pin threads to cores"), None
    allowed = sorted(os.sched_getaffinity(0))
    target = allowed[-1] if cpu < 0 else cpu
    what = f"pinned to CPU {target}"
    if target not in allowed:
        return Grant(what, False, f"CPU {target} is not one this process may use "
                                  f"({', '.join(map(str, allowed))}); set realtime.cpu"), None
    try:
        os.sched_setaffinity(0, {target})
    except OSError as exc:
        return Grant(what, False, f"sched_setaffinity failed: {_errno_name(exc)}"), None
    return Grant(what, True), set(allowed)


# ---- the whole ----------------------------------------------------------------------------------------

@dataclass
class RealtimeState:
    """What `enter_realtime` obtained; `restore()` gives it back (idempotent)."""

    config: RealtimeConfig
    grants: list[Grant] = field(default_factory=list)
    _previous_sched: tuple[int, int] | None = None
    _previous_affinity: set[int] | None = None
    _memory_locked: bool = False
    _gc_was_enabled: bool | None = None
    restored: bool = False

    # -- queries ------------------------------------------------------------------------------------
    @property
    def fifo(self) -> bool:
        return self._previous_sched is not None

    @property
    def memory_locked(self) -> bool:
        return self._memory_locked

    @property
    def cpu(self) -> int | None:
        if self._previous_affinity is None:
            return None
        return next(iter(os.sched_getaffinity(0)), None)

    @property
    def gc_frozen(self) -> bool:
        return self._gc_was_enabled is not None

    def refusals(self) -> list[Grant]:
        return [g for g in self.grants if not g.granted]

    def sentence(self) -> str:
        """One line for the user, e.g. "real-time: SCHED_FIFO 40, memory locked, pinned to CPU 1, gc
        frozen", or with one sentence for each request that was refused."""
        if not self.grants:
            return "real-time: nothing requested ([realtime] in the configuration)"
        got = [g.what for g in self.grants if g.granted]
        text = "real-time: " + (", ".join(got) if got else "nothing granted")
        refused = self.refusals()
        if refused:
            text += "; " + "; ".join(f"no {g.what}: {g.why_not}" for g in refused)
        return text

    def short(self) -> str:
        """A few characters for the live status line: "FIFO 40", "FIFO 40 unlocked", "no RT"."""
        if not self.fifo:
            return "no RT"
        return f"FIFO {self.config.priority}" + ("" if self._memory_locked else " unlocked")

    def attrs(self) -> dict:
        """Session attributes (for the `timing` group): what was asked and what was granted."""
        return {
            sf.REALTIME_SCHEDULING_ATTR: self.config.scheduling,  # requested: "fifo" or "off"
            sf.REALTIME_PRIORITY_ATTR: int(self.config.priority),  # requested SCHED_FIFO priority
            sf.REALTIME_FIFO_ATTR: self.fifo,  # granted
            sf.REALTIME_MEMORY_LOCKED_ATTR: self._memory_locked,
            sf.REALTIME_CPU_ATTR: -1 if self.cpu is None else int(self.cpu),  # -1: not pinned
            sf.REALTIME_GC_FROZEN_ATTR: self.gc_frozen,
            sf.REALTIME_REFUSED_ATTR: "; ".join(f"{g.what}: {g.why_not}" for g in self.refusals()),
        }

    # -- between cycles -----------------------------------------------------------------------------
    def collect_garbage(self) -> None:
        """A generation-0 collection, when automatic collection is off; call it outside the timed
        part of a cycle (after the writes, before the wait)."""
        if self._gc_was_enabled is not None:
            gc.collect(0)

    # -- giving it back -----------------------------------------------------------------------------
    def restore(self) -> None:
        """Previous scheduling policy, affinity, unlocked memory, the collector as it was. Must run in
        the thread that called enter_realtime(); never raises."""
        if self.restored:
            return
        self.restored = True
        if self._previous_sched is not None:
            policy, priority = self._previous_sched
            try:
                os.sched_setscheduler(0, policy, os.sched_param(priority))
            except OSError:
                pass
        if self._previous_affinity is not None:
            try:
                os.sched_setaffinity(0, self._previous_affinity)
            except OSError:
                pass
        if self._memory_locked:
            unlock_memory()
        if self._gc_was_enabled is not None:
            gc.unfreeze()
            if self._gc_was_enabled:
                gc.enable()

    def __enter__(self) -> RealtimeState:
        return self

    def __exit__(self, *exc) -> None:
        self.restore()


def enter_realtime(config: RealtimeConfig) -> RealtimeState:
    """Ask for what `config` says (see the module docstring); never raises."""
    state = RealtimeState(config)
    if config.scheduling == "fifo":
        grant, state._previous_sched = request_fifo(config.priority)
        state.grants.append(grant)
    if config.lock_memory:
        grant = request_memory_lock()
        state._memory_locked = grant.granted
        state.grants.append(grant)
    if config.pin and state.fifo:
        grant, state._previous_affinity = request_pin(config.cpu)
        state.grants.append(grant)
    if config.freeze_gc:
        state._gc_was_enabled = gc.isenabled()
        gc.collect()
        gc.freeze()
        gc.disable()
        state.grants.append(Grant("gc frozen", True))
    return state
