"""Find the missing physics on simulated data with a planted (hidden) effect.

For six planted-effect presets of crane_io/sim/plants, each on the joint its preset names: a simulated
session with the effect hidden (tests/planted.py: the real ArmPlant driven like a follower under an
operator, 60 simulated seconds, seeded), a baseline rigid-body model fitted the way `crane-train fit`
does with the preset's [known] effects, then: the diagnosis ranks the hidden effect first on that joint
(and significant), and refitting with it added cuts that joint's held-out MSE by at least half: the
MSE `crane-train compare` reports on the held-out samples where that joint moves (its dead-zone mask,
as the per-joint error is defined everywhere else); the paper's test set (every joint moving, about 100
samples of a 60 s session) must fall by at least a third too. The `baseline` preset (nothing hidden)
gets no significant candidate on any joint.

CRANE_PLANTED_SEED=N runs the whole file with another seed (the cases were checked with seeds 0, 1, 2).
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from click.testing import CliRunner

from crane_io.sim.plant_config import load_plant_config
from tests.fitting import fit_model
from tests.planted import simulate_session
from train.cli import main
from train.data.preprocess import preprocess
from train.data.session import read_sessions
from train.diagnosis.diagnose import diagnose, diagnose_residual
from train.evaluation.compare import compare_models
from train.evaluation.heldout import model_settings
from train.models.registry import load_model

DURATION_S = 60.0
SEED = int(os.environ.get("CRANE_PLANTED_SEED", "0"))
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
    fixed = planted_dir / f"{preset}-fixed"
    after = _fit(session, fixed, known + [(hidden.effect, joint, None)])
    scores = compare_models([planted_dir / f"{preset}-baseline", fixed], [session])
    moving = [m.moving_mse[joint] for m in scores.models]
    assert moving[1] <= 0.5 * moving[0], moving
    assert after["test"]["mse"][joint] <= 0.67 * before["test"]["mse"][joint], (before["test"], after["test"])


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
    coulomb = first["parameters"]["coulomb"]
    assert {"value", "std", "unit", "ci95", "loop_value", "loop_std"} <= set(coulomb)
    # within 1 % of the plant's 0.25 on one session; whether the intervals cover it one time in twenty
    # is counted over seeds by benchmarks/bench_coverage.py (19 of 20)
    assert coulomb["unit"] == "N m" and abs(coulomb["value"] - 0.25) < 0.0025
    assert coulomb["ci95"][0] < coulomb["value"] < coulomb["ci95"][1]
    assert doc["settings"]["values_from"] == "zero-phase derivatives of the same samples"
    assert set(doc["summary"]) == {"joint1", "joint2", "joint4"}
    saved = tmp_path / "diag" / "diagnosis.json"
    r = runner.invoke(main, ["diagnose", str(base), str(session), "--json-out", str(saved)])
    assert r.exit_code == 0 and "Coulomb friction of about" in r.output  # the text, and the JSON saved
    assert json.loads(saved.read_text()) == doc
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
    session = _session_path(case, "hidden-coulomb")
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    r = CliRunner().invoke(main, ["diagnose", str(base), str(session), "--json-out", str(blocker / "d.json")])
    assert r.exit_code != 0 and r.output.startswith("Error: ") and "is a file, not a folder" in r.output
    assert blocker.read_text() == ""


def test_residual_diagnosis_names_a_planted_term_and_stays_quiet_on_noise():
    """The residual path (used for network models) on a synthetic residual: Coulomb on one joint."""
    from crane_io.physics.effects import get_effect
    from train.data.dataset import Dataset

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
    import crane_io.physics.effects as fx

    monkeypatch.setattr(fx, "_REGISTRY", dict(fx._REGISTRY))  # the user effect leaves with the test
    r = CliRunner().invoke(main, ["effects"])
    assert r.exit_code == 0
    for name in ("coulomb", "viscous", "stribeck", "spring", "payload", "rotor-inertia", "cogging", "offset"):
        assert f"{name}  —" in r.output
    assert "[N m]" in r.output and "{joint}" not in r.output
    user = tmp_path / "mine.py"
    user.write_text(
        "import numpy as np\n"
        "from crane_io.physics.effects.base import Effect, Param, joint_columns\n"
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


def test_no_progress_bar_when_stderr_is_not_a_terminal(case):
    """Text output of diagnose into a log: no tqdm bar on stderr (CliRunner's stderr is not a TTY)."""
    import io

    from train.progress import show_progress

    _, base, _, _, _ = case("hidden-coulomb")
    r = CliRunner().invoke(main, ["diagnose", str(base), str(_session_path(case, "hidden-coulomb"))])
    assert r.exit_code == 0, r.output
    assert "%|" not in r.stderr and "candidate/s" not in r.stderr and "\r" not in r.stderr

    class Tty(io.StringIO):
        def isatty(self):
            return True

    assert show_progress(True, Tty()) and not show_progress(False, Tty())
    assert not show_progress(True, io.StringIO())


def _session_path(case, preset):
    return case(preset)[0]


def test_a_network_is_diagnosed_only_on_samples_it_never_trained_on(case, planted_dir):
    """A physics model is refitted per fold (all samples are fair); a network keeps its weights, so its
    own pool and validation rows are left out of its diagnosis."""
    from train.data.splits import make_splits
    from train.evaluation.heldout import diagnosis_data

    session, base, _, _, _ = case("hidden-coulomb")
    rigid = load_model(base)
    ds = preprocess(read_sessions([session]), model_settings(rigid, base)[0])
    same, why = diagnosis_data(rigid, ds, base)
    assert len(same) == len(ds) and "all" in why
    net_dir = planted_dir / "hidden-coulomb-mlp"
    fit_model([str(session)], "mlp-masked", net_dir, seed=SEED, scale_to_data=True, epochs=2, progress=False)
    net = load_model(net_dir)
    judged, why = diagnosis_data(net, ds, net_dir)
    sp = make_splits(ds, model_settings(net, net_dir)[1], seed=SEED, scale_to_data=True)
    seen = set(sp.index["pool"].tolist()) | set(sp.index["val"].tolist())
    unseen = np.array([i for i in range(len(ds)) if i not in seen])
    assert len(judged) == len(unseen) < len(ds) and "neither trained nor validated" in why
    np.testing.assert_array_equal(judged.t, ds.t[unseen])
    r = CliRunner().invoke(main, ["diagnose", str(net_dir), str(session), "--json"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    assert doc["settings"]["samples"] == len(unseen) and "neither" in doc["settings"]["judged_on"]


def test_a_missing_effect_leaking_into_another_joint_is_not_blamed_there():
    """Spill-over: joint A's missing Coulomb friction bends a parameter A and B share; a candidate acting
    on B alone buys that back and looks significant on its own. Once A's Coulomb is in the model it
    explains nothing, so it is demoted (not significant, `explained_by` names the leader)."""
    from crane_io.physics.effects import get_effect
    from crane_io.physics.effects.base import Effect, Param, joint_columns
    from train.data.dataset import Dataset

    class CrossVelocity(Effect):  # test-only candidate: joint A's velocity acting on another joint
        name = "cross-velocity-test"
        title = "cross velocity"
        signature = "the residual of {joint} follows joint A's velocity"
        params = (Param("gain", "N m s/rad", 0.1, "torque per rad/s of joint A"),)

        def _columns(self, q, dq, ddq, joint, shape):
            return joint_columns(len(q), q.shape[1], joint, dq[:, 0])

    class SharedModel:  # a physics model with one parameter shared by both joints: tau_j = a dq_A
        method, options, theta = "rigid-body", {}, np.array([1.0])

        def linear_basis(self, q, dq, ddq):
            return np.repeat(dq[:, :1, None], 2, axis=1)

        def predict(self, q, dq, ddq):
            return self.linear_basis(q, dq, ddq) @ self.theta

    rng = np.random.default_rng(1)
    n = 3000
    t = np.arange(n) / 50
    q = np.stack([np.sin(0.5 * t), np.sin(0.3 * t + 1)], 1)
    dq = np.gradient(q, t, axis=0)
    ddq = np.gradient(dq, t, axis=0)
    tau = dq[:, :1] * np.ones((1, 2)) + rng.normal(0, 0.01, (n, 2))
    tau[:, 0] += 0.3 * np.sign(dq[:, 0])  # the missing effect, on joint A only
    ds = Dataset(("jointA", "jointB"), t, q, dq, ddq, tau, np.ones((n, 2), bool), 50.0)
    result = diagnose(SharedModel(), ds, effects=[get_effect("coulomb"), CrossVelocity()])
    lead = result.best("jointA")
    assert lead.effect == "coulomb" and lead.significant
    cross = [c for c in result.for_joint("jointB") if c.effect == "cross-velocity-test"][0]
    assert cross.error_reduction > 0.5  # on its own it looks like a find ...
    assert not cross.significant and cross.explained_by == "coulomb on jointA"  # ... but it is spill-over
    assert cross.reduction_given_leader < 0.15
    assert "coulomb on jointA" in result.summary["jointB"] and "diagnose again" in cross.sentence
