"""The identified arm model where it helps, measured on the simulated arm (lockstep sessions, so the
numbers do not depend on the machine's load):

1. what each kind of data is good for: identify (train.identification) and `fit --model rigid-body` on an
   excitation session, a bilateral session and both together; the held-out torque MSE per joint on the
   test blocks of a separate bilateral session;
2. `fit --model rigid-body --start-from arm_model.toml` on a short bilateral session: the fit started
   from the model identified from the excitation, with several weights, against the plain fit, on the
   same held-out session.

    .venv/bin/python benchmarks/bench_identified_model.py [--duration 60] [--short 30] [--workdir DIR]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: small dense problems

import argparse  # noqa: E402
import contextlib  # noqa: E402
import io  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from collect.excitation import ExcitationOptions, run_excitation  # noqa: E402
from collect.run_options import RunOptions  # noqa: E402
from collect.runner import run_session  # noqa: E402
from train.api import fit, load_sessions, load_settings  # noqa: E402
from train.data.splits import make_splits  # noqa: E402
from train.identification.identify import identify  # noqa: E402

EFFECTS = ("viscous", "coulomb")  # identify's default set, for both identify and fit
WEIGHTS = (10.0, 100.0, 1000.0)


def _quiet(fn, *args, **kwargs):
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        return fn(*args, **kwargs)


def record(tmp: Path, kind: str, seed: int, duration: float, budget: int = 300) -> Path:
    path = tmp / f"{kind}-{seed}-{duration:g}.h5"
    if path.exists():  # --workdir: recorded before with the same settings
        return path
    opts = RunOptions(output=path, sim=True, duration=duration, seed=seed, status=False)
    if kind == "excite":
        _quiet(run_excitation, opts, ExcitationOptions(evaluations=budget, say=lambda _line: None))
    else:
        _quiet(run_session, opts)
    return path


def heldout(model, held: Path, seed: int) -> np.ndarray:
    """Per joint MSE (N m)^2 of `model` on the test blocks of the session `held`, where each joint moves."""
    ds = load_sessions(str(held))
    test = make_splits(ds, load_settings(None)["splits"], seed=seed, scale_to_data=True).test
    err = (test.tau - model.predict_dataset(test)) ** 2
    return np.array([err[test.moving[:, j], j].mean() for j in range(test.tau.shape[1])])


def _row(label: str, mse: np.ndarray) -> str:
    return f"{label:46s}" + "".join(f"{m:11.5f}" for m in mse)


def bench(duration: float, short: float, workdir: str | None) -> None:
    t0 = time.perf_counter()
    with contextlib.ExitStack() as stack:
        tmp = Path(workdir) if workdir else Path(stack.enter_context(tempfile.TemporaryDirectory()))
        tmp.mkdir(parents=True, exist_ok=True)
        ex, bil = record(tmp, "excite", 0, duration), record(tmp, "run", 0, duration)
        held_seed = 1000
        held = record(tmp, "run", held_seed, duration)
        print(f"sessions recorded [{time.perf_counter() - t0:.0f} s]", flush=True)
        print(f"\n1. held-out MSE (N m)^2 on the test blocks of bilateral seed {held_seed} ({duration:g} s), "
              f"effects {', '.join(EFFECTS)}")
        print(f"{'model':46s}{'joint1':>11s}{'joint2':>11s}{'joint4':>11s}")
        arm_model = None
        kinds = (("excitation", [ex]), ("bilateral", [bil]), ("excitation + bilateral", [ex, bil]))
        for label, paths in kinds:
            res = _quiet(identify, [str(p) for p in paths], effects=EFFECTS, seed=0, scale_to_data=True)
            print(_row(f"identify on {label}", heldout(res.fit.model, held, held_seed)), flush=True)
            if arm_model is None:
                arm_model = tmp / "arm_model_excitation.toml"
                arm_model.write_text(res.arm_model().to_toml())
            fr = _quiet(fit, [str(p) for p in paths], "rigid-body", effects=EFFECTS, seed=0,
                        scale_to_data=True)
            print(_row(f"fit rigid-body on {label}", heldout(fr.model, held, held_seed)), flush=True)
        print(f"[{time.perf_counter() - t0:.0f} s]")
        print(f"\n2. rigid-body fit on {short:g} s of bilateral data, with and without --start-from the "
              f"excitation's arm model; same held-out session")
        print(f"{'model':46s}{'joint1':>11s}{'joint2':>11s}{'joint4':>11s}")
        for seed in (1, 2, 3):
            few = record(tmp, "run", seed, short)
            plain = _quiet(fit, [str(few)], "rigid-body", effects=EFFECTS, seed=0, scale_to_data=True)
            print(_row(f"seed {seed}: plain fit", heldout(plain.model, held, held_seed)), flush=True)
            for w in WEIGHTS:
                st = _quiet(fit, [str(few)], "rigid-body", effects=EFFECTS, seed=0, scale_to_data=True,
                            start_from=arm_model, start_weight=w)
                print(_row(f"seed {seed}: --start-from, --start-weight {w:g}",
                           heldout(st.model, held, held_seed)), flush=True)
        print(f"[{time.perf_counter() - t0:.0f} s]")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--duration", type=float, default=60.0, help="s of each long session")
    p.add_argument("--short", type=float, default=30.0, help="s of the short bilateral sessions (part 2)")
    p.add_argument("--workdir", default=None, help="keep the sessions here (and reuse them)")
    a = p.parse_args()
    bench(a.duration, a.short, a.workdir)


if __name__ == "__main__":
    main()
