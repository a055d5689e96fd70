"""Saved models and plants carry their effects as data; loading never runs code.

- A model directory (model.json `effect_files`, loop_model.npz `rigid_effect_files`, or a recorded user
  effect whose file is not named) and a plant TOML (`effect_files`) that name a Python file whose running
  would create a marker file: every command that loads models or plants (compare, report, diagnose,
  export, crane-collect run --sim --model / --plant, the plant loader) exits 2 with one sentence and the
  marker is never created; a named file whose SHA-256 is not the recorded one is refused before it runs.
- A discovered effect written as an effect-spec file and read back computes the columns the discovery
  evaluated; text embedded in the file (a session name with quotes and newlines) stays data.
- Two discovered effects of one name and different terms: each model rebuilds its own from its recorded
  spec, and `compare` gives each its own numbers.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from collect.cli import main as collect_main
from crane_io.errors import ConfigError
from crane_io.physics.effects import effect_names, load_effect_file, spec
from crane_io.physics.loop_model import EXPORT_FILE
from crane_io.sim.plant_config import load_plant_config
from tests.fitting import fit_model
from tests.sessions import write_synthetic_session
from train.cli import main
from train.models.loop_export import npz_bytes

EVIL = "from pathlib import Path\nPath({marker!r}).write_text('ran')\n"


@pytest.fixture
def fresh(monkeypatch):
    """As in a new process: no user effect file has run, none is named; the library is restored after."""
    import crane_io.physics.effects as fx

    library = dict(fx._REGISTRY)
    monkeypatch.setattr(spec, "_SOURCE", dict(spec._SOURCE))

    def reset():
        monkeypatch.setattr(fx, "_REGISTRY", dict(library))
        monkeypatch.setattr(spec, "_RUN", {})
        monkeypatch.setattr(spec, "_OFFERED", {})
    reset()
    return reset


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    root = tmp_path_factory.mktemp("as_data")
    session, _ = write_synthetic_session(root / "s.h5", 40, seed=3)
    model = root / "m"
    fit_model([str(session)], "rigid-body", model, effects=["coulomb:joint=joint2"], scale_to_data=True)
    return session, model


def _evil(tmp_path) -> tuple[Path, Path]:
    marker = tmp_path / "marker"
    evil = tmp_path / "evil.py"
    evil.write_text(EVIL.format(marker=str(marker)))
    return evil, marker


def _rewrite(model: Path, options=None, export=None) -> None:
    """Change model.json's options and the export's arrays in place, keeping them consistent."""
    doc = json.loads((model / "model.json").read_text())
    if options:
        options(doc["options"])
    if export:
        with np.load(model / EXPORT_FILE) as z:
            arrays = {k: z[k] for k in z.files}
        export(arrays)
        raw = npz_bytes(arrays)
        (model / EXPORT_FILE).write_bytes(raw)
        doc["loop_export"]["sha256"] = hashlib.sha256(raw).hexdigest()
    (model / "model.json").write_text(json.dumps(doc))


def _old_style(model: Path, evil: Path) -> None:
    """A model directory as older versions wrote it: Python effect files to load."""
    def options(o):
        o["effect_files"] = [str(evil)]

    def export(a):
        a.pop("rigid_effect_specs")
        a["rigid_effect_files"] = np.array([str(evil)])
    _rewrite(model, options, export)


def _user_spec(model: Path, evil: Path) -> None:
    """A model that records a user effect defined in `evil` (its SHA-256 the file's)."""
    user = spec.with_identity({"kind": "user", "name": "evil-effect", "file": str(evil),
                               "sha256": hashlib.sha256(evil.read_bytes()).hexdigest()})

    def options(o):
        o["effect_specs"].append(user)

    def export(a):
        a["rigid_effect_specs"] = np.array(json.dumps(json.loads(str(a["rigid_effect_specs"])) + [user]))
    _rewrite(model, options, export)


COMMANDS = {
    "compare": lambda m, s, out: ["compare", m, "--session", s],
    "report": lambda m, s, out: ["report", m, s, "-o", out / "r.html"],
    "diagnose": lambda m, s, out: ["diagnose", m, s],
    "export": lambda m, s, out: ["export", m],
}


@pytest.mark.parametrize("style", [_old_style, _user_spec], ids=["effect_files", "unnamed-user-effect"])
@pytest.mark.parametrize("command", list(COMMANDS))
def test_loading_a_model_that_names_a_python_file_runs_nothing(fitted, tmp_path, fresh, command, style):
    session, model = fitted
    evil, marker = _evil(tmp_path)
    copy = tmp_path / "m"
    shutil.copytree(model, copy)
    style(copy, evil)
    r = CliRunner().invoke(main, [str(a) for a in COMMANDS[command](copy, session, tmp_path)])
    assert r.exit_code == 2, r.output
    error = r.stderr.splitlines()[-1]  # (report says first what it evaluates)
    assert error.startswith("Error: ") and r.stderr.count("Error") == 1 and "evil.py" in error, r.output
    assert "Traceback" not in r.output and not marker.exists()
    assert not (tmp_path / "r.html").exists()


@pytest.mark.parametrize("style", [_old_style, _user_spec], ids=["effect_files", "unnamed-user-effect"])
def test_the_control_loop_refuses_a_model_that_names_a_python_file_and_runs_nothing(
        fitted, tmp_path, fresh, style):
    _, model = fitted
    evil, marker = _evil(tmp_path)
    copy = tmp_path / "m"
    shutil.copytree(model, copy)
    style(copy, evil)
    out = tmp_path / "run.h5"
    r = CliRunner().invoke(collect_main, ["run", "--sim", "--duration", "1", "-o", str(out),
                                          "--model", str(copy)])
    assert r.exit_code == 2, r.output
    assert r.stderr.startswith("Error:") and r.stderr.count("\n") == 1 and "evil.py" in r.stderr, r.stderr
    assert not marker.exists() and not out.exists()


def test_a_plant_that_names_python_effect_files_is_refused_and_runs_nothing(tmp_path, fresh):
    evil, marker = _evil(tmp_path)
    plant = tmp_path / "p.toml"
    plant.write_text(f'base = "baseline"\neffect_files = ["{evil}"]\n')
    with pytest.raises(ConfigError, match=r"effect_files.*evil\.py.*never runs") as info:
        load_plant_config(plant)
    assert "\n" not in str(info.value)
    out = tmp_path / "run.h5"
    r = CliRunner().invoke(collect_main, ["run", "--sim", "--duration", "1", "-o", str(out),
                                          "--plant", str(plant)])
    assert r.exit_code == 2 and r.stderr.startswith("Error:") and r.stderr.count("\n") == 1, r.stderr
    assert not marker.exists() and not out.exists()


def test_a_named_python_effect_file_runs_only_with_the_recorded_sha256(fitted, tmp_path, fresh):
    session, model = fitted
    source = tmp_path / "drag.py"
    marker = tmp_path / "drag.ran"
    source.write_text(
        "from pathlib import Path\n"
        "from crane_io.physics.effects import Effect, Param\n"
        "from crane_io.physics.effects.base import joint_columns\n"
        f"Path({str(marker)!r}).write_text('ran')\n\n"
        "class Drag(Effect):\n"
        "    name = 'as-data-test-drag'\n"
        "    params = (Param('c', 'N m s^3/rad^3', 0.01, 'cubic drag'),)\n\n"
        "    def _columns(self, q, dq, ddq, joint, shape):\n"
        "        return joint_columns(len(q), q.shape[1], joint, dq[:, joint] ** 3)\n")
    out = tmp_path / "m"
    r = CliRunner().invoke(main, ["fit", str(session), "--model", "rigid-body", "--scale-to-data",
                                  "--effect-file", str(source), "--effect", "as-data-test-drag:joint=joint1",
                                  "-o", str(out)])
    assert r.exit_code == 0, r.output
    recorded = json.loads((out / "model.json").read_text())["options"]["effect_specs"]
    assert {"kind": "user", "name": "as-data-test-drag", "file": str(source.resolve()),
            "sha256": hashlib.sha256(source.read_bytes()).hexdigest()}.items() <= recorded[-1].items()
    fresh()
    marker.unlink()
    r = CliRunner().invoke(main, ["export", str(out), "--force", "--effect-file", str(source)])
    assert r.exit_code == 0 and marker.exists(), r.output  # named, unchanged: it runs
    fresh()
    marker.unlink()
    source.write_text(source.read_text() + "# edited\n")
    r = CliRunner().invoke(main, ["compare", str(out), "--session", str(session),
                                  "--effect-file", str(source)])
    assert r.exit_code == 2 and r.output.startswith("Error: ") and r.output.count("\n") == 1, r.output
    assert "drag.py" in r.output and "changed since the model was fitted" in r.output
    assert not marker.exists()


def _discovery(joints, terms, coefs, joint="joint2", session_name="s.h5"):
    from train.diagnosis.discovery import Discovery, FoundTerm, JointDiscovery

    found = [FoundTerm(t.name, c, 0.01, t.unit, t.expr, t.parameter, t.family) for t, c in zip(terms, coefs)]
    d = JointDiscovery(joint, "expr", found, 0.5, [0.5] * 5, True, "")
    return Discovery(tuple(joints), [d], {joint: ""}, {"every_joint": False})


def _data(n=200, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-1.5, 1.5, (n, 3)), rng.normal(0, 1, (n, 3)), rng.normal(0, 5, (n, 3))


def test_a_discovered_effect_written_as_data_computes_the_columns_the_discovery_evaluated(tmp_path, fresh):
    from train.diagnosis.discovery_basis import evaluate, generate
    from train.diagnosis.effect_writer import effect_name, write_effect_file

    joints = ("joint1", "joint2", "joint4")
    basis = generate(joints, 1)  # every kind of term, the library's columns included
    picks = [basis[i] for i in range(0, len(basis), 3)]
    found = _discovery(joints, picks, np.linspace(-1, 1, len(picks)))
    path, added = write_effect_file(tmp_path / "d.json", found)
    name = effect_name(found.discovered[0], joints)
    assert added == [(name, "joint2", None)]
    assert load_effect_file(path) == [name]
    from crane_io.physics.effects import get_effect

    effect = get_effect(name)
    q, dq, ddq = _data()
    cols = effect.columns(q, dq, ddq, 1)
    expected = np.stack([evaluate(t, q, dq, ddq) for t in picks], axis=1)
    np.testing.assert_array_equal(cols[:, 1, :], expected)
    assert not cols[:, [0, 2], :].any()
    names = [p.name for p in effect.params]  # one named parameter per term
    assert len(set(names)) == len(picks) and names[:2] == [t.parameter for t in picks[:2]]


@pytest.mark.parametrize("name", ['s"""\nimport os; os.system("touch MARKER")\n"""', "a\nb\r\x00'\\.h5"])
def test_text_embedded_in_an_effect_spec_file_stays_data(tmp_path, fresh, name):
    from train.diagnosis.discovery_basis import generate
    from train.diagnosis.effect_writer import write_effect_file

    joints = ("joint1", "joint2", "joint4")
    name = name.replace("MARKER", str(tmp_path / "marker"))
    path, _ = write_effect_file(tmp_path / "d.json", _discovery(joints, generate(joints, 1)[:2], [0.1, 0.2]),
                                model_dir=name, sessions=[name])
    doc = json.loads(path.read_text())
    assert doc["found_by"]["sessions"] == [name] and doc["found_by"]["model"] == name
    assert load_effect_file(path) == ["joint2-" + "+".join(sorted(("const", "sign-dq")))]
    assert not (tmp_path / "marker").exists()
    assert list(tmp_path.iterdir()) == [path]  # written atomically: no temporary file left


def test_an_effect_spec_outside_the_grammar_is_refused_in_one_sentence(tmp_path, fresh):
    bad = {"format": "crane-effects", "format_version": 1, "effects": [{
        "kind": "terms", "name": "x", "joints": ["joint1"],
        "terms": [{"parameter": "p", "factors": [["__import__", "os"]]}]}]}
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(bad))
    with pytest.raises(ConfigError, match="not a factor of the basis grammar") as info:
        load_effect_file(path)
    assert "\n" not in str(info.value)


def test_diagnose_writes_the_effect_spec_file_only_as_json_and_never_over_an_input(fitted, tmp_path):
    session, model = fitted
    r = CliRunner().invoke(main, ["diagnose", str(model), str(session), "--write-effect-file",
                                  str(tmp_path / "d.py")])
    assert r.exit_code == 2 and ".json" in r.output and r.output.count("\n") == 1, r.output
    r = CliRunner().invoke(main, ["diagnose", str(model), str(session), "--write-effect-file",
                                  str(model / "model.json")])
    assert r.exit_code == 2 and r.output.startswith("Error: "), r.output


def _same_name_spec(factors, value):
    return {"kind": "terms", "name": "discovered-joint2", "joint": "joint2",
            "joints": ["joint1", "joint2", "joint4"],
            "terms": [{"parameter": "p", "factors": factors, "value": value}]}


def test_two_discovered_effects_of_one_name_are_never_mistaken_for_one(fitted, tmp_path, fresh):
    from train.models.registry import load_model

    session, _ = fitted
    models, predictions = [], []
    q, dq, ddq = _data(seed=4)
    for i, factors in enumerate(([["sign", 1]], [["dq", 1], ["cos", 2, [1]]])):
        f = tmp_path / f"d{i}.json"
        f.write_text(json.dumps(spec.spec_file_document([_same_name_spec(factors, 0.1)])))
        out = tmp_path / f"m{i}"
        fit_model([str(session)], "rigid-body", out, effects=["discovered-joint2:joint=joint2"],
                  effect_files=[str(f)], scale_to_data=True)
        models.append(out)
        predictions.append(load_model(out).predict(q, dq, ddq))
    ids = [json.loads((m / "model.json").read_text())["options"]["effect_specs"][0]["identity"]
           for m in models]
    assert ids[0] != ids[1]
    fresh()  # neither effect file is in the library any more: each model rebuilds its own from data
    for m, expected in zip(models, predictions):
        np.testing.assert_array_equal(load_model(m).predict(q, dq, ddq), expected)
    alone = [CliRunner().invoke(main, ["compare", str(m), "--session", str(session), "--json"])
             for m in models]
    both = CliRunner().invoke(main, ["compare", *map(str, models), "--session", str(session), "--json"])
    assert both.exit_code == 0 and all(r.exit_code == 0 for r in alone), both.output
    rows = [json.loads(r.output)["models"][0] for r in alone]
    assert json.loads(both.output)["models"] == rows
    assert rows[0] != rows[1]


def test_an_effect_file_that_exits_is_a_one_sentence_error_and_fit_writes_no_model(fitted, tmp_path, fresh):
    session, _ = fitted
    quitter = tmp_path / "quits.py"
    quitter.write_text("import sys\nsys.exit(0)\n")
    out = tmp_path / "m"
    r = CliRunner().invoke(main, ["fit", str(session), "--model", "rigid-body", "--scale-to-data",
                                  "--effect-file", str(quitter), "-o", str(out)])
    assert r.exit_code == 2 and r.output.startswith("Error: ") and "quits.py" in r.output, r.output
    assert r.output.count("\n") == 1 and not out.exists()


def test_a_plant_names_effects_defined_as_data_in_its_effect_spec_files(tmp_path, fresh):
    from crane_io.sim.arm_plant import ArmPlant

    f = tmp_path / "mine.json"
    f.write_text(json.dumps(spec.spec_file_document([_same_name_spec([["dq", 1], ["sin", 1, [1]]], 0.1)])))
    plant = tmp_path / "p.toml"
    plant.write_text('base = "baseline"\neffect_specs = ["mine.json"]\n'
                     '[hidden]\neffect = "discovered-joint2"\njoint = "joint2"\np = 0.3\n')
    config = load_plant_config(plant)
    assert config.hidden.values == {"p": 0.3}
    assert config.hidden.definition["terms"][0]["term"] == "dq2·sin(q2)"
    effect = config.hidden.build()
    q, dq, ddq = _data(n=5)
    expected = 0.3 * dq[:, 1] * np.sin(q[:, 1])
    np.testing.assert_allclose(effect.torque(q, dq, ddq, 1, {"p": 0.3})[:, 1], expected)
    one = effect.torque(q[:1], dq[:1], ddq[:1], 1, {"p": 0.3})[0, 1]  # the plant's one-sample path
    assert one == pytest.approx(expected[0], rel=1e-12)
    assert "discovered-joint2" not in effect_names()  # the plant's own: the library is untouched
    ArmPlant(config, seed=0, kernel=False)  # builds the effect from its definition
    r = CliRunner().invoke(main, ["effects", "--effect-file", str(f), "--json"])
    assert r.exit_code == 0 and "discovered-joint2" in r.output, r.output


def test_the_documented_effect_spec_file_computes_what_the_documented_python_effect_does(fresh):
    from crane_io.physics.effects import get_effect

    examples = Path(__file__).parents[1] / "docs" / "examples"
    assert load_effect_file(examples / "cable_drag.json") == ["cable-drag-data"]
    load_effect_file(examples / "cable_drag.py")
    q, dq, ddq = _data()
    np.testing.assert_array_equal(get_effect("cable-drag-data").torque(q, dq, ddq, 0),
                                  get_effect("cable-drag").torque(q, dq, ddq, 0))


_JSON = st.recursive(st.none() | st.booleans() | st.integers(-5, 70) | st.floats() | st.text(max_size=8),
                     lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=6), c, max_size=4),
                     max_leaves=12)
_OPS = st.sampled_from(["1", "q", "dq", "ddq", "sign", "tanh", "abs", "pow", "sin", "cos", "library", "exec"])


@settings(max_examples=150, deadline=None)
@given(kind=st.sampled_from(["terms", "library", "user", "other"]),
       joints=_JSON | st.just(["joint1", "joint2"]),
       factors=st.lists(st.lists(_OPS | _JSON, min_size=1, max_size=4), max_size=3) | _JSON,
       extra=st.dictionaries(st.sampled_from(["name", "version", "joint", "value", "sha256", "file",
                                              "friction"]), _JSON, max_size=3))
def test_any_damaged_effect_spec_is_one_sentence_or_a_working_effect(kind, joints, factors, extra):
    raw = {"kind": kind, "name": "fuzz", "version": 1, "joints": joints,
           "terms": [{"parameter": "p", "factors": factors, "value": extra.pop("value", 0.1)}], **extra}
    try:
        doc = spec.check_spec(raw)
    except ConfigError as exc:
        assert "\n" not in str(exc)
        return
    assert spec.identity(doc) == spec.identity(json.loads(spec.canonical_json(doc)))
    if doc["kind"] == "terms":
        n = len(doc["joints"])
        cols = spec.rebuild(doc).columns(*(np.full((2, n), 0.3) for _ in range(3)), 0)
        assert cols.shape == (2, n, 1)
