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

numba keeps the machine code in `__pycache__` next to each kernel module (in `NUMBA_CACHE_DIR` when set).
numba itself notices only a change of the compiled module's own file; a kernel also draws on its layout
modules and on the kernels it calls (the lockstep cycle steps the plant kernel). So every compiled
function's cache entry is named with `sources_digest(namespace)`: a hash of the source of the module and
of every toolkit module it imports at its top level, transitively (constants imported from a layout
module are compiled into the machine code, so their module counts too). An edit anywhere a kernel draws on
compiles it again instead of loading machine code built from the old source. Loading from the cache takes
a fraction of a second per module; compiling them all (after an install, or after a kernel's source
changed) takes about `COMPILE_ESTIMATE_S` on a 2-core machine. `scripts/setup.sh` compiles them once
(`python -m collect.kernels`); a command that may compile says so while it does, with `compile_notice`.
"""

from __future__ import annotations

import contextlib
import hashlib
import sys
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
    tag = f"s{sources_digest(namespace)}."
    for name in names:
        f = ns[name]
        g = types.FunctionType(f.__code__, ns, name, f.__defaults__)
        g.__qualname__ = tag + (qualname_prefix + name if qualname_prefix else f.__qualname__)
        ns[name] = jit(g)
    done = _notice_watch([ns[name] for name in names])
    try:
        for name, sigs in signatures.items():
            for sig in sigs:
                ns[name].compile(sig)
    finally:
        if done is not None:
            done.set()
    return {name: ns[name] for name in names}


_PROJECT_PACKAGES = ("crane_io", "collect", "train")
_digests: dict[str, str] = {}


def _imported_modules(name: str, source: bytes, path: str) -> set[str]:
    """The toolkit modules module `name` (its `source`, from `path`) imports at its top level (relative
    imports resolved; `from a.b import c` counts a.b and a.b.c, the latter dropped later when it is
    not a module)."""
    import ast

    package = name.split(".") if path.endswith("__init__.py") else name.split(".")[:-1]
    found = set()
    for node in ast.parse(source).body:
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            module = ".".join([*base, *([node.module] if node.module else [])])
            found.add(module)
            found.update(f"{module}.{alias.name}" for alias in node.names)
    return {m for m in found if m.split(".")[0] in _PROJECT_PACKAGES}


def _source_file(name: str) -> str | None:
    import importlib.util

    module = sys.modules.get(name)
    path = getattr(module, "__file__", None) if module is not None else None
    if path is None:
        try:
            spec = importlib.util.find_spec(name)
        except (ImportError, ValueError):
            return None
        path = spec.origin if spec is not None else None
    return path if path and path.endswith(".py") else None


def module_sources(start: str) -> dict[str, bytes]:
    """Module name -> source bytes of `start` and of every toolkit module it imports at its top level,
    transitively."""
    seen, todo, sources = set(), [start], {}
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        path = _source_file(name)
        if path is None:  # a name imported from a module, not a module
            continue
        with open(path, "rb") as fh:
            sources[name] = fh.read()
        todo.extend(sorted(_imported_modules(name, sources[name], path) - seen))
    return sources


def sources_digest(namespace: dict) -> str:
    """A short hash of the sources (`module_sources`) of the module whose globals are `namespace`; the
    same for the same sources, in any process."""
    start = namespace.get("__name__")
    if start not in _digests:
        h = hashlib.sha256()
        for name, source in sorted(module_sources(start).items()):
            h.update(name.encode() + b"\0" + source)
        _digests[start] = h.hexdigest()[:12]
    return _digests[start]


@contextlib.contextmanager
def compile_notice(callback, after_s: float = 1.0):
    """While inside: once a `compile_functions` call is compiling (a signature missed numba's cache) and
    still busy after `after_s`, `callback()` is called, once, from a watching thread (a command says there
    what it is doing, e.g. "compiling the simulator's kernels once, about 30 s")."""
    _notice[:] = [callback, float(after_s)]
    try:
        yield
    finally:
        _notice.clear()


def _misses(dispatchers) -> int:
    """How many signatures of `dispatchers` numba had to compile (not found in its cache) so far."""
    total = 0
    for d in dispatchers:
        try:
            total += sum(d.stats.cache_misses.values())
        except AttributeError:  # a numba without dispatcher statistics: judge by the time alone
            return 1
    return total


def _notice_watch(dispatchers) -> threading.Event | None:
    """The compile_notice in effect, watched from a thread until the returned event is set: its callback
    is called once numba is compiling (a signature missed its cache) and the call has taken `after_s`,
    never for loading from the cache, however slow a busy machine makes that."""
    if not _notice:
        return None
    callback, after_s = _notice
    done = threading.Event()
    before = _misses(dispatchers)

    def watch():
        if done.wait(after_s):
            return
        while not done.is_set():
            if _misses(dispatchers) > before:
                if _notice and _notice[0] is callback:
                    _notice.clear()  # said once
                    callback()
                return
            done.wait(0.1)

    threading.Thread(target=watch, daemon=True, name="compile-notice").start()
    return done
