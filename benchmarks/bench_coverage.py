"""Coverage of the rigid-body model's stated 95 % intervals on simulated sessions with a known truth, and
what a repeated stretch of data does to them.

Sessions: the `hidden-spring` plant (the baseline arm plus a 0.3 N m/rad spring on joint1, relaxed at
0.5 rad; crane_io/sim/plants/hidden-spring.toml), 60 s of operator-like motion of joints 1, 2 and 4
(tests/planted.py drives the plant directly at 500 Hz), one session per seed. Each is preprocessed as
`crane-train fit` does and fitted by the rigid-body model with the preset's known effects plus the
spring on joint1 at its true rest angle, on every all-moving sample of the session. Counted: how often
value +- ci95_factor x stderr (the block jackknife, train.evaluation.block_uncertainty) covers the true
stiffness, and how often value +- 1.96 x the least-squares covariance's standard error would. A
binomial 99.8 % band of a correct 95 % interval over the same number of sessions is in the notes.

Repeated stretch: the first session's samples with its middle 20 s appended once more (exact copies,
as a copied file would give); the ratio of the stiffness' stated +- with and without the copy.

Slow: ~20 s of simulation per session on a shared 2-core machine; --quick runs 4 seeds of 30 s.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PRESET = "hidden-spring"
PARAMETER = "spring.stiffness@joint1"


def _setup():
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))  # tests/planted.py: the planted-session simulator


def _model(ds):
    from crane_io.sim.plant_config import load_plant_config
    from train.models.registry import make_model

    config = load_plant_config(PRESET)
    truth = config.hidden.as_dict()  # effect, joint and its values
    effects = [(n, j, None) for n, j, _ in config.known if j is None or j in ds.joint_names]
    effects.append(("spring", truth["joint"], {"rest_angle": float(truth["rest_angle"])}))
    return make_model("rigid-body", ds.joint_names, effects=effects), float(truth["stiffness"])


def _fit(ds):
    """(value, stated stderr, least-squares covariance stderr, 95 % factor, truth) of the stiffness."""
    model, truth = _model(ds)
    model.fit(ds)
    i = model.names.index(PARAMETER)
    rows = np.flatnonzero(ds.all_moving)
    naive = model._solve(ds.subset(rows), model.terms, per_joint=False)[1]
    return model.theta[i], model.stderr[i], naive[i], model.fit_info["ci95_factor"], truth


def _session(folder: Path, seed: int, duration: float):
    from tests.planted import simulate_session
    from train.data.preprocess import preprocess
    from train.data.session import read_sessions

    path = simulate_session(folder / f"s{seed}.h5", PRESET, duration_s=duration, seed=seed)
    return preprocess(read_sessions([path]))


def coverage(seeds, duration: float, folder: Path) -> dict:
    fits, first = [], None
    for seed in seeds:
        ds = _session(folder, seed, duration)
        first = ds if first is None else first
        fits.append(_fit(ds))
    v, se, naive, factor, truth = (np.array(x) for x in zip(*fits))
    n = len(seeds)
    # the first session with its middle third appended once more
    k = len(first)
    again = first.subset(np.concatenate([np.arange(k), np.arange(k // 3, 2 * k // 3)]))
    se_again = _fit(again)[1]
    return {"n": n, "truth": float(truth[0]), "hits": int((np.abs(v - truth) <= factor * se).sum()),
            "naive_hits": int((np.abs(v - truth) <= 1.96 * naive).sum()), "values": v, "stderr": se,
            "naive": naive, "repeat_ratio": float(se_again / se[0])}


def run(quick: bool = False) -> list[dict]:
    from scipy.stats import binom

    _setup()
    seeds, duration = (range(4), 30.0) if quick else (range(20), 60.0)
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        c = coverage(list(seeds), duration, Path(tmp))
    lo, hi = binom.ppf(0.001, c["n"], 0.95), binom.ppf(0.999, c["n"], 0.95)
    where = f"{c['n']} sessions of {duration:g} s, {PRESET}, truth {c['truth']:g} N m/rad"
    band = f"a correct 95 % interval: {lo:g}-{hi:g} of {c['n']} (99.8 %)"
    name = "rigid-body stderr coverage"
    return [
        {"benchmark": name, "metric": "block jackknife 95 % intervals covering the truth",
         "value": c["hits"] / c["n"], "unit": "fraction", "note": f"{where}; {band}; load {load:.1f}"},
        {"benchmark": name, "metric": "least-squares covariance 95 % intervals covering the truth",
         "value": c["naive_hits"] / c["n"], "unit": "fraction", "note": where},
        {"benchmark": name, "metric": "stiffness mean (sd over sessions)", "value": float(c["values"].mean()),
         "unit": "N m/rad", "note": f"sd {c['values'].std(ddof=1):.3g}; mean stated stderr "
                                    f"{c['stderr'].mean():.3g} (least squares {c['naive'].mean():.3g})"},
        {"benchmark": name, "metric": "stated stderr with a third of the session repeated / without",
         "value": c["repeat_ratio"], "unit": "ratio", "note": "repeated samples join their first block"},
    ]


if __name__ == "__main__":
    for row in run("--quick" in sys.argv):
        print(f"{row['metric']:<60} {row['value']:<10.4g} {row['unit']:<10} {row['note']}")
