"""The self-test's acceptance battery: `crane-collect selftest`'s checks (collect/selftest.py) on in-process
simulated arms, lockstep. Healthy arms (plant seeds 0-9) must pass; each planted miswiring
(crane_io/sim/wiring_faults.py) must fail. Prints one line per arm and the totals; exit 1 when an arm
is judged wrongly.

    .venv/bin/python scripts/selftest_battery.py              # 10 healthy seeds, 5 faults, 4 more faults
    .venv/bin/python scripts/selftest_battery.py --seeds 2    # fewer healthy seeds
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from crane_io.description import default_arm  # noqa: E402
from crane_io.sim.wiring_faults import WiringFaults  # noqa: E402

FAULTS = {  # the five planted miswirings of the acceptance
    "swapped IDs 2,3": WiringFaults(swap_ids=(2, 3)),
    "reversed joint2": WiringFaults(reversed_joints=("joint2",)),
    "wrong model on ID 5": WiringFaults(wrong_models=((5, "XM540-W270"),)),
    "current sign -1": WiringFaults(current_sign=-1.0),
    "torque constant x2": WiringFaults(current_scale=2.0),
}
MORE_FAULTS = {  # harder variants: same-model swaps, other reversed joints, a scale the other way
    "swapped IDs 5,6": WiringFaults(swap_ids=(5, 6)),
    "reversed joint3": WiringFaults(reversed_joints=("joint3",)),
    "reversed joint4": WiringFaults(reversed_joints=("joint4",)),
    "torque constant x0.5": WiringFaults(current_scale=0.5),
}


def one(faults: WiringFaults, seed: int):
    from collect.cli.selftest import SIM_PERIOD_S, simulated_selftest_arm
    from collect.selftest import run_selftest

    arm = default_arm()
    t0 = time.perf_counter()
    with simulated_selftest_arm(arm, seed, faults) as sim:
        result = run_selftest(sim.url, arm, None, period_s=SIM_PERIOD_S, paced=False)
    return result, time.perf_counter() - t0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10, help="healthy arms, seeds 0..N-1")
    parser.add_argument("--no-more", action="store_true", help="only the five acceptance faults")
    args = parser.parse_args()
    from collect.kernels import compile_kernels

    compile_kernels()
    cases = [(f"healthy seed {s}", WiringFaults(), s, True) for s in range(args.seeds)]
    cases += [(name, f, 0, False) for name, f in FAULTS.items()]
    if not args.no_more:
        cases += [(name, f, 0, False) for name, f in MORE_FAULTS.items()]
    right = {"healthy": [0, 0], "fault": [0, 0], "more": [0, 0]}
    print(f"{'arm':<24} {'verdict':<8} {'ok':<4} {'arm s':>6} {'wall s':>7}  failing checks")
    for name, faults, seed, healthy in cases:
        result, wall = one(faults, seed)
        ok = result.passed == healthy
        group = "healthy" if healthy else ("fault" if name in FAULTS else "more")
        right[group][0] += ok
        right[group][1] += 1
        failing = ", ".join(f"{f.check} {f.joint}" for f in result.findings if f.failed) or "-"
        print(f"{name:<24} {'PASSED' if result.passed else 'FAILED':<8} {'yes' if ok else 'NO':<4} "
              f"{result.duration_s:6.1f} {wall:7.1f}  {failing}", flush=True)
    print(f"healthy arms passed: {right['healthy'][0]} of {right['healthy'][1]}; planted miswirings caught: "
          f"{right['fault'][0]} of {right['fault'][1]}"
          + ("" if args.no_more else f"; more miswirings caught: {right['more'][0]} of {right['more'][1]}"))
    wrong = sum(n - k for k, n in right.values())
    return 1 if wrong else 0


if __name__ == "__main__":
    sys.exit(main())
