"""Every numba kernel a collection run uses, compiled now (or loaded from numba's cache, crane_io.jit):
`compile_kernels(sim=True)` is what `crane-collect run` does first, so that the run compiles nothing
later, and `python -m collect.kernels` is what `scripts/setup.sh` runs after an install, so that no
command pays the compilation (about `crane_io.jit.COMPILE_ESTIMATE_S`; later a second or two).
"""

from __future__ import annotations

import sys
import time

from crane_io.jit import COMPILE_ESTIMATE_S, compile_notice


def compile_kernels(sim: bool = True) -> None:
    """The control loop's kernels (controller, recorder, bus cycle) and, with `sim`, the simulator's
    (plant, chain, lockstep cycle, sensor noise, operator). Without numba nothing (the Python paths)."""
    from crane_io.dynamixel import cycle_kernel

    from . import controller_kernel
    from .bilateral_loop import _record_kernel

    if sim:
        from crane_io.sim import chain_kernel, lockstep_kernel, noise_kernel, plant_kernel

        from .operator import _hand_compiled

        plant_kernel.compiled()
        chain_kernel.compiled()
        lockstep_kernel.compiled()
        noise_kernel.verified()
        _hand_compiled()
    controller_kernel.compiled()
    _record_kernel()
    cycle_kernel.compiled()


def compile_sentence(sim: bool) -> str:
    """What a command says while it compiles the kernels (crane_io.jit.compile_notice)."""
    what = "the simulator's kernels" if sim else "the control kernels"
    estimate = COMPILE_ESTIMATE_S if sim else 6
    return (f"compiling {what} once, about {estimate} s, longer on a busy machine (numba; later runs load "
            "them from its cache)")


def main() -> int:
    """Compile (or load) every kernel, saying so when it compiles; a line when they are ready."""
    t0 = time.perf_counter()
    try:
        with compile_notice(lambda: print(f"== {compile_sentence(True)}", flush=True)):
            compile_kernels(sim=True)
    except KeyboardInterrupt:
        print("interrupted; the first run compiles the kernels instead", file=sys.stderr)
        return 130
    print(f"== numba kernels ready ({time.perf_counter() - t0:.1f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
