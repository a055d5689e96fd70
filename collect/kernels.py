"""Every numba kernel a collection run uses, compiled now (or loaded from numba's cache, crane_io.jit):
`compile_kernels()` is what `crane-collect run --sim` and `sim-serve` do first, so that they compile
nothing later, and `python -m collect.kernels` is what `scripts/setup.sh` runs after an install, so that no
command pays the compilation (about `crane_io.jit.COMPILE_ESTIMATE_S`; later a second or two).
"""

from __future__ import annotations

import os
import sys
import time

from crane_io.jit import COMPILE_ESTIMATE_S, compile_notice


def compile_kernels() -> None:
    """The simulator's kernels (plant, chain, lockstep cycle, sensor noise, operator) and the control loop's
    (controller, recorder, bus cycle). Without numba nothing (the Python paths). Not for a run on real arms:
    there numba is not imported before the controller is built (collect/controller.py), and the bus and the
    recorder compile theirs when they start."""
    from crane_io.dynamixel import cycle_kernel
    from crane_io.sim import chain_kernel, lockstep_kernel, noise_kernel, plant_kernel

    from . import controller_kernel, operator_kernel
    from .bilateral_loop import _record_kernel

    # the environment's switches to the reference paths (crane_io.sim.chain, arm_plant): not compiled
    chain_fast = os.environ.get("CRANE_CHAIN_FAST", "1") != "0"
    if chain_fast or os.environ.get("CRANE_PLANT_KERNEL", "1") != "0":
        plant_kernel.compiled()
    if chain_fast:
        chain_kernel.compiled()
        lockstep_kernel.compiled()
    noise_kernel.verified()
    operator_kernel.compiled()
    controller_kernel.compiled()
    _record_kernel()
    cycle_kernel.compiled()


def compile_sentence() -> str:
    """What a command says while it compiles the kernels (crane_io.jit.compile_notice)."""
    return (f"compiling the simulator's kernels once, about {COMPILE_ESTIMATE_S} s, longer on a busy machine "
            "(numba; later runs load them from its cache)")


def main() -> int:
    """Compile (or load) every kernel, saying so when it compiles; a line when they are ready."""
    t0 = time.perf_counter()
    try:
        with compile_notice(lambda: print(f"== {compile_sentence()}", flush=True)):
            compile_kernels()
    except KeyboardInterrupt:
        print("interrupted; the first run compiles the kernels instead", file=sys.stderr)
        return 130
    print(f"== numba kernels ready ({time.perf_counter() - t0:.1f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
