"""Compiling the project's numba kernels (the simulator's plant, chain, lockstep and noise kernels, the bus's
cycle kernel, the controller's and the loop's), one rule for all.

`compile_functions(namespace, names, signatures)` compiles the named plain-Python functions of a module
with `njit(cache=True)` (no `fastmath`: the same IEEE operations as the Python source), so that they call
each other compiled, and compiles the `signatures` given (name -> argument types, numba's string form)
at once: loaded from numba's cache or compiled right then, in the thread that builds the simulator (or
switches a bus's torque on). A kernel compiled lazily instead would be compiled at its first call,
which for a simulator serving a pseudo-terminal is while a host waits for a reply: on a fresh checkout
that is several seconds, and the host rightly declares the servos silent.
Returns None when numba is not installed.

numba keeps the machine code in `__pycache__` next to each kernel module (in `NUMBA_CACHE_DIR` when set; a
module whose source changed is compiled again). Loading from the cache takes a fraction of a second per
module; compiling them all (after an install, or after a kernel's source changed) takes about
`COMPILE_ESTIMATE_S` on a 2-core machine. `scripts/setup.sh` compiles them once (`python -m collect.kernels`);
a command that may compile says so while it does, with `compile_notice`.
"""

from __future__ import annotations

import contextlib
import threading
import types

COMPILE_ESTIMATE_S = 30  # every kernel of a simulated run from an empty cache: 27 s on 2 cores at load 2
_notice: list = []  # [callback, seconds]: the compile_notice in effect (at most one, per process)


def compile_functions(namespace: dict, names: tuple[str, ...], signatures: dict[str, tuple[str, ...]],
                      qualname_prefix: str = "", **options) -> dict | None:
    """name -> compiled function for `names` (see the module docstring); None without numba.
    `qualname_prefix`: put before every function's name in its qualified name, which names its entry in
    numba's cache (a module that compiles another module's functions with other options, or calls them
    under other names, keeps its own entries)."""
    try:
        import numba
    except ImportError:
        return None
    jit = numba.njit(cache=True, **options)
    ns = dict(namespace)  # the compiled functions call each other; the module keeps the Python ones
    for name in names:
        f = ns[name]
        g = types.FunctionType(f.__code__, ns, name, f.__defaults__)
        g.__qualname__ = qualname_prefix + name if qualname_prefix else f.__qualname__
        ns[name] = jit(g)
    timer = _notice_timer()
    try:
        for name, sigs in signatures.items():
            for sig in sigs:
                ns[name].compile(sig)
    finally:
        if timer is not None:
            timer.cancel()
    return {name: ns[name] for name in names}


@contextlib.contextmanager
def compile_notice(callback, after_s: float = 1.0):
    """While inside: once a `compile_functions` call is still busy after `after_s` (numba compiling, not
    loading from its cache), `callback()` is called, once, from a timer thread (a command says there
    what it is doing, e.g. "compiling the simulator's kernels once, about 30 s")."""
    _notice[:] = [callback, float(after_s)]
    try:
        yield
    finally:
        _notice.clear()


def _notice_timer() -> threading.Timer | None:
    if not _notice:
        return None
    callback, after_s = _notice

    def fire():
        if _notice and _notice[0] is callback:
            _notice.clear()  # said once
            callback()

    timer = threading.Timer(after_s, fire)
    timer.daemon = True
    timer.start()
    return timer
