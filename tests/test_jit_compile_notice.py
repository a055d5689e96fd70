"""crane_io.jit.compile_notice: a compilation (a signature that missed numba's cache) still busy after a
while is announced once; a quick one, a slow load from the cache (a busy machine) and one outside the
notice are not."""

import collections
import threading
import types

from crane_io import jit


class _Dispatcher:
    """What the notice reads of a numba dispatcher: its cache statistics."""

    def __init__(self):
        self.misses = collections.Counter()

    @property
    def stats(self):
        return types.SimpleNamespace(cache_misses=self.misses)


def _busy(seconds: float, compiles: bool) -> None:
    """What compile_functions does around its compilations, for `seconds`: numba compiling (a cache miss)
    or loading from its cache."""
    d = _Dispatcher()
    done = jit._notice_watch([d])
    if compiles:
        d.misses["(float64,)"] += 1
    threading.Event().wait(seconds)
    if done is not None:
        done.set()


def test_a_slow_compile_is_announced_once():
    said = []
    with jit.compile_notice(lambda: said.append("compiling"), after_s=0.01):
        _busy(0.4, compiles=True)
        _busy(0.4, compiles=True)  # a second slow module: nothing more is said
    assert said == ["compiling"]


def test_a_slow_load_from_the_cache_on_a_busy_machine_says_nothing():
    said = []
    with jit.compile_notice(lambda: said.append("compiling"), after_s=0.01):
        _busy(0.4, compiles=False)
    threading.Event().wait(0.2)
    assert said == []


def test_a_quick_compile_says_nothing():
    said = []
    with jit.compile_notice(lambda: said.append("compiling"), after_s=5.0):
        _busy(0.0, compiles=True)
    threading.Event().wait(0.05)
    assert said == []


def test_outside_a_notice_nothing_watches():
    with jit.compile_notice(lambda: None):
        pass
    assert jit._notice_watch([_Dispatcher()]) is None
