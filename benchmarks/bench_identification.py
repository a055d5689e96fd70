"""Identification on the simulated arm against its goals: an excitation session (`crane-collect excite
--sim`) and a bilateral session (`crane-collect run --sim`) of the same length identify models
(train.identification) that are judged on a separate bilateral session, against the plant's truth and in
the control loop.

Per seed: an excitation designed on the plain condition number, one designed on the normalised one
(`ExcitationOptions(normalised=True)`) and a bilateral session, each identified with the plant's effect
set, for coverage and for the held-out error on the first seed's separate bilateral session. The first
seed also gives the details:

1. held-out torque MSE on the test blocks of a separate bilateral session (its own seed) per joint, of
   the model identified from the excitation and of the one identified from the bilateral session, both
   with the plant's effect set (--effect as in PLANT_EFFECTS) and with the default (viscous, Coulomb);
   the noise floor: the plant's structure fitted on that session's own training pool (same split).
2. condition numbers of both recordings: the plain one of the base + friction regressor
   (crane_io.physics.excitation_trajectory.recording_condition), its unit-column-norm version, and the
   one identify prints (weighted, unit-norm columns, the fit's rows).
3. physical consistency of every run and the coverage of the 95 % intervals (estimate +- 1.96 stderr)
   of every parameter with a truth: the base parameters of the plant's rigid body plus its rotor
   inertia (found by least squares of the model's base columns on the plant's exact inverse dynamics
   over random states), friction from the plant preset.
4. the identified arm model as both arms' nominal observer model (`run --arm-model`) against the stock
   one, same seed: the follower's false reaction torque in free motion (`crane-train fidelity` with the
   truth trace).

    .venv/bin/python benchmarks/bench_identification.py [--quick] [--seeds 0,1,2] [--duration 180]
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

import h5py  # noqa: E402
import numpy as np  # noqa: E402

from collect.config import load_config  # noqa: E402
from collect.excitation import ExcitationOptions, models, run_excitation  # noqa: E402
from collect.run_options import RunOptions  # noqa: E402
from collect.runner import run_session  # noqa: E402
from crane_io import session_format as sf  # noqa: E402
from crane_io.physics.dynamics import ArmDynamics  # noqa: E402
from crane_io.physics.excitation_trajectory import recording_condition  # noqa: E402
from crane_io.sim.plant_config import load_plant_config  # noqa: E402
from train.api import load_sessions, load_settings  # noqa: E402
from train.data.splits import make_splits  # noqa: E402
from train.identification.identify import identify  # noqa: E402

PLANT = "crane-x7"
# the plant's structure in identify's terms: Coulomb (its stiction while moving), viscous, Stribeck on every
# joint, rotor inertia where it is not a base parameter already (joint4)
PLANT_EFFECTS = ("coulomb", "viscous", "stribeck:stribeck_velocity=0.05", "rotor-inertia:joint=joint4")
DEFAULT_EFFECTS = ("viscous", "coulomb")
Z95 = 1.959964


def _quiet(fn, *args, **kwargs):
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        return fn(*args, **kwargs)


def record(tmp: Path, kind: str, seed: int, duration: float, budget: int, normalised: bool = False,
           **extra) -> Path:
    tag = "-".join([Path(str(v)).stem for v in extra.values()] + (["normalised"] if normalised else []))
    path = tmp / f"{kind}-{seed}-{duration:g}-{budget}{'-' + tag if tag else ''}.h5"
    if path.exists():  # --workdir: a session recorded before with the same settings
        return path
    opts = RunOptions(output=path, sim=True, duration=duration, seed=seed, status=False, **extra)
    if kind == "excite":
        _quiet(run_excitation, opts, ExcitationOptions(evaluations=budget, say=lambda _line: None,
                                                         normalised=normalised))
    else:
        _quiet(run_session, opts)
    return path


def conditions(path: Path, config) -> dict:
    with h5py.File(path, "r") as f:
        names = [n.decode() if isinstance(n, bytes) else n for n in f.attrs[sf.JOINT_NAMES_ATTR]]
        joints = [n.decode() if isinstance(n, bytes) else n for n in f.attrs[sf.BILATERAL_JOINTS_ATTR]]
        q = f["follower/q"][:]
        rate = float(f.attrs[sf.RATE_ATTR])
    dynamics, _ = models(config, tuple(joints))
    qj = q[:, [names.index(n) for n in joints]]
    return {"plain": recording_condition(dynamics, qj, rate),
            "unit": recording_condition(dynamics, qj, rate, normalised=True)}


def plant_truth(result) -> dict[str, float]:
    """name -> true value for every identified parameter the plant defines."""
    plant = load_plant_config(PLANT)
    model = result.fit.model
    joints = list(model.joint_names)
    armature = np.zeros(len(joints))
    friction: dict[str, float] = {}
    for e in plant.effects:
        name, joint, params = e.effect, e.joint, dict(e.values)
        if joint not in joints:
            continue
        if name == "rotor-inertia":
            armature[joints.index(joint)] += params["inertia"]
        elif name == "stiction":
            friction[f"coulomb.coulomb@{joint}"] = params["coulomb"]
        elif name in ("viscous", "coulomb", "stribeck"):
            friction[f"{name}.{name}@{joint}"] = params[name]
    locked = {k: float(v) for k, v in dict(plant.locked).items() if k not in joints}
    plant_dyn = ArmDynamics(tuple(joints), locked=locked)
    rng = np.random.default_rng(0)
    n = 400
    q = rng.uniform(-1.5, 1.5, (n, len(joints)))
    dq, ddq = rng.normal(0, 1.0, (n, len(joints))), rng.normal(0, 3.0, (n, len(joints)))
    tau = plant_dyn.inverse_dynamics(q, dq, ddq) + armature * ddq
    ctx = result.fit.splits.pool.context  # the held joints where they were, at rest
    if isinstance(ctx, dict) and ctx.get("names"):
        ctx = {**ctx, "q": np.repeat(np.asarray(ctx["q"])[:1], n, axis=0),
               "dq": np.zeros((n, len(ctx["names"]))), "ddq": np.zeros((n, len(ctx["names"])))}
    else:
        ctx = None
    phi = model.regressor(q, dq, ddq, context=ctx)
    inertial = [k for k, nm in enumerate(result.names) if k < result.n_base or nm.startswith("rotor-inertia")]
    a = phi[:, :, inertial].reshape(-1, len(inertial))
    theta = np.linalg.lstsq(a, tau.ravel(), rcond=None)[0]
    misfit = float(np.sqrt(np.mean((a @ theta - tau.ravel()) ** 2)))
    if misfit > 1e-6:
        raise RuntimeError(f"the model's rigid body does not span the plant's (misfit {misfit:.2e} N m)")
    truth = {result.names[k]: float(v) for k, v in zip(inertial, theta)}
    for nm in result.names:
        if nm in friction:
            truth[nm] = friction[nm]
    return truth


def coverage(result, truth: dict[str, float]) -> list[tuple[str, float, float, float, bool]]:
    est, se = result.estimate.theta, result.estimate.stderr
    rows = []
    for k, nm in enumerate(result.names):
        if nm in truth:
            rows.append((nm, truth[nm], float(est[k]), float(se[k]), abs(est[k] - truth[nm]) <= Z95 * se[k]))
    return rows


ZERO_PHASE = False  # --zero-phase: every session filtered forward and backward (identify's zero_phase)


def identify_as_set(path: Path, effects, seed: int):
    return _quiet(identify, str(path), effects=effects, seed=seed, scale_to_data=True, zero_phase=ZERO_PHASE)


def heldout_on(result, path: Path, seed: int) -> np.ndarray:
    """Per joint MSE (N m)^2 of the model on the test blocks of the session at `path` (identify's split)."""
    ds = load_sessions(str(path), zero_phase=ZERO_PHASE)
    test = make_splits(ds, load_settings(None)["splits"], seed=seed, scale_to_data=True).test
    pred = result.fit.model.predict_dataset(test)
    err = (test.tau - pred) ** 2
    return np.array([err[test.moving[:, j], j].mean() for j in range(test.tau.shape[1])])


def _fmt(xs) -> str:
    return " ".join(f"{x:9.5f}" for x in xs)


def bench(seeds: list[int], duration: float, budget: int, workdir: str | None = None, loop: bool = True,
          zero_phase: bool = False) -> list[dict]:
    """Every part of the module docstring, printed; the headline figures as run_all.py rows."""
    global ZERO_PHASE
    ZERO_PHASE = zero_phase
    out: list[dict] = []

    def row(metric: str, value: float, unit: str = "", note: str = "") -> None:
        out.append({"benchmark": "identification", "metric": metric, "value": float(value), "unit": unit,
                    "note": note})

    config = load_config(None)
    t_start = time.perf_counter()
    with contextlib.ExitStack() as stack:
        tmp = Path(workdir) if workdir else Path(stack.enter_context(tempfile.TemporaryDirectory()))
        tmp.mkdir(parents=True, exist_ok=True)
        cover: list = []
        consistent: list = []
        held_seed = seeds[0] + 1000
        held = record(tmp, "run", held_seed, duration, budget)
        r_floor = identify_as_set(held, PLANT_EFFECTS, held_seed)
        floor = r_floor.heldout_mse
        per_seed: list[str] = []
        kinds: dict[str, list] = {}
        for i, seed in enumerate(seeds):
            ex = record(tmp, "excite", seed, duration, budget)
            r_ex = identify_as_set(ex, PLANT_EFFECTS, seed)
            truth = plant_truth(r_ex)
            rows = coverage(r_ex, truth)
            cover += rows
            consistent.append((seed, r_ex.projection.as_estimated, r_ex.projection.within_uncertainty,
                               r_ex.projection.chi2, r_ex.projection.dof))
            print(f"seed {seed}: excitation {duration:.0f} s, identify condition "
                  f"{r_ex.estimate.condition:.1f}; "
                  f"{sum(r[4] for r in rows)}/{len(rows)} truths inside their 95 % interval; consistent as "
                  f"estimated {r_ex.projection.as_estimated}, within uncertainty "
                  f"{r_ex.projection.within_uncertainty} (chi2 {r_ex.projection.chi2:.2f}, dof "
                  f"{r_ex.projection.dof})  [{time.perf_counter() - t_start:.0f} s]", flush=True)
            for nm, tv, ev, sv, inside in rows:
                print(f"    {nm:34s} truth {tv:10.5f} estimate {ev:10.5f} +- {Z95 * sv:9.5f} "
                      f"{'in' if inside else 'OUT'}")
            ex_norm = record(tmp, "excite", seed, duration, budget, normalised=True)
            for kind, path in (("excitation", ex), ("excitation, normalised design", ex_norm),
                               ("bilateral", record(tmp, "run", seed, duration, budget))):
                res = r_ex if kind == "excitation" else identify_as_set(path, PLANT_EFFECTS, seed)
                rows_k = coverage(res, truth if kind == "excitation" else plant_truth(res))
                ratio = heldout_on(res, held, held_seed) / floor
                kinds.setdefault(kind, []).append((rows_k, ratio, res.estimate.condition,
                                                   res.projection.within_uncertainty))
                per_seed.append(f"{seed:4d}  {kind:30s} {res.estimate.condition:6.1f} "
                                f"{sum(r[4] for r in rows_k):3d}/{len(rows_k)}   "
                                + " ".join(f"{x:5.2f}x" for x in ratio))
            if i > 0:
                continue
            bil = record(tmp, "run", seed, duration, budget)
            r_ex_d = identify_as_set(ex, DEFAULT_EFFECTS, seed)
            r_bil = identify_as_set(bil, PLANT_EFFECTS, seed)
            r_bil_d = identify_as_set(bil, DEFAULT_EFFECTS, seed)
            bil_rows = coverage(r_bil, plant_truth(r_bil))
            print(f"bilateral seed {seed} ({duration:.0f} s), plant effects: {sum(r[4] for r in bil_rows)}/"
                  f"{len(bil_rows)} truths inside their 95 % interval; "
                  + ", ".join(f"{nm} {ev:.4f} (truth {tv:.4f})" for nm, tv, ev, _s, _i in bil_rows
                              if nm in ("joint1.Izz+", "joint2.Iyy+", "joint2.Ixx+", "joint4.Iyy")))
            joints = list(r_ex.fit.model.joint_names)
            print(f"\n1. held-out torque MSE (N m)^2 on the test blocks of bilateral seed {seed + 1000} "
                  f"({duration:.0f} s), joints {', '.join(joints)}")
            print(f"{'model':44s} {_fmt([0] * 0)}" + " ".join(f"{j:>9s}" for j in joints) + "   / floor")
            print(f"{'floor: plant structure fitted on its pool':44s} {_fmt(floor)}")
            for label, res in (("excitation, plant effects", r_ex), ("excitation, viscous+coulomb", r_ex_d),
                               ("bilateral, plant effects", r_bil), ("bilateral, viscous+coulomb", r_bil_d)):
                mse = heldout_on(res, held, seed + 1000)
                print(f"{label:44s} {_fmt(mse)}   " + " ".join(f"{m / f:5.2f}x" for m, f in zip(mse, floor)))
            ex_n = record(tmp, "excite", seed, duration, budget, normalised=True)
            r_ex_n = identify_as_set(ex_n, PLANT_EFFECTS, seed)
            c_ex, c_bil, c_n = conditions(ex, config), conditions(bil, config), conditions(ex_n, config)
            mse_n = heldout_on(r_ex_n, held, seed + 1000)
            print(f"{'excitation (normalised design), plant effects':44s} {_fmt(mse_n)}   "
                  + " ".join(f"{m / f:5.2f}x" for m, f in zip(mse_n, floor)))
            print(f"\n2. condition numbers, {duration:.0f} s each (excitation whole session / bilateral)")
            print(f"   plain (base + friction columns)       {c_ex['plain']:8.1f} / {c_bil['plain']:8.1f} = "
                  f"{c_bil['plain'] / c_ex['plain']:.2f}x")
            print(f"   unit-norm columns                     {c_ex['unit']:8.1f} / {c_bil['unit']:8.1f} = "
                  f"{c_bil['unit'] / c_ex['unit']:.2f}x")
            print(f"   identify (weighted, unit-norm, plant effects) {r_ex.estimate.condition:8.1f} / "
                  f"{r_bil.estimate.condition:8.1f} = "
                  f"{r_bil.estimate.condition / r_ex.estimate.condition:.2f}x")
            print(f"   identify (weighted, unit-norm, viscous+coulomb) {r_ex_d.estimate.condition:8.1f} / "
                  f"{r_bil_d.estimate.condition:8.1f} = "
                  f"{r_bil_d.estimate.condition / r_ex_d.estimate.condition:.2f}x")
            print(f"   trajectory designed on the unit-norm condition number (excite normalised=True): plain "
                  f"{c_n['plain']:.1f} ({c_bil['plain'] / c_n['plain']:.2f}x), unit-norm {c_n['unit']:.1f} "
                  f"({c_bil['unit'] / c_n['unit']:.2f}x), identify {r_ex_n.estimate.condition:.1f} "
                  f"({r_bil.estimate.condition / r_ex_n.estimate.condition:.2f}x)", flush=True)
            row("condition number, identify: bilateral / excitation", r_bil.estimate.condition
                / r_ex.estimate.condition, "x", f"seed {seed}, {duration:.0f} s, goal >= 10")
            if not loop:
                continue
            model_dir = tmp / "model-ex"
            _quiet(r_ex.save, model_dir, force=True)
            loop_s = min(duration, 60.0)
            stock_tr, id_tr = tmp / "stock.truth.h5", tmp / f"ident{'-zp' if ZERO_PHASE else ''}.truth.h5"
            stock = record(tmp, "run", seed + 2000, loop_s, budget, truth_trace=stock_tr)
            ident = record(tmp, "run", seed + 2000, loop_s, budget, truth_trace=id_tr,
                           arm_model=model_dir / "arm_model.toml")
            from train.evaluation.fidelity import measure_fidelity

            f_stock, f_id = measure_fidelity(stock, stock_tr), measure_fidelity(ident, id_tr)
            print(f"\n4. follower false reaction torque RMS in free motion, N m ({loop_s:.0f} s, seed "
                  f"{seed + 2000}): stock nominal model / identified arm model (excitation, plant effects)")
            for j in f_stock.joints:
                a, b = f_stock.joints[j]["follower_false_rms"], f_id.joints[j]["follower_false_rms"]
                print(f"   {j}: {a:.4f} / {b:.4f} ({'lower' if b < a else 'NOT lower'})")
                row(f"false reaction torque {j}: arm model / stock", b / a, "x",
                    f"seed {seed + 2000}, goal < 1")
        print(f"\nper seed, plant effects: identify's condition number, truths inside their 95 % interval, "
              f"held-out MSE / floor on bilateral seed {held_seed} "
              f"(joints {', '.join(r_floor.fit.model.joint_names)})")
        print("\n".join(per_seed))
        for kind, runs in kinds.items():
            n_k = sum(sum(r[4] for r in rows_k) for rows_k, *_ in runs)
            t_k = sum(len(rows_k) for rows_k, *_ in runs)
            worst = np.max([ratio for _, ratio, *_ in runs], axis=0)
            row(f"worst held-out MSE / floor, {kind}", float(worst.max()), "x",
                "every joint and seed, goal <= 1.1")
            row(f"coverage of 95 % intervals, {kind}", 100 * n_k / max(t_k, 1), "%", "goal >= 90")
            print(f"   {kind:30s} coverage {n_k}/{t_k} = {100 * n_k / max(t_k, 1):.0f} %; physically "
                  f"consistent (projection within uncertainty) {sum(r[3] for r in runs)}/{len(runs)}; "
                  f"worst held-out / floor " + " ".join(f"{x:.2f}x" for x in worst))
        n_in = sum(r[4] for r in cover)
        print(f"\n3. over seeds {seeds}: physically consistent (projection found) in {len(consistent)}/"
              f"{len(consistent)} runs; as estimated in {sum(c[1] for c in consistent)}, within uncertainty "
              f"in "
              f"{sum(c[2] for c in consistent)}; truth inside the 95 % interval for {n_in}/{len(cover)} "
              f"= {100 * n_in / max(len(cover), 1):.0f} % of parameter estimates")
        by_name: dict[str, list[bool]] = {}
        for nm, *_rest, inside in cover:
            by_name.setdefault(nm, []).append(inside)
        print("   per parameter: " + "; ".join(f"{nm} {sum(v)}/{len(v)}" for nm, v in by_name.items()))
    print(f"\n[{time.perf_counter() - t_start:.0f} s wall]")
    return out


def run(quick: bool = False) -> list[dict]:
    """run_all.py's entry: --quick's settings, or the full three seeds."""
    return bench([0], 60.0, 300) if quick else bench([0, 1, 2], 180.0, 1000)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="60 s sessions, one seed, budget 300")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--duration", type=float, default=180.0)
    ap.add_argument("--budget", type=int, default=1000)
    ap.add_argument("--workdir", default=None, help="keep the sessions here and reuse them on a rerun")
    ap.add_argument("--zero-phase", action="store_true",
                    help="identify and judge on data filtered forward and backward")
    ap.add_argument("--no-loop", action="store_true", help="skip part 4 (the arm model in the loop)")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    duration, budget = args.duration, args.budget
    if args.quick:
        seeds, duration, budget = seeds[:1], 60.0, 300
    bench(seeds, duration, budget, args.workdir, not args.no_loop, args.zero_phase)


if __name__ == "__main__":
    main()
