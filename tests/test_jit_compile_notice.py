"""crane_io.jit.compile_notice: a compilation still busy after a while is announced once; a quick one (a
load from numba's cache) and one outside the notice are not."""

import threading

from crane_io import jit


def _busy_compile(seconds: float) -> None:
    """What compile_functions does around its compilations: the notice's timer, running for `seconds`."""
    timer = jit._notice_timer()
    threading.Event().wait(seconds)
    if timer is not None:
        timer.cancel()


def test_a_slow_compile_is_announced_once():
    said = []
    with jit.compile_notice(lambda: said.append("compiling"), after_s=0.01):
        _busy_compile(0.3)
        _busy_compile(0.3)  # a second slow module: nothing more is said
    assert said == ["compiling"]


def test_a_quick_load_from_the_cache_says_nothing():
    said = []
    with jit.compile_notice(lambda: said.append("compiling"), after_s=5.0):
        _busy_compile(0.0)
    threading.Event().wait(0.05)
    assert said == []


def test_outside_a_notice_no_timer_runs():
    with jit.compile_notice(lambda: None):
        pass
    assert jit._notice_timer() is None
