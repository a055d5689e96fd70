"""The ranking of `crane-train diagnose` must not mislead.

Each test fails without its fix:
- a shape parameter between the points of its grid (a spring relaxed at -1.2 rad; the grid has -1.25
  and -1.0) is refined, with an uncertainty that is not "± 0", and what the grid pick of a fitted model
  leaves behind (k x 0.2 rad of constant torque) is not found as a "torque offset";
- with two effects planted, exactly those two are significant (nested forward selection, not every
  candidate against the same baseline: stiction and asymmetric Coulomb contain Coulomb);
- a payload against a full rigid-body model (whose base parameters absorb it) is reported as not
  identifiable, with no value, in the JSON and in the text;
- a residual shaped like sign(velocity) x cos(2 angle) has no linear correlation with the angle; the
  summary names the velocity's sign together with the angle.
(The hybrid's share of its network is tested in tests/test_hybrid.py.)

Sessions: tests/planted.py (the real ArmPlant driven like a follower, 60 simulated seconds, seeded).
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from click.testing import CliRunner

from crane_io.physics.effects import get_effect
from crane_io.sim.plant_config import load_plant_config
from tests.fitting import fit_model
from tests.planted import simulate_session
from train.cli import main
from train.data.dataset import Dataset
from train.data.preprocess import preprocess
from train.data.session import read_sessions
from train.diagnosis.diagnose import diagnose, diagnose_residual
from train.evaluation.heldout import model_settings
from train.models.registry import load_model

SEED = int(os.environ.get("CRANE_PLANTED_SEED", "0"))


@pytest.fixture(scope="module")
def planted(tmp_path_factory):
    """preset, extra effects -> (session, model dir, model, dataset, diagnosis); cached per module."""
    root = tmp_path_factory.mktemp("ranking")
    cache = {}

    def get(preset, extra=(), tag="base"):
        key = (preset, tag)
        if key not in cache:
            session = root / f"{preset}.h5"
            if not session.exists():
                simulate_session(session, preset, 60.0, seed=SEED)
            out = root / f"{preset}-{tag}"
            fit_model([str(session)], "rigid-body", out, seed=SEED, scale_to_data=True, progress=False,
                      effects=list(load_plant_config(preset).known) + list(extra))
            model = load_model(out)
            ds = preprocess(read_sessions([session]), model_settings(model, out)[0])
            cache[key] = (session, out, model, ds, diagnose(model, ds))
        return cache[key]

    return get


def _significant(result):
    return {(c.effect, c.joint) for c in result.candidates if c.significant}


def test_a_spring_off_the_grid_is_refined_and_leaves_no_offset_behind(planted):
    truth = load_plant_config("hidden-spring-offgrid").hidden.values  # stiffness 0.4, rest -1.2 rad
    _, _, _, _, result = planted("hidden-spring-offgrid")
    best = result.best("joint1")
    assert best.effect == "spring" and best.significant, result.summary["joint1"]
    rest, stiff = best.parameters["rest_angle"], best.parameters["stiffness"]
    # refined between the grid's -1.25 and -1.0, with an uncertainty that includes the refinement
    assert rest["value"] == pytest.approx(truth["rest_angle"], abs=0.05), rest
    assert 0 < rest["std"] < 0.05, rest
    assert stiff["value"] == pytest.approx(truth["stiffness"], abs=0.03) and stiff["std"] > 0
    assert best.shape["rest_angle"] not in get_effect("spring").shape_grid["rest_angle"]

    # the spring added the way a user adds it (`fit` picks its rest angle from the grid: -1.0 here,
    # leaving 0.4 x 0.2 = 0.08 N m of constant torque): that leftover is not "a torque offset"
    _, _, model, _, after = planted("hidden-spring-offgrid", [("spring", "joint1", None)], "spring")
    picked = model.terms[-1]["shape"]["rest_angle"]
    assert picked != pytest.approx(truth["rest_angle"], abs=0.02)  # the case: an off-grid truth
    assert not any(c.significant for c in after.for_joint("joint1")), after.summary["joint1"]
    offset = next(c for c in after.for_joint("joint1") if c.effect == "offset")
    assert not offset.significant and offset.error_reduction < 0.15
    # ... it is reported for what it is: the model's own rest angle, refined, and how to refit
    ref = next(r for r in after.refinements if r["effect"] == "spring")
    assert ref["joint"] == "joint1" and ref["parameter"] == "rest_angle" and ref["model_value"] == picked
    assert ref["value"] == pytest.approx(truth["rest_angle"], abs=0.05) and ref["std"] > 0
    if abs(picked - truth["rest_angle"]) >= 0.1:  # seed 0: -1.0 picked, 0.08 N m left: 83 % of the error
        assert ref["significant"] and "rest_angle=" in after.summary["joint1"]

    # refitted with the refined rest angle: nothing significant left on joint1, no refinement either
    refined = [("spring", "joint1", {"rest_angle": round(ref["value"], 3)})]
    _, _, _, _, final = planted("hidden-spring-offgrid", refined, "refined")
    assert not any(c.significant for c in final.for_joint("joint1")), final.summary["joint1"]
    assert not any(r["significant"] for r in final.refinements), final.refinements


def test_two_planted_effects_are_named_and_nothing_else(planted):
    """hidden-two: joint2's Coulomb friction and joint4's ripple. Stiction, asymmetric Coulomb and
    Stribeck each explain ~90 % of joint2's error on their own (they contain or mimic Coulomb); once
    Coulomb is in the model they explain nothing more."""
    _, _, _, _, result = planted("hidden-two")
    assert _significant(result) == {("coulomb", "joint2"), ("cogging", "joint4")}, result.summary
    assert result.selected[0] == "coulomb on joint2" and set(result.selected) == {"coulomb on joint2",
                                                                                   "cogging on joint4"}
    lookalikes = [c for c in result.for_joint("joint2") if c.effect in ("stiction", "coulomb-asym")]
    assert lookalikes and all(c.error_reduction > 0.5 for c in lookalikes)  # alone they look like finds
    for c in lookalikes:
        assert not c.significant and c.explained_by == "coulomb on joint2"
        assert c.reduction_given_leader < 0.15 and "diagnose again" in c.sentence
    assert "Also significant" not in result.summary["joint2"]
    cog = result.best("joint4")
    assert cog.effect == "cogging" and cog.selection_step == 2 and cog.given == ["coulomb on joint2"]
    assert cog.reduction_given_leader > 0.5
    assert not any(c.significant for c in result.for_joint("joint1")), result.summary["joint1"]


def test_a_payload_on_a_full_rigid_body_model_is_reported_unidentifiable(planted):
    """A point mass at the tool only changes the last body's inertial parameters, which a fitted
    rigid-body model estimates: any payload mass fits as well, so no mass may be printed."""
    session, base, _, _, result = planted("hidden-payload")
    payload = next(c for c in result.candidates if c.effect == "payload")
    assert not payload.identifiable and not payload.significant
    assert payload.parameters == {} and payload.unidentifiable_parameters == ["mass"]
    assert "cannot be identified" in payload.sentence
    assert "payload" in result.summary[payload.joint] and "Not identifiable" in result.summary[payload.joint]
    runner = CliRunner()
    r = runner.invoke(main, ["diagnose", str(base), str(session), "--json"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    entry = next(c for c in doc["candidates"] if c["effect"] == "payload")
    assert entry["identifiable"] is False and entry["parameters"] == {}
    r = runner.invoke(main, ["diagnose", str(base), str(session), "--top", "20"])
    assert r.exit_code == 0, r.output
    assert "Not identifiable from this model" in r.output and "payload at the tool" in r.output
    line = next(x for x in r.output.splitlines() if " payload " in x)
    assert "kg" not in line  # no mass printed


def _multisine_data(n=6000, rate=50.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    f = np.array([[0.21, 0.53, 0.87], [0.17, 0.61, 0.97], [0.29, 0.47, 0.79]])
    ph = rng.uniform(0, 2 * np.pi, (3, 3))
    q = np.stack([sum(0.45 * np.sin(f[j, i] * t + ph[j, i]) for i in range(3)) for j in range(3)], 1)
    dq = np.gradient(q, t, axis=0)
    ddq = np.gradient(dq, t, axis=0)
    moving = np.abs(dq) > 0.05
    ds = Dataset(("joint1", "joint2", "joint4"), t, q, dq, ddq, np.zeros((n, 3)), moving, rate)
    return ds, rng


@pytest.mark.parametrize("centred", [True, False])
def test_a_velocity_sign_times_angle_residual_names_both(centred):
    """0.2 sign(dq2) cos(2 q2): no linear correlation with the angle. Centred (its Coulomb part removed)
    nothing in the library explains it; uncentred, Coulomb explains its mean level and the rest keeps
    the shape. Either way the summary names the sign of velocity together with the angle."""
    ds, rng = _multisine_data()
    shape = np.cos(2 * ds.q[:, 1])
    if centred:
        shape = shape - shape[ds.moving[:, 1]].mean()
    residual = rng.normal(0, 0.03, ds.tau.shape)
    residual[:, 1] += 0.2 * np.sign(ds.dq[:, 1]) * shape
    rows = ds.moving[:, 1]
    assert abs(np.corrcoef(residual[rows, 1], ds.q[rows, 1])[0, 1]) < 0.1  # invisible to Pearson
    effects = [get_effect(n) for n in ("coulomb", "viscous", "offset", "spring", "stribeck")]
    result = diagnose_residual(ds, residual, effects=effects)
    text = result.summary["joint2"]
    assert "sign of velocity of joint2 together with the angle of joint2" in text, text
    if centred:
        assert not any(c.significant for c in result.for_joint("joint2")), text
    else:
        assert result.best("joint2").effect == "coulomb" and "Once coulomb is in the model" in text
    top = result.dependence["joint2"][0]
    assert top["with"] == "sign of velocity of joint2 together with the angle of joint2"
    assert top["share"] > 0.5
    assert "looks like noise" in result.summary["joint1"]  # noise stays noise
