"""The discovery battery: does `crane-train diagnose --discover-all` find what is planted, and only that?

Sessions come from the simulated arm (tests/planted.py: crane_io.sim.arm_plant driven at 500 Hz by an
operator-like minimum-jerk hand on joints 1, 2 and 4, recorded as crane-collect records). Per case, a
training session and an independent test session (another seed) are simulated; the baseline rigid-body
model is fitted with the plant's known effects; `crane-train diagnose MODEL TRAIN --discover-all --json
--write-effect-file F.json` runs; when it writes a file, the model is refitted with it and scored on the
whole test session (every sample where each joint moves: the session is independent, so all of it is
held out), with the baseline model and with the model fitted with the planted effect's true form (the
noise floor) beside it. `compare` on that session would score only its split's held-out rows (about 7 s
of a 60 s session), too few to tell two good models apart.

Cases:
  angle-friction-4th  tests/fakes/planted-angle-friction-4th.toml: friction 0.25 (1 + 1.5 sin^2 2 q1)
                      sign(dq1) on joint1 (the operator's hand moves joint1 within +-1.3 rad). Pass: joint1's
                      discovery has a term in cos(4·q1) (the 4th harmonic), no other joint claims anything,
                      and the refitted model's test error on every joint is within 1.3x of the noise floor
                      (the model fitted with the planted effect's true form).
  baseline            crane_io/sim/plants/baseline.toml, nothing hidden. Pass: no claim, no file.
  barely-moving       baseline, the hand moving joint4 within +-0.085 rad (0.17 rad at most). Pass: no
                      claim, no file; the refused periodic terms are said.

    .venv/bin/python benchmarks/bench_discovery.py                # 60 s sessions, seeds 0 and 1
    .venv/bin/python benchmarks/bench_discovery.py --seeds 0-5    # 60 s sessions, seeds 0 to 5
    .venv/bin/python benchmarks/bench_discovery.py --quick        # 30 s sessions, seed 0
"""

from __future__ import annotations

import contextlib
import json
import sys
import tempfile
from pathlib import Path
from unittest import mock

ROOT = Path(__file__).resolve().parents[1]
FAKES = ROOT / "tests" / "fakes"
CASES = {  # name -> (plant, hand span overrides (rad), planted joint or None)
    "angle-friction-4th": (str(FAKES / "planted-angle-friction-4th.toml"), {"joint1": 1.3}, "joint1"),
    "baseline": ("baseline", {}, None),
    "barely-moving": ("baseline", {"joint4": 0.085}, None),
}
PLANTED_EFFECT = "angle-friction-4th-planted"
FLOOR_FACTOR = 1.3


@contextlib.contextmanager
def _own_registry():
    import crane_io.physics.effects as fx

    saved = dict(fx._REGISTRY)
    try:
        yield
    finally:
        fx._REGISTRY.clear()
        fx._REGISTRY.update(saved)


def simulate(path: Path, plant: str, spans: dict, duration: float, seed: int) -> Path:
    """A simulated session with the operator's hand moving the named joints within +-span of their centre."""
    sys.path.insert(0, str(ROOT))
    import tests.planted as planted

    with mock.patch.dict(planted.SPAN, spans):
        return planted.simulate_session(path, plant, duration, seed=seed)


def _fit(sessions, out, known, effect_files=(), seed=0):
    import train

    train.fit([str(s) for s in sessions], "rigid-body", effects=list(known), effect_files=list(effect_files),
              scale_to_data=True, seed=seed).save(out)
    return out


def moving_mse(model_dirs, session: Path) -> list[dict]:
    """Per model, joint -> MSE on every sample of `session` where the joint moves (each model reads the
    session with its own preprocessing)."""
    from train.data.preprocess import read_preprocessed
    from train.evaluation.heldout import model_settings
    from train.models.registry import load_model

    out = []
    for d in model_dirs:
        model = load_model(d)
        ds = read_preprocessed([session], model_settings(model, d)[0])
        err = (ds.tau - model.predict_dataset(ds)) ** 2
        out.append({n: float(err[ds.moving[:, j], j].mean()) for j, n in enumerate(ds.joint_names)})
    return out


def run_case(name: str, root: Path, duration: float, seed: int) -> dict:
    """One case: its discovery document's verdicts and, when a file is written, the test errors."""
    from click.testing import CliRunner

    from crane_io.sim.plant_config import load_plant_config
    from train.cli import main

    plant, spans, joint = CASES[name]
    with _own_registry():
        known = list(load_plant_config(plant).known)
        train_s = simulate(root / f"{name}-{seed}-train.h5", plant, spans, duration, seed)
        test_s = simulate(root / f"{name}-{seed}-test.h5", plant, spans, duration, seed + 100)
        base = _fit([train_s], root / f"{name}-{seed}-base", known, seed=seed)
        out = root / f"{name}-{seed}-found.json"
        r = CliRunner().invoke(main, ["diagnose", str(base), str(train_s), "--discover-all", "--json",
                                      "--write-effect-file", str(out)])
        if r.exit_code != 0:
            raise RuntimeError(r.output)
        doc = json.loads(r.output)
        found = {d["joint"]: d for d in doc["discovered"]}
        claims = {j: d for j, d in found.items() if d["significant"]}
        row = {"case": name, "seed": seed, "claims": {j: d["expression"] for j, d in claims.items()},
               "file": doc["effect_file"], "summary": doc["discovery"]["summary"]}
        if doc["effect_file"]:
            written = json.loads(out.read_text())
            adds = [(e["name"], e["joint"], None) for e in written["effects"]]
            models = [base, _fit([train_s], root / f"{name}-{seed}-found", known + adds, [out], seed)]
            if joint is not None:
                truth = [(PLANTED_EFFECT, joint, None)]
                models.append(_fit([train_s], root / f"{name}-{seed}-truth", known + truth,
                                   [FAKES / "planted_discovery_effects.json"], seed))
            row["test_mse"] = moving_mse(models, test_s)
            row["found_vs_baseline"] = {j: row["test_mse"][1][j] / row["test_mse"][0][j]
                                        for j in row["test_mse"][0]}
    row["pass"] = _verdict(row, joint, found)
    return row


def _verdict(row: dict, joint: str | None, found: dict) -> bool:
    if joint is None:
        return not row["claims"] and row["file"] is None
    terms = [t["term"] for t in found[joint]["terms"]]
    if set(row["claims"]) != {joint} or not any("cos(4·q" in t for t in terms):
        return False
    base, fixed, truth = (m[joint] for m in row["test_mse"])
    row["ratio_to_floor"] = fixed / truth
    row["baseline_ratio_to_floor"] = base / truth
    row["floor_ratios"] = {k: row["test_mse"][1][k] / row["test_mse"][2][k] for k in row["test_mse"][0]}
    return all(r <= FLOOR_FACTOR for r in row["floor_ratios"].values())


def _ratios(d: dict) -> str:
    return ", ".join(f"{k} {v:.3g}" for k, v in d.items())


def run(quick: bool = False, seeds=None) -> list[dict]:
    duration, default = (30.0, (0,)) if quick else (60.0, (0, 1))
    seeds = default if seeds is None else seeds
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            for name in CASES:
                r = run_case(name, Path(tmp), duration, seed)
                note = "; ".join(f"{j}: {e}" for j, e in r["claims"].items()) or "no claim"
                if "ratio_to_floor" in r:
                    rows.append({"benchmark": "discovery", "value": r["ratio_to_floor"], "unit": "x",
                                 "metric": f"{name} s{seed} joint1 test MSE / floor",
                                 "note": f"baseline {r['baseline_ratio_to_floor']:.2f}x; every joint's "
                                         f"found/floor {_ratios(r['floor_ratios'])}, found/baseline "
                                         f"{_ratios(r['found_vs_baseline'])}; {note}"})
                rows.append({"benchmark": "discovery", "metric": f"{name} s{seed} pass",
                             "value": float(r["pass"]), "unit": "bool", "note": note})
                print(json.dumps(r, indent=1, default=str), file=sys.stderr, flush=True)
    return rows


def _seeds(argv: list[str]):
    """The seeds of `--seeds A-B` or `--seeds A,B,...` (None without the option)."""
    if "--seeds" not in argv:
        return None
    text = argv[argv.index("--seeds") + 1]
    if "-" in text:
        first, last = (int(x) for x in text.split("-"))
        return tuple(range(first, last + 1))
    return tuple(int(x) for x in text.split(","))


if __name__ == "__main__":
    quick = "--quick" in sys.argv[1:]
    for row in run(quick, _seeds(sys.argv[1:])):
        print(f"{row['metric']:<48} {row['value']:8.3f} {row['unit']:<5} {row['note']}")
