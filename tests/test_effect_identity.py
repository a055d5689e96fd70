"""An effect is what it computes, not its name: two effect files that both define `discovered-joint2`
with different terms give models that compare as different effects with their own numbers; `fit` given
both refuses in one sentence."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from tests.sessions import write_synthetic_session
from train.cli import main
from train.evaluation.compare import compare_models, table_text
from train.models.registry import load_model

NAME = "discovered-joint2"
ONE = [{"parameter": "c_sign", "factors": [["sign", 1]], "value": 0.1}]
TWO = [*ONE, {"parameter": "c_dq", "factors": [["dq", 1]], "value": 0.0}]  # another count of terms
OTHER_ONE = [{"parameter": "c_sign", "factors": [["tanh", 1, 0.05]], "value": 0.1}]  # same count


def _effect_file(path, terms):
    path.write_text(json.dumps({"format": "crane-effects", "format_version": 1, "effects": [
        {"kind": "terms", "name": NAME, "version": 1, "joint": "joint2",
         "joints": ["joint1", "joint2", "joint4"], "terms": terms}]}))
    return str(path)


def _run(*args):
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert "Traceback" not in result.output, result.output
    return result


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    d = tmp_path_factory.mktemp("identity")
    session, _ = write_synthetic_session(d / "s.h5", 60, seed=5)
    files = {key: _effect_file(d / f"{key}.json", terms)
             for key, terms in (("one", ONE), ("two", TWO), ("other", OTHER_ONE), ("one-again", ONE))}
    models = {}
    for key, file in files.items():
        out = d / f"m-{key}"
        r = _run("fit", session, "--model", "rigid-body", "--effect-file", file, "--effect",
                 f"{NAME}:joint=joint2", "-o", out, "--scale-to-data", "--no-progress")
        assert r.exit_code == 0, r.output
        models[key] = str(out)
    return d, session, files, models


def _scores(result):
    return {m.directory: m.test["mse"] for m in result.models}


def test_models_record_different_identities_for_one_name(lab):
    _, _, _, models = lab
    specs = {k: load_model(m).options["effect_specs"] for k, m in models.items()}
    ids = {k: s[0]["identity"] for k, s in specs.items()}
    assert all(s[0]["name"] == NAME for s in specs.values())
    assert ids["one"] == ids["one-again"] and len({ids["one"], ids["two"], ids["other"]}) == 3


@pytest.mark.parametrize("other", ["two", "other"])
def test_compare_tells_the_definitions_apart_with_each_model_its_own_numbers(lab, other):
    _, session, files, models = lab
    result = compare_models([models["one"], models[other]], [session])
    text = table_text(result)
    assert "same effects as 1" not in text and f"~{NAME}:joint=joint2 (another definition" in text
    swapped = compare_models([models[other], models["one"]], [session])
    for d, mse in _scores(result).items():  # each model scored on its own effect, whatever the order
        assert mse == pytest.approx(_scores(swapped)[d])
    a, b = (_scores(result)[models[k]]["joint2"] for k in ("one", other))
    assert a != b
    doc = result.to_json()["models"]
    assert doc[0]["effect_identities"] != doc[1]["effect_identities"]
    r = _run("compare", models["one"], models[other], "--session", session)
    assert r.exit_code == 0 and "another definition" in r.output


def test_the_same_definition_under_another_file_is_the_same_effect(lab):
    _, session, _, models = lab
    result = compare_models([models["one"], models["one-again"]], [session])
    assert "same effects as 1" in table_text(result)


def test_a_model_predicts_with_its_own_definition_whatever_the_library_holds(lab):
    from crane_io.physics.effects import load_effect_file
    from train.data.preprocess import read_preprocessed
    from train.evaluation.heldout import model_settings

    _, session, files, models = lab
    model = load_model(models["one"])
    ds = read_preprocessed([session], model_settings(model, models["one"])[0])
    before = model.predict_dataset(ds)
    load_effect_file(files["two"])  # the library's discovered-joint2 is now the two-term one
    after = load_model(models["one"]).predict_dataset(ds)
    assert np.array_equal(before, after)


def test_fit_refuses_two_definitions_of_one_name_in_one_sentence(lab, tmp_path):
    _, session, files, _ = lab
    for other in ("two", "other"):
        r = _run("fit", session, "--model", "rigid-body", "--effect-file", files["one"], "--effect-file",
                 files[other], "--effect", f"{NAME}:joint=joint2", "-o", tmp_path / other, "--scale-to-data")
        assert r.exit_code != 0 and r.output.count("\n") == 1
        assert f"both define the effect '{NAME}', differently" in r.output
        assert not (tmp_path / other).exists()
    r = _run("fit", session, "--model", "rigid-body", "--effect-file", files["one"], "--effect-file",
             files["one-again"], "--effect", f"{NAME}:joint=joint2", "-o", tmp_path / "same",
             "--scale-to-data", "--no-progress")
    assert r.exit_code == 0, r.output


def test_diagnose_takes_another_definition_of_a_model_effect_name_as_a_candidate(lab):
    from crane_io.physics.effects import get_effect, load_effect_file
    from train.data.preprocess import read_preprocessed
    from train.diagnosis.diagnose import diagnose
    from train.evaluation.heldout import model_settings

    _, session, files, models = lab
    model = load_model(models["one"])
    ds = read_preprocessed([session], model_settings(model, models["one"])[0])
    load_effect_file(files["one-again"])  # the model's own definition: already in the model on joint2
    own = diagnose(model, ds, effects=[get_effect(NAME)]).candidates
    assert {c.joint for c in own} == {"joint1", "joint4"}
    load_effect_file(files["two"])  # the same name, other terms: a candidate like any other
    found = diagnose(model, ds, effects=[get_effect(NAME)]).candidates
    assert {c.joint for c in found} == {"joint1", "joint2", "joint4"} and all(c.effect == NAME for c in found)
