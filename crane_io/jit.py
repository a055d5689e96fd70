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
"""

from __future__ import annotations

import types


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
    for name, sigs in signatures.items():
        for sig in sigs:
            ns[name].compile(sig)
    return {name: ns[name] for name in names}
