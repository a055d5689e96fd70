"""The identification regressor's condition number: an excitation session (`crane-collect excite --sim`)
against a bilateral session of the same length (`crane-collect run --sim`), and the excitation's safety.

Both sessions are measured the same way (crane_io.physics.excitation_trajectory.recording_condition):
the follower's recorded angles, dq and ddq from a Savitzky-Golay filter, every 10th sample, the
base-parameter regressor of the session's joints (the others locked at [held]) plus viscous and Coulomb
columns per joint; also with every column scaled to unit norm ("normalised", free of the parameters'
units). The goal: the excitation's condition number at least 10 times lower. Safety: the excitation
session's recorded angles (of its joints) stay within the joint limits and clear of the table and the
arm's own links (crane_io.physics.arm_clearance) at every row, and it ends by its duration.

    .venv/bin/python benchmarks/bench_excitation.py [--duration 20] [--joints joint1,joint2,joint4]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: the regressor's SVDs are small

import argparse  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import h5py  # noqa: E402
import numpy as np  # noqa: E402

from collect.excitation import ExcitationOptions, models, run_excitation  # noqa: E402
from collect.run_options import RunOptions  # noqa: E402
from collect.runner import run_session  # noqa: E402
from crane_io import session_format as sf  # noqa: E402
from crane_io.description import default_arm  # noqa: E402
from crane_io.physics.excitation_trajectory import from_dict, recording_condition  # noqa: E402


def measure(path: Path, config) -> dict:
    """The condition number, the joint-limit and clearance margins and the end of one session."""
    with h5py.File(path, "r") as f:
        names = [n.decode() if isinstance(n, bytes) else n for n in f.attrs[sf.JOINT_NAMES_ATTR]]
        joints = [n.decode() if isinstance(n, bytes) else n for n in f.attrs[sf.BILATERAL_JOINTS_ATTR]]
        q = f["follower/q"][:]
        rate = float(f.attrs[sf.RATE_ATTR])
        end = f.attrs[sf.END_REASON_ATTR]
        start = float(f.attrs.get(sf.EXCITATION_START_ATTR, 0.0))
        traj = f.attrs.get(sf.EXCITATION_TRAJECTORY_ATTR)
    cols = [names.index(n) for n in joints]
    dynamics, clearance = models(config, tuple(joints))
    arm = default_arm()
    lower = np.array([arm.joint(n).lower for n in names])
    upper = np.array([arm.joint(n).upper for n in names])
    qj = q[:, cols]
    out = {"rows": len(q), "seconds": len(q) / rate, "end": end, "joints": joints,
           "condition": recording_condition(dynamics, qj, rate),
           "normalised": recording_condition(dynamics, qj, rate, normalised=True),
           "limit_margin_deg": float(np.degrees(np.min(np.minimum(q - lower, upper - q)[:, cols]))),
           "clearance_cm": 100.0 * float(np.min(clearance.clearance(qj[::5])))}
    if traj is not None:
        k0 = int(round(start * rate))
        designed = from_dict(json.loads(traj))
        k1 = k0 + int(round(designed.duration * rate))
        out["condition_trajectory_part"] = recording_condition(dynamics, qj[k0:k1], rate)
        out["designed_condition"] = designed.condition_number
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0, help="s of trajectory")
    ap.add_argument("--joints", default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--budget", type=int, default=1000)
    args = ap.parse_args()
    from collect.config import load_config

    with tempfile.TemporaryDirectory() as tmp:
        ex_path, bil_path = Path(tmp) / "excite.h5", Path(tmp) / "bilateral.h5"
        t0 = time.perf_counter()
        run_excitation(RunOptions(output=ex_path, sim=True, duration=args.duration, seed=args.seed,
                                  joints=args.joints, status=False),
                       ExcitationOptions(evaluations=args.budget, say=lambda _line: None))
        t_ex = time.perf_counter() - t0
        with h5py.File(ex_path, "r") as f:  # the trajectory's whole periods: the bilateral session's length
            length = from_dict(json.loads(f.attrs[sf.EXCITATION_TRAJECTORY_ATTR])).duration
        run_session(RunOptions(output=bil_path, sim=True, duration=length, seed=args.seed,
                               joints=args.joints, status=False))
        config = load_config(None)
        if args.joints is not None:
            config = config.with_bilateral_joints(args.joints)
        ex, bil = measure(ex_path, config), measure(bil_path, config)
    print(f"joints {', '.join(ex['joints'])}; excitation session {ex['seconds']:.1f} s (approach, "
          f"trajectory, rest; {t_ex:.0f} s wall, budget {args.budget} evaluations), "
          f"bilateral {bil['seconds']:.1f} s")
    print(f"{'session':<12} {'cond':>8} {'normalised':>11} {'limit margin':>14} {'clearance':>10}  "
          "end")
    for name, m in (("excitation", ex), ("bilateral", bil)):
        print(f"{name:<12} {m['condition']:>8.1f} {m['normalised']:>11.1f} "
              f"{m['limit_margin_deg']:>10.1f} deg "
              f"{m['clearance_cm']:>7.1f} cm  {m['end']}")
    print(f"designed trajectory: condition number {ex['designed_condition']:.1f}; recorded trajectory part "
          f"{ex['condition_trajectory_part']:.1f}")
    for what, value in (("designed trajectory", ex["designed_condition"]),
                        ("recorded trajectory part", ex["condition_trajectory_part"]),
                        ("whole excitation session", ex["condition"])):
        ratio = bil["condition"] / value
        print(f"bilateral / {what}: {ratio:.2f}x (goal >= 10x: {'met' if ratio >= 10 else 'NOT met'})")


if __name__ == "__main__":
    main()
