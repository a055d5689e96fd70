"""The identified arm model where it helps, measured on the simulated arm (lockstep sessions, so the
numbers do not depend on the machine's load):

1. what each kind of data is good for: identify (train.identification) and `fit --model rigid-body` on an
   excitation session, a bilateral session and both together; the held-out torque MSE per joint on the
   test blocks of a separate bilateral session;
2. `fit --model rigid-body --start-from arm_model.toml` on a short bilateral session: the fit started
   from the model identified from the excitation, with several weights, against the plain fit, on the
   same held-out session;
3. the round trip on an arm carrying a payload: an excitation on the `crane-x7` plant plus a 0.3 kg
   payload, identified, the simulated arm built from its arm_model.toml (plant key `arm_model`), and that
   plant's gravity torque against the true (payload) plant's and the stock arm's over random poses.

    .venv/bin/python benchmarks/bench_identified_model.py [--duration 60] [--short 30] [--workdir DIR]
                                                          [--round-trip-only]
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


def record(tmp: Path, kind: str, seed: int, duration: float, budget: int = 300,
           plant: str | None = None) -> Path:
    path = tmp / f"{kind}-{seed}-{duration:g}{'-' + Path(plant).stem if plant else ''}.h5"
    if path.exists():  # --workdir: recorded before with the same settings
        return path
    opts = RunOptions(output=path, sim=True, duration=duration, seed=seed, status=False, plant=plant)
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


def payload_plant(tmp: Path, mass: float) -> Path:
    """A plant TOML: the crane-x7 preset's effects plus a payload of `mass` kg."""
    from crane_io.sim.plant_config import load_plant_config

    lines = ['base = "crane-x7"', 'name = "payload"']
    for e in load_plant_config("crane-x7").effects:
        lines += ["[[effects]]", f'effect = "{e.effect}"'] + ([f'joint = "{e.joint}"'] if e.joint else [])
        lines += [f"{k} = {v!r}" for k, v in e.values.items()]
    lines += ["[[effects]]", 'effect = "payload"', f"mass = {mass!r}"]
    path = tmp / "payload.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def round_trip(tmp: Path, duration: float, mass: float = 0.3) -> None:
    """Part 3 of the module docstring, printed."""
    from crane_io.physics.dynamics import ArmDynamics
    from crane_io.sim.arm_plant import ArmPlant

    plant_toml = payload_plant(tmp, mass)
    ex = record(tmp, "excite", 0, duration, plant=str(plant_toml))
    res = _quiet(identify, str(ex), effects=EFFECTS, seed=0, scale_to_data=True)
    model = tmp / "arm_model_payload.toml"
    model.write_text(res.arm_model().to_toml())
    built = tmp / "identified_plant.toml"
    built.write_text(f'joints = ["joint1", "joint2", "joint4"]\narm_model = "{model.name}"\n')
    plant = ArmPlant(built)
    rng = np.random.default_rng(0)
    q = rng.uniform([-1.5, -1.4, -2.0], [1.5, 1.4, -0.3], (200, 3))
    g = plant.dyn.gravity_torque(q)
    true = ArmDynamics(("joint1", "joint2", "joint4"), payload_mass=mass).gravity_torque(q)
    stock = ArmDynamics(("joint1", "joint2", "joint4")).gravity_torque(q)
    print(f"\n3. round trip, {duration:g} s excitation on crane-x7 + {mass:g} kg payload: gravity torque "
          f"over 200 random poses, RMS per joint (N m)")
    print(f"   identified plant - true plant   {_fmt3(np.sqrt(((g - true) ** 2).mean(axis=0)))}")
    print(f"   stock arm - true plant          {_fmt3(np.sqrt(((stock - true) ** 2).mean(axis=0)))}")
    print(f"   identified plant - identified model at rest (max) "
          f"{np.abs(g - res.fit.model.predict(q, 0 * q, 0 * q)).max():.2e}")


def _fmt3(x) -> str:
    return " ".join(f"{v:8.4f}" for v in x)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--duration", type=float, default=60.0, help="s of each long session")
    p.add_argument("--short", type=float, default=30.0, help="s of the short bilateral sessions (part 2)")
    p.add_argument("--workdir", default=None, help="keep the sessions here (and reuse them)")
    p.add_argument("--round-trip-only", action="store_true", help="only part 3")
    a = p.parse_args()
    if not a.round_trip_only:
        bench(a.duration, a.short, a.workdir)
    with contextlib.ExitStack() as stack:
        tmp = Path(a.workdir) if a.workdir else Path(stack.enter_context(tempfile.TemporaryDirectory()))
        round_trip(tmp, a.duration)


if __name__ == "__main__":
    main()
