"""Find the missing physics on simulated data with a planted (hidden) effect.

For six planted-effect presets of crane_io/plants, each on the joint its preset names: a simulated
session with the effect hidden (tests/planted.py: the real ArmPlant driven like a follower under an
operator, 60 simulated seconds, seeded), a baseline rigid-body model fitted the way `crane-train fit`
does with the preset's [known] effects, then: the diagnosis ranks the hidden effect first on that joint
(and significant), and refitting with it added cuts that joint's held-out (test) MSE by at least half.
The `baseline` preset (nothing hidden) gets no significant candidate on any joint.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from crane_io.plant_config import load_plant_config
from tests.planted import simulate_session
from train.cli import main
from train.cmd_fit import fit_model
from train.diagnose import diagnose, diagnose_residual
from train.heldout import model_settings
from train.models.registry import load_model
from train.preprocess import preprocess
from train.session import read_sessions

DURATION_S = 60.0
SEED = 0
PLANTED = ["hidden-coulomb", "hidden-viscous", "hidden-stribeck", "hidden-spring", "hidden-cogging",
           "hidden-offset"]


@pytest.fixture(scope="session")
def planted_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("planted")


def _session(planted_dir, preset):
    path = planted_dir / f"{preset}.h5"
    if not path.exists():
        simulate_session(path, preset, DURATION_S, seed=SEED)
    return path


def _fit(session, out, effects):
    return fit_model([str(session)], "rigid-body", out, seed=SEED, effects=effects, scale_to_data=True,
                     progress=False)


@pytest.fixture(scope="session")
def case(planted_dir):
    """preset -> (session, baseline model dir, baseline fit doc, diagnosis); computed once per preset."""
    cache = {}

    def get(preset):
        if preset not in cache:
            session = _session(planted_dir, preset)
            known = list(load_plant_config(preset).known)
            base = planted_dir / f"{preset}-baseline"
            doc = _fit(session, base, known)
            model = load_model(base)
            ds = preprocess(read_sessions([session]), model_settings(model, base)[0])
            cache[preset] = (session, base, doc, diagnose(model, ds), known)
        return cache[preset]

    return get


@pytest.mark.parametrize("preset", PLANTED)
def test_the_hidden_effect_is_named_first_and_adding_it_halves_the_error(preset, case, planted_dir):
    session, _, before, result, known = case(preset)
    hidden = load_plant_config(preset).hidden
    joint = hidden.joint
    best = result.best(joint)
    assert best is not None and best.effect == hidden.effect, result.summary[joint]
    assert best.rank == 1 and best.significant and best.error_reduction > 0.3
    assert best.sentence.startswith(f"{joint}: ")
    assert f"{100 * best.error_reduction:.0f}%" in result.summary[joint]
    # the estimate of the hidden effect's main (first) parameter has the right sign and an uncertainty
    first = next(iter(best.parameters.values()))
    truth = next(v for k, v in hidden.values.items() if k in best.parameters)
    assert np.sign(first["value"]) == np.sign(truth) and first["std"] >= 0
    # no other joint blames anything
    for other in result.joints:
        if other != joint:
            assert not any(c.significant for c in result.for_joint(other)), result.summary[other]
    after = _fit(session, planted_dir / f"{preset}-fixed", known + [(hidden.effect, joint, None)])
    assert after["test"]["mse"][joint] <= 0.5 * before["test"]["mse"][joint], (before["test"], after["test"])


def test_nothing_hidden_gives_no_significant_candidate(case):
    _, _, _, result, _ = case("baseline")
    assert not any(c.significant for c in result.candidates), [c.sentence for c in result.candidates[:5]]
    for joint in result.joints:
        assert "no candidate effect explains a significant part" in result.summary[joint]
        assert "residual" in result.summary[joint]  # what the residual correlates with (or that it does not)


def test_diagnose_cli_json_report_and_compare_end_to_end(case, planted_dir, tmp_path):
    """The walkthrough of docs/modelling.md through the command line, on the hidden-coulomb session."""
    session, base, _, _, known = case("hidden-coulomb")
    before = session.read_bytes()
    runner = CliRunner()
    r = runner.invoke(main, ["diagnose", str(base), str(session), "--json"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    first = [c for c in doc["candidates"] if c["joint"] == "joint2"][0]
    for key in ("joint", "rank", "effect", "error_reduction", "parameters", "significant", "sentence"):
        assert key in first
    assert first["effect"] == "coulomb" and first["rank"] == 1
    assert set(first["parameters"]["coulomb"]) == {"value", "std", "unit"}
    assert first["parameters"]["coulomb"]["unit"] == "N m"
    assert set(doc["summary"]) == {"joint1", "joint2", "joint4"}
    r = runner.invoke(main, ["diagnose", str(base), str(session)])
    assert r.exit_code == 0 and "Coulomb friction of about" in r.output
    fixed = tmp_path / "fixed"
    args = ["fit", str(session), "--model", "rigid-body", "-o", str(fixed), "--seed", str(SEED),
            "--scale-to-data", "--no-progress"]
    for name, joint, _ in known + [("coulomb", "joint2", None)]:
        args += ["--effect", f"{name}:joint={joint}"]
    r = runner.invoke(main, args)
    assert r.exit_code == 0, r.output
    r = runner.invoke(main, ["compare", str(base), str(fixed), "--json"])
    assert r.exit_code == 0, r.output
    cmp = json.loads(r.output)
    assert cmp["models"][1]["test"]["mse"]["joint2"] < 0.5 * cmp["models"][0]["test"]["mse"]["joint2"]
    report = tmp_path / "report.html"
    r = runner.invoke(main, ["report", str(base), str(session), "-o", str(report)])
    assert r.exit_code == 0, r.output
    page = report.read_text()
    assert "Coulomb friction" in page and "https://" not in page
    assert session.read_bytes() == before  # the input is never modified


def test_diagnose_bad_input_is_one_sentence(case, tmp_path):
    _, base, _, _, _ = case("hidden-coulomb")
    r = CliRunner().invoke(main, ["diagnose", str(base), str(tmp_path / "missing.h5")])
    assert r.exit_code != 0 and r.output.startswith("Error: ") and "Traceback" not in r.output
    r = CliRunner().invoke(main, ["diagnose", str(tmp_path), str(tmp_path / "missing.h5")])
    assert r.exit_code != 0 and r.output.startswith("Error: ")


def test_residual_diagnosis_names_a_planted_term_and_stays_quiet_on_noise():
    """The residual path (used for network models) on a synthetic residual: Coulomb on one joint."""
    from crane_io.effects import get_effect
    from train.dataset import Dataset

    rng = np.random.default_rng(0)
    n = 4000
    t = np.arange(n) / 50
    q = np.stack([np.sin(0.4 * t * (j + 1) + j) for j in range(3)], 1)
    dq = np.gradient(q, t, axis=0)
    ddq = np.gradient(dq, t, axis=0)
    ds = Dataset(("joint1", "joint2", "joint4"), t, q, dq, ddq, np.zeros((n, 3)), np.abs(dq) > 0.05, 50.0)
    noise = rng.normal(0, 0.05, (n, 3))
    quiet = diagnose_residual(ds, noise)
    assert not any(c.significant for c in quiet.candidates)
    planted = noise + get_effect("coulomb").torque(q, dq, ddq, 1, {"coulomb": 0.2})
    loud = diagnose_residual(ds, planted)
    best = loud.best("joint2")
    assert best.effect == "coulomb" and best.significant
    assert best.parameters["coulomb"]["value"] == pytest.approx(0.2, abs=3 * best.parameters["coulomb"]["std"]
                                                                + 0.01)


def test_effects_command_lists_the_library_with_units_and_signatures(tmp_path, monkeypatch):
    import crane_io.effects as fx

    monkeypatch.setattr(fx, "_REGISTRY", dict(fx._REGISTRY))  # the user effect leaves with the test
    r = CliRunner().invoke(main, ["effects"])
    assert r.exit_code == 0
    for name in ("coulomb", "viscous", "stribeck", "spring", "payload", "rotor-inertia", "cogging", "offset"):
        assert f"{name}  —" in r.output
    assert "[N m]" in r.output and "{joint}" not in r.output
    user = tmp_path / "mine.py"
    user.write_text(
        "import numpy as np\n"
        "from crane_io.effects.base import Effect, Param, joint_columns\n"
        "class Squeal(Effect):\n"
        "    name = 'squeal-test'\n"
        "    title = 'test squeal'\n"
        "    signature = 'the residual of {joint} squeals'\n"
        "    params = (Param('gain', 'N m s^2/rad^2', 0.1, 'squeal per (rad/s)^2'),)\n"
        "    def _columns(self, q, dq, ddq, joint, shape):\n"
        "        return joint_columns(len(q), q.shape[1], joint, dq[:, joint] * np.abs(dq[:, joint]))\n")
    r = CliRunner().invoke(main, ["effects", "--effect-file", str(user), "--json"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    mine = [e for e in doc["effects"] if e["name"] == "squeal-test"]
    assert mine and mine[0]["parameters"][0]["unit"] == "N m s^2/rad^2"
    r = CliRunner().invoke(main, ["effects", "--effect-file", str(tmp_path / "nope.py")])
    assert r.exit_code != 0 and r.output.startswith("Error: ")
