"""Discover the missing term (`crane-train diagnose --discover`, train/diagnosis/discovery.py).

Four effects whose form the effects library lacks are planted, each hidden on a stated joint of the
baseline plant (tests/fakes/planted-*.toml, effects as data in tests/fakes/planted_effects.json): a
friction whose level changes with the angle (joint2), joint2's velocity dragging joint4 (a coupling), a
drag growing with the square of the velocity (joint4) and a damping that changes with the angle (joint1).
For each:
a 60 s simulated session (tests/planted.py), the baseline rigid-body model with the plant's [known]
effects, then `diagnose --discover --json --write-effect-file`: the joint gets a significant expression
of the right structure and no other joint gets one, and refitting with the written effect file cuts
that joint's held-out MSE (`compare`, samples where it moves) by at least half. The baseline plant
(nothing hidden) gets no significant discovery; a planted library effect (Coulomb on joint2) is named by
the ranking, and discovery does not contradict it.

CRANE_PLANTED_SEED=N runs the file with another seed.
"""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import crane_io.physics.effects as fx
from crane_io.sim.plant_config import load_plant_config
from tests.fitting import fit_model
from tests.planted import simulate_session
from train.cli import main
from train.evaluation.compare import compare_models

DURATION_S = 60.0
SEED = int(os.environ.get("CRANE_PLANTED_SEED", "0"))
FAKES = Path(__file__).parent / "fakes"


def _leading(entry) -> dict:
    return entry["terms"][0]  # terms are ordered by their share of the fitted torque


def _angle_friction(entry):  # sign(dq2) or tanh(dq2/v) times a function of q2
    t = _leading(entry)
    sign, _, angle = t["term"].partition("·")
    return t["family"] == "velocity sign x angle" and "dq2" in sign and "q2" in angle


def _cross_velocity(entry):  # joint2's velocity acting on joint4
    return _leading(entry)["term"] in ("dq2", "tanh(dq2/0.25)")


def _quadratic_drag(entry):  # faster than linear in joint4's own velocity
    return _leading(entry)["term"] in ("|dq4|·dq4", "dq4³")


def _angle_damping(entry):  # joint1's velocity times a function of its angle
    t = _leading(entry)
    return t["family"] == "velocity x angle" and t["term"].startswith("dq1·")


CASES = {  # plant file -> (joint, structure check)
    "planted-angle-friction": ("joint2", _angle_friction),
    "planted-cross-velocity": ("joint4", _cross_velocity),
    "planted-quadratic-drag": ("joint4", _quadratic_drag),
    "planted-angle-damping": ("joint1", _angle_damping),
}


@contextlib.contextmanager
def _own_registry():
    """User effects registered inside (the planted ones, the written ones) leave the library after."""
    saved = dict(fx._REGISTRY)
    try:
        yield
    finally:
        fx._REGISTRY.clear()
        fx._REGISTRY.update(saved)


def _plant(preset: str) -> str:
    path = FAKES / f"{preset}.toml"
    return str(path) if path.exists() else preset


@pytest.fixture(scope="module")
def planted(tmp_path_factory):
    """preset -> (session, baseline model dir, known effects); simulated and fitted once per preset."""
    root = tmp_path_factory.mktemp("discovery")
    cache = {}

    def get(preset):
        if preset not in cache:
            with _own_registry():
                config = load_plant_config(_plant(preset))
                session = simulate_session(root / f"{preset}.h5", _plant(preset), DURATION_S, seed=SEED)
            known = list(config.known)
            base = root / f"{preset}-baseline"
            fit_model([str(session)], "rigid-body", base, seed=SEED, effects=known, scale_to_data=True,
                      progress=False)
            cache[preset] = (session, base, known)
        return cache[preset]

    return get


def _discover(base, session, *extra):
    r = CliRunner().invoke(main, ["diagnose", str(base), str(session), "--discover", "--json", *extra])
    assert r.exit_code == 0, r.output
    return json.loads(r.output)


@pytest.mark.parametrize("preset", list(CASES))
def test_discovery_finds_the_planted_term_and_its_effect_file_halves_the_error(preset, planted, tmp_path):
    session, base, known = planted(preset)
    joint, right_structure = CASES[preset]
    out = tmp_path / "discovered.json"
    doc = _discover(base, session, "--write-effect-file", str(out))
    found = {d["joint"]: d for d in doc["discovered"]}
    entry = found[joint]
    assert entry["significant"] and entry["error_reduction"] > 0.2, entry
    assert right_structure(entry), entry
    for t in entry["terms"]:
        assert set(t) >= {"term", "coefficient", "stderr"} and t["stderr"] > 0
    assert entry["expression"] and isinstance(entry["expression"], str)
    for other, d in found.items():
        if other != joint:
            assert not d["significant"], d
    assert doc["effect_file"] == str(out)
    written = json.loads(out.read_text())  # effects as data
    (spec,) = written["effects"]
    assert spec["name"].startswith(f"{joint}-") and entry["expression"] in spec["description"]
    assert [t["parameter"] for t in spec["terms"]] == [t["parameter"] for t in entry["terms"]]
    assert [t["value"] for t in spec["terms"]] == [t["coefficient"] for t in entry["terms"]]
    effects = known + [(spec["name"], joint, None)]
    if entry["on_top_of"]:
        effects.append((entry["on_top_of"], joint, None))
    fixed = tmp_path / "with-discovered"
    with _own_registry():
        fit_model([str(session)], "rigid-body", fixed, seed=SEED, effects=effects, effect_files=[str(out)],
                  scale_to_data=True, progress=False)
        scores = compare_models([base, fixed], [session])
    before, after = (m.moving_mse[joint] for m in scores.models)
    assert after <= 0.5 * before, (before, after)


def test_nothing_hidden_gives_no_significant_discovery(planted, tmp_path):
    session, base, _ = planted("baseline")
    out = tmp_path / "nothing.json"
    doc = _discover(base, session, "--write-effect-file", str(out), "--discover-all")
    assert [d["joint"] for d in doc["discovered"]] == doc["joints"]
    assert not any(d["significant"] for d in doc["discovered"]), doc["discovery"]["summary"]
    assert doc["effect_file"] is None and not out.exists()
    r = CliRunner().invoke(main, ["diagnose", str(base), str(session), "--discover"])
    assert r.exit_code == 0, r.output
    assert "No significant discovery on any joint" in r.output and "Discovery:" in r.output
    r = CliRunner().invoke(main, ["diagnose", str(base), str(session), "--write-effect-file",
                                  str(tmp_path / "terms.txt")])  # refused before any work
    assert r.exit_code != 0 and "Error: " in r.output and ".json" in r.output and "Traceback" not in r.output


def test_a_library_effect_is_named_by_the_ranking_and_discovery_agrees(planted):
    session, base, _ = planted("hidden-coulomb")
    doc = _discover(base, session)
    best = [c for c in doc["candidates"] if c["joint"] == "joint2"][0]
    assert best["effect"] == "coulomb" and best["significant"]
    found = {d["joint"]: d for d in doc["discovered"]}
    # on top of the ranking's Coulomb friction nothing significant is left, anywhere
    assert found["joint2"]["on_top_of"] == "coulomb"
    assert not any(d["significant"] for d in doc["discovered"]), doc["discovery"]["summary"]
    # from the model alone, discovery names the same thing: a velocity-sign term of about 0.25 N m
    alone = {d["joint"]: d for d in _discover(base, session, "--discover-all")["discovered"]}
    lead = _leading(alone["joint2"])
    assert alone["joint2"]["significant"] and alone["joint2"]["on_top_of"] is None
    assert lead["family"] == "velocity sign" and lead["term"].startswith(("sign(dq2)", "tanh(dq2"))
    assert lead["coefficient"] == pytest.approx(0.25, abs=0.05)
    assert not alone["joint1"]["significant"] and not alone["joint4"]["significant"]


def test_residual_discovery_on_synthetic_data_and_quiet_on_noise():
    """The residual path (a model that is not linear in parameters): terms fitted to its residual."""
    from train.data.dataset import Dataset
    from train.diagnosis.discovery import discover

    rng = np.random.default_rng(SEED)
    n = 3000
    t = np.arange(n) / 50
    q = np.stack([0.5 * np.sin(0.4 * t * (j + 1) + j) + 0.3 * np.sin(1.3 * t * (j + 0.7)) + 0.3
                  for j in range(3)], 1)  # two incommensurate tones: angle and velocity vary independently
    dq = np.gradient(q, t, axis=0)
    ddq = np.gradient(dq, t, axis=0)
    ds = Dataset(("joint1", "joint2", "joint4"), t, q, dq, ddq, np.zeros((n, 3)), np.abs(dq) > 0.05, 50.0)

    class Residual:  # predicts tau minus a given residual; no regressor (like a network)
        def __init__(self, residual):
            self.residual = residual

        def predict(self, q, dq, ddq):
            return ds.tau - self.residual

    noise = rng.normal(0, 0.05, (n, 3))
    quiet = discover(Residual(noise), ds)
    assert not any(d.significant for d in quiet.discovered), quiet.summary
    planted = noise.copy()
    planted[:, 1] += 0.2 * np.sign(dq[:, 1]) * (1 + 0.8 * np.cos(2 * q[:, 1]))
    loud = discover(Residual(planted), ds)
    d = loud.for_joint("joint2")
    assert d.significant and d.error_reduction > 0.5, d.sentence
    assert any(t.family == "velocity sign x angle" and "q2" in t.term.partition("·")[2] for t in d.terms)
    # the expression found reproduces the planted torque (cos(q2) and cos(2·q2) may stand in for each
    # other over joint2's range)
    from train.diagnosis.discovery_basis import Term, evaluate

    fit = sum(t.coefficient * evaluate(Term(t.term, t.expr, t.unit, t.family, frozenset()), q, dq, ddq)
              for t in d.terms)
    truth = planted[:, 1] - noise[:, 1]
    rows = ds.moving[:, 1]
    assert np.sqrt(np.mean((fit - truth)[rows] ** 2)) < 0.1 * np.sqrt(np.mean(truth[rows] ** 2))
    assert all(t.stderr > 0 for t in d.terms)
    assert not loud.for_joint("joint1").significant and not loud.for_joint("joint4").significant
    assert json.dumps(loud.to_json())  # plain data
    from train.evaluation.report import discovery_section

    page = discovery_section(loud)  # the report page's section: sentences, terms, the fit's figure
    assert page.count("<img") == 1 and "data:image/png;base64," in page and "https://" not in page
    # the effect-spec file records the flag that found the terms
    from train.diagnosis.effect_writer import effect_document

    assert effect_document(loud, "m", ["m.h5"])["found_by"] == {
        "command": "crane-train diagnose", "model": "m", "sessions": ["m.h5"], "flag": "--discover"}
    every = discover(Residual(planted), ds, every_joint=True)
    assert effect_document(every, "m", ["m.h5"])["found_by"]["flag"] == "--discover-all"



def test_expression_is_readable_and_factored_when_it_can_be():
    from train.diagnosis.discovery import FoundTerm, expression

    terms = [FoundTerm("sign(dq2)", 0.21, 0.01), FoundTerm("sign(dq2)·cos(2·q2)", 0.168, 0.01)]
    assert expression(terms) == "0.21·sign(dq2)·(1 + 0.8·cos(2·q2))"
    assert expression([FoundTerm("dq2", 0.116, 0.003), FoundTerm("|dq4|·dq4", -0.05, 0.01)]) == (
        "0.116·dq2 - 0.05·|dq4|·dq4")
    assert expression([]) == ""
