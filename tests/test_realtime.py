"""collect/realtime.py: each request granted or refused with one sentence, never raising; restore()
gives back the previous scheduling policy, affinity, memory and garbage collector. No test here
busy-waits, with or without SCHED_FIFO."""

import gc
import os
import resource

import pytest

from collect import realtime
from collect.config import RealtimeConfig, load_config
from crane_io.errors import ConfigError


def _snapshot():
    return (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority, os.sched_getaffinity(0),
            gc.isenabled(), gc.get_freeze_count())


def test_enter_and_restore_gives_everything_back():
    before = _snapshot()
    state = realtime.enter_realtime(RealtimeConfig(priority=10))
    try:
        assert state.grants and all(isinstance(g, realtime.Grant) for g in state.grants)
        assert not gc.isenabled() and gc.get_freeze_count() > 0
        if state.fifo:
            assert os.sched_getscheduler(0) == os.SCHED_FIFO
            assert len(os.sched_getaffinity(0)) == 1
        state.collect_garbage()
    finally:
        state.restore()
    assert _snapshot() == before
    state.restore()  # idempotent
    assert _snapshot() == before


def test_refused_fifo_says_how_to_grant_it_and_pins_nothing(monkeypatch):
    def refuse(*_):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    real_getrlimit = resource.getrlimit
    monkeypatch.setattr(resource, "getrlimit",
                        lambda which: (0, 0) if which == resource.RLIMIT_RTPRIO else real_getrlimit(which))
    before = os.sched_getaffinity(0)
    state = realtime.enter_realtime(RealtimeConfig(lock_memory=False, freeze_gc=False))
    assert not state.fifo and state.cpu is None
    assert os.sched_getaffinity(0) == before  # a normal-priority loop is not pinned
    (grant,) = state.grants
    assert not grant.granted
    assert "rtprio" in grant.why_not and "limits.conf" in grant.why_not
    assert "no SCHED_FIFO 40" in state.sentence() and state.short() == "no RT"
    assert "SCHED_FIFO 40" in state.attrs()["realtime_refused"]
    state.restore()


def test_a_finite_memlock_limit_is_refused_up_front(monkeypatch):
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    real_getrlimit = resource.getrlimit
    monkeypatch.setattr(resource, "getrlimit", lambda which: (
        (8 << 20, 8 << 20) if which == resource.RLIMIT_MEMLOCK else real_getrlimit(which)))
    grant = realtime.request_memory_lock()
    assert not grant.granted
    assert "8192 KiB" in grant.why_not and "memlock unlimited" in grant.why_not


def test_pinning_to_a_core_the_process_may_not_use_is_refused():
    before = os.sched_getaffinity(0)
    grant, previous = realtime.request_pin(max(before) + 64)
    assert not grant.granted and previous is None and "realtime.cpu" in grant.why_not
    assert os.sched_getaffinity(0) == before


def test_nothing_requested():
    state = realtime.enter_realtime(RealtimeConfig(scheduling="off", lock_memory=False, freeze_gc=False))
    assert state.grants == [] and "nothing requested" in state.sentence()
    state.restore()


def test_realtime_configuration(tmp_path):
    c = load_config().realtime
    assert (c.scheduling, c.priority, c.pin, c.cpu, c.lock_memory, c.freeze_gc) == ("fifo", 40, True, -1,
                                                                                    True, True)
    p = tmp_path / "c.toml"
    p.write_text('[realtime]\nscheduling = "off"\npriority = 70\ncpu = 0\n')
    c = load_config(p).realtime
    assert (c.scheduling, c.priority, c.cpu) == ("off", 70, 0)
    for text, key in (('scheduling = "rr"', "realtime.scheduling"), ("priority = 0", "realtime.priority"),
                      ("cpu = -2", "realtime.cpu")):
        p.write_text(f"[realtime]\n{text}\n")
        with pytest.raises(ConfigError, match=key):
            load_config(p)
