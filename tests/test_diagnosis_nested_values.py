"""The nested (forward) selection of `crane-train diagnose` reports each pick's parameters from the model with
all earlier picks in, in the JSON and in the text: viscous friction planted on three joints (and a heavier
rotor on joint4) against a model with Coulomb friction only. A later pick's value alone differs from its
value once the earlier picks are in; the reported one is the latter, the same value a diagnosis of the model
refitted with the earlier picks gives."""

from __future__ import annotations

import json

import pytest

from crane_io.physics.effects import get_effect
from tests.fitting import fit_model
from tests.planted import simulate_session
from train.data.preprocess import preprocess
from train.data.session import read_sessions
from train.diagnosis.diagnose import diagnose
from train.evaluation.heldout import model_settings
from train.models.registry import load_model

PLANT = """base = "baseline"
name = "viscous-three"
description = "Baseline with strong viscous friction on joints 1, 2, 4 and a heavier rotor on joint4."
""" + "".join(f"""
[[effects]]
effect = "{effect}"
joint = "{joint}"
{key} = {value}
""" for effect, joint, key, value in (("viscous", "joint1", "viscous", 0.25),
                                      ("viscous", "joint2", "viscous", 0.2),
                                      ("viscous", "joint4", "viscous", 0.15),
                                      ("rotor-inertia", "joint4", "inertia", 0.03)))
COULOMB = [("coulomb", j) for j in ("joint1", "joint2", "joint4")]


def _model(session, out, effects):
    fit_model([str(session)], "rigid-body", out, seed=0, scale_to_data=True, progress=False, effects=effects)
    model = load_model(out)
    return model, preprocess(read_sessions([session]), model_settings(model, out)[0])


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    root = tmp_path_factory.mktemp("nested")
    plant = root / "viscous-three.toml"
    plant.write_text(PLANT)
    session = simulate_session(root / "s.h5", str(plant), 30.0, seed=0)
    model, ds = _model(session, root / "coulomb", COULOMB)
    return root, session, ds, diagnose(model, ds)


def _picks(result):
    return sorted((c for c in result.candidates if c.selection_step), key=lambda c: c.selection_step)


def test_later_picks_report_their_values_with_the_earlier_picks_in(lab):
    root, session, _, result = lab
    picks = _picks(result)
    assert len(picks) >= 3, result.summary
    assert picks[0].parameters_alone is None  # the first pick joins the model alone: one set of values
    for c in picks[1:]:
        assert c.given == [f"{p.effect} on {p.joint}" for p in picks[:c.selection_step - 1]]
        assert c.parameters_alone is not None and set(c.parameters) == set(c.parameters_alone)
        assert any(c.parameters[n]["value"] != c.parameters_alone[n]["value"] for n in c.parameters)
    # the last pick: its reported value is what the model with the earlier picks gives it
    last = picks[-1]
    earlier = [(p.effect, p.joint) for p in picks[:-1]]
    refit, ds = _model(session, root / "with-earlier", COULOMB + earlier)
    alone_again = diagnose(refit, ds, effects=[get_effect(last.effect)])
    (same,) = [c for c in alone_again.candidates if c.joint == last.joint]
    for name, p in last.parameters.items():
        assert p["value"] == pytest.approx(same.parameters[name]["value"], rel=1e-6)
        assert abs(p["value"] - last.parameters_alone[name]["value"]) > 1e-6


def test_json_and_text_show_the_nested_values(lab, tmp_path):
    _, session, _, result = lab
    doc = result.to_json()
    picked = {(c["effect"], c["joint"]): c for c in doc["candidates"] if c["selection_step"]}
    for c in _picks(result)[1:]:
        entry = picked[(c.effect, c.joint)]
        assert entry["parameters"] == json.loads(json.dumps(c.parameters))
        assert entry["parameters_alone"] == json.loads(json.dumps(c.parameters_alone))
        value = next(iter(c.parameters.values()))["value"]
        assert f"about {value:.2g}" in c.sentence and "once" in c.sentence
        assert c.sentence in result.summary[c.joint]


def test_the_refinement_sentence_shows_the_model_value_and_the_command_value_alike():
    from train.diagnosis.text import refinement_sentence

    r = {"joint": "joint1", "effect": "spring", "parameter": "rest_angle", "unit": "rad",
         "model_value": -1.125, "value": -1.21437, "std": 0.0064, "error_reduction": 0.2}
    text = refinement_sentence(r)
    assert "rest_angle = -1.125 rad" in text  # the model's own value, not rounded to another one
    assert "refined to -1.214 ±" in text and "rest_angle=-1.214." in text
    r["model_value"] = 0.35
    assert "rest_angle = 0.35 rad" in refinement_sentence(r)
