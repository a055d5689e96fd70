"""Coverage of the rigid-body model's stated 95 % intervals on simulated sessions with a known truth, for
the values the model uses in the loop and for the values it reports, and what a repeated stretch of data
does to them.

Sessions: one per seed of each planted preset (crane_io/sim/plants/), 60 s of operator-like motion of
joints 1, 2 and 4 (tests/planted.py drives the plant directly at 500 Hz):

* `hidden-spring`: a 0.3 N m/rad spring on joint1 relaxed at 0.5 rad (stiffness, correlated with
  joint1's inertia in back-and-forth moves);
* `hidden-rotor-inertia`: 0.02 kg m^2 of rotor inertia on joint4 (an inertia column itself);
* `hidden-coulomb`: 0.25 N m of Coulomb friction on joint2;
* `hidden-viscous`: 0.08 N m s/rad of viscous friction on joint1;
* `hidden-cogging`: a 12/rev ripple of 0.08 N m on joint4 (the fit's linear coefficients are its sin and
  cos pair, amplitude x cos and x sin of the phase; amplitude and phase are judged in the diagnosis);
* and in every session the plant's viscous friction on joint2 (0.04 N m s/rad, a known effect).

Each session is preprocessed as `crane-train fit` does (the default, causal filters) and fitted by the
rigid-body model with the preset's known effects plus the hidden one (a shape at its true value), on every
all-moving sample. Counted for each parameter: how often value +- ci95_factor x stderr (the block
jackknife, train.evaluation.block_uncertainty) covers the truth, for the loop model's own fit (`loop`,
model.theta: the causal signals) and for the values the model reports (`reported`,
model.reported_parameters(): the same samples' zero-phase signals); and, for the loop fit, how often
value +- 1.96 x the least-squares covariance's standard error would. A binomial 99.8 % band of a correct
95 % interval over the same number of sessions is in the notes.

Repeated stretch: the first session's samples with its middle 20 s appended once more (exact copies, as
a copied file would give); the ratio of the first parameter's stated +- with and without the copy.

`--sessions DIR` keeps the simulated sessions there (PRESET-SEED.h5) and reuses those it finds;
`--presets a,b`, `--seeds 0-19`. Slow: ~20-40 s of simulation per session on a shared 2-core machine;
--quick runs 4 seeds of 30 s of the spring alone.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PRESETS = ("hidden-spring", "hidden-rotor-inertia", "hidden-coulomb", "hidden-viscous", "hidden-cogging")
ALWAYS = (("viscous", "joint2"),)  # plant effects every preset has, judged in every session too


def _setup():
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))  # tests/planted.py: the planted-session simulator


def _model(ds, preset: str):
    """The model (known effects + the hidden one at its true shape) and {parameter name: truth}."""
    from crane_io.physics.effects import get_effect
    from crane_io.sim.plant_config import load_plant_config
    from train.models.registry import make_model

    config = load_plant_config(preset)
    hidden = config.hidden.as_dict()
    effects = [(n, j, None) for n, j, _ in config.known if j is None or j in ds.joint_names]
    name, joint = hidden["effect"], hidden["joint"]
    effect = get_effect(name)
    shape = {k: float(hidden[k]) for k in effect.shape_grid if k in hidden} or None
    effects.append((name, joint, shape))
    truths = {}
    values = {p.name: float(hidden[p.name]) for p in effect.params if p.name in hidden}
    for k, column in enumerate(effect.column_names(joint, shape)):  # "spring.stiffness@joint1": "stiffness"
        key = column.split(".", 1)[1].split("@")[0]
        if key in hidden:
            truths[column] = float(hidden[key])
        elif key in ("sin", "cos"):  # a ripple's coefficient pair: amplitude x cos, sin of the phase
            truths[column] = float(effect.coefficients(values)[k])
    for ename, ejoint in ALWAYS:
        for spec in config.effects:
            if spec.effect == ename and spec.joint == ejoint and (ename, ejoint) != (name, joint):
                truths[f"{ename}.{ename}@{ejoint}"] = float(spec.values[ename])
    return make_model("rigid-body", ds.joint_names, effects=effects), truths


def _fit(ds, preset: str) -> dict:
    """{parameter: (truth, loop value, loop stderr, least-squares stderr, reported value, reported stderr,
    95 % factor)}."""
    model, truths = _model(ds, preset)
    model.fit(ds)
    rows = np.flatnonzero(ds.all_moving)
    naive = model._solve(ds.subset(rows), model.terms, per_joint=False)[1]
    theta, stderr = model.reported_parameters()
    factor = model.fit_info["ci95_factor"]
    out = {}
    for name, truth in truths.items():
        i = model.names.index(name)
        out[name] = (truth, model.theta[i], model.stderr[i], naive[i], theta[i], stderr[i], factor)
    return out


def _session(folder: Path, preset: str, seed: int, duration: float):
    from tests.planted import simulate_session
    from train.data.preprocess import preprocess
    from train.data.session import read_sessions

    tail = "" if duration == 60.0 else f"-{duration:g}s"
    path = folder / f"{preset}-{seed}{tail}.h5"
    if not path.exists():
        tmp = path.with_suffix(".tmp.h5")
        simulate_session(tmp, preset, duration_s=duration, seed=seed)
        tmp.rename(path)
    return preprocess(read_sessions([path]))


def _summary(rows: np.ndarray) -> dict:
    """Counts of one parameter over sessions; rows (n, 7) as _fit gives them."""
    truth, v, se, naive, rv, rse, factor = rows.T
    out = {"n": len(rows), "truth": float(truth[0])}
    for key, value, err, f in (("loop", v, se, factor), ("reported", rv, rse, factor),
                               ("least-squares", v, naive, np.full(len(rows), 1.96))):
        out[key] = {"hits": int((np.abs(value - truth) <= f * err).sum()), "mean": float(value.mean()),
                    "bias": float((value - truth).mean()), "sd": float(value.std(ddof=1)) if len(rows) > 1
                    else float("nan"), "se": float(err.mean())}
    return out


def coverage(presets, seeds, duration: float, folder: Path) -> dict:
    """{(preset, parameter): summary} over the seeds, and the repeated-stretch ratio of the first."""
    results, first = {}, None
    for preset in presets:
        fits = []
        for seed in seeds:
            ds = _session(folder, preset, seed, duration)
            first = (ds, preset) if first is None else first
            fits.append(_fit(ds, preset))
        for name in fits[0]:
            results[(preset, name)] = _summary(np.array([f[name] for f in fits], dtype=float))
    ds, preset = first
    k = len(ds)
    again = ds.subset(np.concatenate([np.arange(k), np.arange(k // 3, 2 * k // 3)]))
    name = next(iter(_fit(ds, preset)))
    ratio = _fit(again, preset)[name][5] / _fit(ds, preset)[name][5]
    return {"results": results, "repeat_ratio": float(ratio), "repeat_parameter": name}


def _diagnose(ds, preset: str) -> dict:
    """The diagnosis of the baseline model (the preset's known effects) on the session: whether the hidden
    effect is named first on its joint, and per linear parameter of it (truth, value, 95 % interval,
    the loop fit's value and std)."""
    from crane_io.sim.plant_config import load_plant_config
    from train.diagnosis.cv import interval_factor
    from train.diagnosis.diagnose import diagnose
    from train.models.registry import make_model

    config = load_plant_config(preset)
    hidden = config.hidden.as_dict()
    effects = [(n, j, None) for n, j, _ in config.known if j is None or j in ds.joint_names]
    model = make_model("rigid-body", ds.joint_names, effects=effects).fit(ds)
    d = diagnose(model, ds)
    first = min((c for c in d.candidates if c.joint == hidden["joint"]), key=lambda c: c.rank)
    named = first.effect == hidden["effect"] and bool(first.significant)
    factor = interval_factor(d.settings["folds"])
    out = {"named": named, "values_from": d.settings.get("values_from", "")}
    for name, p in (first.parameters if named else {}).items():
        if name in hidden and name in {q.name for q in _linear(hidden["effect"])}:
            truth = float(hidden[name])
            lo, hi = p["ci95"]
            lv, ls = p.get("loop_value", p["value"]), p.get("loop_std", p["std"])
            out[f"{hidden['effect']}.{name}@{hidden['joint']}"] = (
                truth, p["value"], p["std"], lo <= truth <= hi, lv, ls, abs(lv - truth) <= factor * ls)
    return out


def _linear(name: str):
    from crane_io.physics.effects import get_effect

    return get_effect(name).linear_params


def diagnosis_coverage(presets, seeds, duration: float, folder: Path) -> dict:
    """{(preset, parameter): counts} of the diagnosis over the seeds: named first, reported interval
    covering the truth, the loop fit's interval covering it."""
    out = {}
    for preset in presets:
        runs = [_diagnose(_session(folder, preset, seed, duration), preset) for seed in seeds]
        names = {k for r in runs for k in r if k not in ("named", "values_from")}
        for name in sorted(names):
            rows = np.array([r[name] for r in runs if name in r], dtype=float)
            truth = rows[:, 0]
            out[(preset, name)] = {
                "n": len(runs), "named": sum(r["named"] for r in runs), "truth": float(truth[0]),
                "hits": int(rows[:, 3].sum()), "loop_hits": int(rows[:, 6].sum()),
                "bias": float((rows[:, 1] - truth).mean()), "sd": float(rows[:, 1].std(ddof=1)),
                "se": float(rows[:, 2].mean()), "loop_bias": float((rows[:, 4] - truth).mean()),
                "loop_sd": float(rows[:, 4].std(ddof=1)), "loop_se": float(rows[:, 5].mean()),
                "values_from": runs[0]["values_from"]}
    return out


def _diagnosis_rows(c: dict, duration: float, load: float) -> list[dict]:
    out = []
    for (preset, name), s in c.items():
        where = f"{s['n']} sessions of {duration:g} s, {preset}, truth {s['truth']:g}; load {load:.1f}"
        out.append({"benchmark": "diagnosis interval coverage",
                    "metric": f"{name}: named first (significant)", "value": s["named"] / s["n"],
                    "unit": "fraction", "note": where})
        source = s["values_from"] or "the fits judged"
        for key, hits, bias, sd, se in (("reported", s["hits"], s["bias"], s["sd"], s["se"]),
                                        ("loop", s["loop_hits"], s["loop_bias"], s["loop_sd"], s["loop_se"])):
            out.append({"benchmark": "diagnosis interval coverage",
                        "metric": f"{name} {key}: 95 % intervals covering the truth (of those named)",
                        "value": hits / max(s["named"], 1), "unit": "fraction",
                        "note": f"{hits} of {s['named']}; bias {bias:+.2g}, sd {sd:.2g}, mean stated se "
                                f"{se:.2g}; from {source if key == 'reported' else 'the causal fits'}"})
    return out


def _rows(c: dict, duration: float, load: float) -> list[dict]:
    from scipy.stats import binom

    out = []
    for (preset, name), s in c["results"].items():
        lo, hi = binom.ppf(0.001, s["n"], 0.95), binom.ppf(0.999, s["n"], 0.95)
        where = (f"{s['n']} sessions of {duration:g} s, {preset}, truth {s['truth']:g}; a correct 95 % "
                 f"interval: {lo:g}-{hi:g} of {s['n']} (99.8 %); load {load:.1f}")
        for key in ("reported", "loop", "least-squares"):
            r = s[key]
            out.append({"benchmark": "rigid-body interval coverage",
                        "metric": f"{name} {key}: 95 % intervals covering the truth",
                        "value": r["hits"] / s["n"], "unit": "fraction",
                        "note": f"mean {r['mean']:.4g}, bias {r['bias']:+.2g}, sd {r['sd']:.2g}, mean stated "
                                f"se {r['se']:.2g}; {where}"})
    out.append({"benchmark": "rigid-body interval coverage",
                "metric": f"stated stderr of {c['repeat_parameter']} with a third repeated / without",
                "value": c["repeat_ratio"], "unit": "ratio",
                "note": "repeated samples join their first block"})
    return out


def _seeds(text: str) -> list[int]:
    a, _, b = text.partition("-")
    return list(range(int(a), int(b or a) + 1))


def run(quick: bool = False, presets=None, seeds=None, folder: str | None = None,
        parts=("fit", "diagnose")) -> list[dict]:
    _setup()
    if quick:
        presets, seeds, duration = presets or PRESETS[:1], seeds or list(range(4)), 30.0
    else:
        presets, seeds, duration = presets or PRESETS, seeds or list(range(20)), 60.0
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        where = Path(folder or tmp)
        where.mkdir(parents=True, exist_ok=True)
        rows = []
        if "fit" in parts:
            rows += _rows(coverage(presets, seeds, duration, where), duration, load)
        if "diagnose" in parts:
            rows += _diagnosis_rows(diagnosis_coverage(presets, seeds, duration, where), duration, load)
        return rows


def main() -> None:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="4 seeds of 30 s of the spring alone")
    ap.add_argument("--presets", default=None, help="comma-separated planted presets (default: all five)")
    ap.add_argument("--seeds", default=None, help="e.g. 0-19 or 0,3,5 (default: 0-19)")
    ap.add_argument("--sessions", default=None, metavar="DIR",
                    help="keep the simulated sessions here and reuse those found")
    ap.add_argument("--parts", default="fit,diagnose", help="fit, diagnose or both (comma-separated)")
    args = ap.parse_args()
    for row in run(args.quick, args.presets.split(",") if args.presets else None,
                   _seeds(args.seeds) if args.seeds else None, args.sessions,
                   tuple(args.parts.split(","))):
        print(f"{row['metric']:<72} {row['value']:<8.4g} {row['unit']:<9} {row['note']}")


if __name__ == "__main__":
    main()
