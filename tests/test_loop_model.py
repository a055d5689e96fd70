"""crane_io.physics.loop_model: a saved model as the control loop loads it (loop_model.npz, no train,
no torch).

- LoopModel.load(dir).predict_one equals the train model's own load_model(dir).predict for every method
  (tolerance: |diff| <= 1e-5 |expected| + 1e-6 N m, float64 here against torch's float32 network);
- every refusal is a LoopModelError whose sentence names the directory;
- the export's SHA-256 depends on the weights only (same weights, same digest; other weights, another);
- `crane-train export DIR` writes the export of a model saved without one and touches nothing else;
- importing crane_io.physics.loop_model imports neither torch nor train.
"""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from crane_io.physics.loop_model import EXPORT_FILE, SI_UNITS, LoopModel, LoopModelError, check_for_arm
from train.data.dataset import Dataset
from train.data.preprocess import PreprocessConfig
from train.models.loop_export import npz_bytes
from train.models.registry import load_model, make_model

JOINTS = ("joint1", "joint2", "joint4")
EFFECTS = [["coulomb", None, None], ["viscous", None, None],
           ["stribeck", "joint2", {"stribeck_velocity": 0.05}]]
OPTIONS = {"mlp-mse": {"epochs": 3, "hidden": 16}, "mlp-masked": {"epochs": 3, "hidden": 16},
           "rigid-body": {"effects": EFFECTS}, "hybrid": {"epochs": 3, "hidden": 16, "effects": EFFECTS}}
RTOL, ATOL = 1e-5, 1e-6  # N m


def _data(n, seed, joints=JOINTS):
    from crane_io.physics.dynamics import ArmDynamics

    rng = np.random.default_rng(seed)
    q, dq, ddq = rng.uniform(-1, 1, (n, 3)), rng.uniform(-2, 2, (n, 3)), rng.uniform(-10, 10, (n, 3))
    dq[::7, 1] = 0.0  # exact zeros: sign(0) = 0 must match
    tau = ArmDynamics(joints=joints).inverse_dynamics(q, dq, ddq) + 0.2 * np.sign(dq) + 0.05 * dq
    return Dataset(joints, np.arange(n) * 0.02, q, dq, ddq, tau, rng.random((n, 3)) < 0.8, 50.0)


def _fit_save(method, directory, joints=JOINTS, preprocessing=None, **options):
    pre = PreprocessConfig(joints=joints).to_dict() if preprocessing is None else preprocessing
    opts = {**OPTIONS[method], **options}
    ds = _data(300, 1, joints)
    return make_model(method, joints, preprocessing=pre, **opts).fit(ds, ds).save(directory)


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    root = tmp_path_factory.mktemp("loop_models")
    return {m: _fit_save(m, root / m) for m in OPTIONS}


@pytest.fixture
def copy(saved, tmp_path):
    def make(method="mlp-masked"):
        d = tmp_path / f"copy-{method}"
        shutil.copytree(saved[method], d)
        return d
    return make


def _assert_equal_predictions(directory, joints=JOINTS):
    loop = LoopModel.load(directory)
    ref = load_model(directory)
    test = _data(150, 2, joints)
    expected = ref.predict(test.q, test.dq, test.ddq)
    got = np.array([loop.predict_one(q, dq, ddq).copy() for q, dq, ddq in zip(test.q, test.dq, test.ddq)])
    np.testing.assert_allclose(got, expected, rtol=RTOL, atol=ATOL)
    out = np.empty(len(joints))
    assert loop.predict_one(test.q[0], test.dq[0], test.ddq[0], out=out) is out
    return loop


@pytest.mark.parametrize("method", list(OPTIONS))
def test_loop_model_equals_the_train_model(saved, method):
    loop = _assert_equal_predictions(saved[method])
    assert loop.method == method and loop.joint_names == JOINTS and loop.arm == "follower"
    assert loop.units == SI_UNITS and loop.preprocessing["cutoff_rad_s"] == 25.0
    assert loop.path == str(saved[method]) and re.fullmatch(r"[0-9a-f]{64}", loop.sha256)
    if method in ("rigid-body", "hybrid"):
        assert loop.effects == ["coulomb:joint1", "coulomb:joint2", "coulomb:joint4", "viscous:joint1",
                                "viscous:joint2", "viscous:joint4", "stribeck:joint2"]
    else:
        assert loop.effects == []
    doc = json.loads((saved[method] / "model.json").read_text())
    assert doc["units"] == SI_UNITS and doc["loop_export"]["sha256"] == loop.sha256


def test_rigid_body_in_another_joint_order_with_locked_joints_and_payload_effects(tmp_path):
    joints = ("joint4", "joint1", "joint2")
    d = _fit_save("rigid-body", tmp_path / "m", joints, locked={"joint3": 0.3}, payload_mass=0.1,
                  effects=[["coulomb", None, None], ["spring", "joint4", {"rest_angle": 0.25}],
                           ["cogging", "joint1", {"cycles_per_rev": 6.0}]])
    with np.load(d / EXPORT_FILE) as z:
        assert list(z["rigid_locked_joints"]) == ["joint3"] and float(z["rigid_locked_angles"][0]) == 0.3
        assert float(z["rigid_payload_mass"]) == 0.1
    _assert_equal_predictions(d, joints)


USER_EFFECT = textwrap.dedent('''
    from pathlib import Path

    from crane_io.physics.effects import Effect, Param
    from crane_io.physics.effects.base import joint_columns

    with open(Path(__file__).with_suffix(".ran"), "a") as f:  # a trace of every time this file runs
        f.write("ran\\n")

    class CubicDrag(Effect):
        name = "loop-test-cubic-drag"
        title = "cubic drag"; description = "d"; signature = "s {joint}"
        params = (Param("c3", "N m s^3/rad^3", 0.01, "cubic coefficient"),)

        def _columns(self, q, dq, ddq, joint, shape):
            return joint_columns(len(q), q.shape[1], joint, dq[:, joint] ** 3)
''')


@pytest.fixture
def fresh_process(monkeypatch):
    """As in a new process: no user effect file has run, none is named."""
    from crane_io.physics.effects import spec

    def reset():
        monkeypatch.setattr(spec, "_RUN", {})
        monkeypatch.setattr(spec, "_OFFERED", {})
    monkeypatch.setattr(spec, "_SOURCE", dict(spec._SOURCE))
    return reset


def test_a_user_python_effect_runs_in_the_loop_only_from_the_named_file_with_its_recorded_sha256(
        tmp_path, fresh_process):
    from crane_io.physics.effects import load_effect_file
    from crane_io.physics.effects.spec import offer_effect_files

    effect_file, ran = tmp_path / "my_effects.py", tmp_path / "my_effects.ran"
    effect_file.write_text(USER_EFFECT)
    fresh_process()
    load_effect_file(effect_file)  # named to define the effect (fit): it runs
    d = _fit_save("rigid-body", tmp_path / "m", effects=[["loop-test-cubic-drag", "joint2", None]])
    loop = _assert_equal_predictions(d)
    assert loop.effects == ["loop-test-cubic-drag:joint2"]
    assert loop.paths[0].generic_terms  # a user effect goes through its columns
    spec = json.loads(str(np.load(d / EXPORT_FILE)["rigid_effect_specs"]))
    assert spec[0]["kind"] == "user" and spec[0]["file"] == str(effect_file.resolve())
    fresh_process()
    ran.unlink()
    with pytest.raises(LoopModelError, match=re.escape(str(d)) + ".*my_effects.py.*runs no user code"):
        LoopModel.load(d)
    assert not ran.exists()
    offer_effect_files([effect_file])  # named, same bytes: it runs once, and the loop uses it
    assert LoopModel.load(d).effects == ["loop-test-cubic-drag:joint2"] and ran.read_text() == "ran\n"
    fresh_process()
    ran.unlink()
    effect_file.write_text(USER_EFFECT + "\n# edited\n")
    offer_effect_files([effect_file])  # named, but changed: refused before it runs
    with pytest.raises(LoopModelError, match=re.escape(str(d)) + ".*my_effects.py.*changed since"):
        LoopModel.load(d)
    assert not ran.exists()


def test_an_export_that_lists_python_effect_files_is_refused_without_running_them(copy, tmp_path):
    marker = tmp_path / "ran"
    evil = tmp_path / "evil.py"
    evil.write_text(f"open({str(marker)!r}, 'w').write('x')\n")
    d = copy("rigid-body")
    with np.load(d / EXPORT_FILE) as z:
        arrays = {k: z[k] for k in z.files}
    arrays.pop("rigid_effect_specs")
    arrays["rigid_effect_files"] = np.array([str(evil)])
    raw = npz_bytes(arrays)
    (d / EXPORT_FILE).write_bytes(raw)
    doc = json.loads((d / "model.json").read_text())
    doc["loop_export"]["sha256"] = hashlib.sha256(raw).hexdigest()
    (d / "model.json").write_text(json.dumps(doc))
    with pytest.raises(LoopModelError, match=re.escape(str(d)) + ".*evil.py.*never runs"):
        LoopModel.load(d)
    assert not marker.exists()


def test_arm_is_read_from_model_json(copy):
    d = copy()
    doc = json.loads((d / "model.json").read_text())
    doc["preprocessing"]["arm"] = "leader"
    (d / "model.json").write_text(json.dumps(doc))
    assert LoopModel.load(d).arm == "leader"
    doc["arm"] = "follower"
    (d / "model.json").write_text(json.dumps(doc))
    assert LoopModel.load(d).arm == "follower"


def test_check_for_arm_refuses_joints_that_are_not_bilateral(saved):
    loop = LoopModel.load(saved["mlp-masked"])
    loop.check_for_arm(("joint1", "joint2", "joint4", "joint6"), "follower")
    with pytest.raises(LoopModelError, match=re.escape(str(saved["mlp-masked"])) + ".*joint4"):
        check_for_arm(loop, ("joint1", "joint2"))
    with pytest.raises(LoopModelError, match="fitted on the follower's data"):
        loop.check_for_arm(JOINTS, "leader")


# ---- refusals ----------------------------------------------------------------------------------------------
def _edit_json(d, edit):
    doc = json.loads((d / "model.json").read_text())
    edit(doc)
    (d / "model.json").write_text(json.dumps(doc))


def _edit_export(d, edit, keep_recorded_sha=False):
    """Change the export's arrays; model.json's recorded digest follows unless keep_recorded_sha."""
    with np.load(d / EXPORT_FILE) as z:
        arrays = {k: z[k] for k in z.files}
    edit(arrays)
    raw = npz_bytes(arrays)
    (d / EXPORT_FILE).write_bytes(raw)
    if not keep_recorded_sha:
        import hashlib

        _edit_json(d, lambda doc: doc["loop_export"].update(sha256=hashlib.sha256(raw).hexdigest()))


def _refused(d, *words):
    with pytest.raises(LoopModelError) as info:
        LoopModel.load(d)
    msg = str(info.value)
    assert str(d) in msg, msg
    assert "\n" not in msg and msg.count(". ") == 0, msg  # one sentence
    for w in words:
        assert w in msg, msg
    return msg


def test_refuses_a_missing_directory(tmp_path):
    _refused(tmp_path / "nope", "does not exist")


def test_refuses_a_directory_without_model_json(tmp_path):
    _refused(tmp_path, "no model.json")


def test_refuses_what_is_not_a_crane_model(copy):
    d = copy()
    _edit_json(d, lambda doc: doc.update(format="something-else"))
    _refused(d, "not a crane-model")
    (d / "model.json").write_text("{not json")
    _refused(d, "not readable JSON")


def test_refuses_a_model_without_its_loop_export(copy):
    d = copy()
    (d / EXPORT_FILE).unlink()
    _refused(d, "no loop export", f"crane-train export {d}")


def test_refuses_an_unknown_export_format_version(copy):
    d = copy()
    _edit_export(d, lambda a: a.update(format_version=np.int64(99)))
    _refused(d, "format version 99")


def test_refuses_units_other_than_si(copy):
    d = copy()
    _edit_json(d, lambda doc: doc.update(units={**SI_UNITS, "q": "deg"}))
    _refused(d, "units")
    d = copy("rigid-body")
    _edit_export(d, lambda a: a.update(units=np.array(json.dumps({**SI_UNITS, "tau": "mN m"}))))
    _refused(d, "units")


@pytest.mark.parametrize("method,key,value,words", [
    ("mlp-masked", "mlp_W2", np.zeros((16, 2)), ("inconsistent", "shape")),
    ("mlp-masked", "mlp_x_std", np.ones(6), ("inconsistent", "x_std")),
    ("rigid-body", "rigid_theta_full", np.zeros(20), ("rigid-body part",)),
    ("rigid-body", "rigid_effect_coefs", np.zeros(2), ("inconsistent",)),
    ("hybrid", "joint_names", np.array(["joint1", "joint2"]), ("joints joint1, joint2",)),
    ("hybrid", "method", np.array("rigid-body"), ("method 'rigid-body'",)),
])
def test_refuses_an_inconsistent_export(copy, method, key, value, words):
    d = copy(method)
    _edit_export(d, lambda a: a.update({key: value}))
    _refused(d, *words)


def test_refuses_an_export_whose_digest_differs_from_model_json(copy):
    d = copy()
    _edit_export(d, lambda a: a.update(mlp_b2=a["mlp_b2"] + 1.0), keep_recorded_sha=True)
    _refused(d, "SHA-256", "crane-train export")


def test_refuses_an_export_older_than_the_weights(copy):
    d = copy("rigid-body")
    with np.load(d / "rigid_body.npz") as z:
        theta, stderr = z["theta"], z["stderr"]
    np.savez(d / "rigid_body.npz", theta=theta * 2, stderr=stderr)
    _refused(d, "changed after", "crane-train export")


def test_refuses_zero_phase_and_missing_preprocessing(copy):
    d = copy()
    _edit_json(d, lambda doc: doc["preprocessing"].update(zero_phase=True))
    _refused(d, "zero-phase")
    _edit_json(d, lambda doc: doc.update(preprocessing={}))
    _refused(d, "cutoff_rad_s")


def test_refuses_a_corrupt_export(copy):
    d = copy()
    (d / EXPORT_FILE).write_bytes(b"garbage")
    _edit_json(d, lambda doc: doc.pop("loop_export"))
    _refused(d, "corrupt")


# ---- digest, export command, imports ----------------------------------------------------------------------
def test_the_digest_follows_the_weights(saved, tmp_path):
    loop = LoopModel.load(saved["mlp-masked"])
    again = LoopModel.load(load_model(saved["mlp-masked"]).save(tmp_path / "same"))
    assert again.sha256 == loop.sha256  # the same weights: the same bytes
    other = LoopModel.load(_fit_save("mlp-masked", tmp_path / "other", seed=5))
    assert other.sha256 != loop.sha256


@pytest.mark.parametrize("method", ["mlp-masked", "hybrid"])
def test_crane_train_export_writes_the_missing_export(copy, method):
    from train.cli import main

    d = copy(method)
    sha = LoopModel.load(d).sha256
    (d / EXPORT_FILE).unlink()
    before = {p: p.read_bytes() for p in d.rglob("*") if p.is_file()}
    result = CliRunner().invoke(main, ["export", str(d)])
    assert result.exit_code == 0, result.output
    assert EXPORT_FILE in result.output
    after = {p: p.read_bytes() for p in d.rglob("*") if p.is_file()}
    assert set(after) - set(before) == {d / EXPORT_FILE}
    assert all(after[p] == b for p, b in before.items())  # nothing else touched
    assert LoopModel.load(d).sha256 == sha  # the same export as Model.save wrote
    _assert_equal_predictions(d)


def test_crane_train_export_refuses_bad_input_in_one_sentence(tmp_path):
    from train.cli import main

    result = CliRunner().invoke(main, ["export", str(tmp_path / "nope")])
    assert result.exit_code != 0
    assert "does not exist" in result.output and "Traceback" not in result.output
    result = CliRunner().invoke(main, ["export", str(tmp_path)])
    assert result.exit_code != 0 and "not a crane-x7 model directory" in result.output


def test_importing_the_loop_model_imports_neither_torch_nor_train():
    code = ("import crane_io.physics.loop_model, sys; "
            "assert 'torch' not in sys.modules and 'train' not in sys.modules, "
            "[m for m in ('torch', 'train') if m in sys.modules]")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          cwd=Path(__file__).resolve().parents[1])
    assert done.returncode == 0, done.stderr


def test_loading_and_predicting_imports_neither_torch_nor_train(saved):
    code = ("import sys, numpy as np; from crane_io.physics.loop_model import LoopModel; "
            f"m = LoopModel.load({str(saved['hybrid'])!r}); "
            "m.predict_one(np.zeros(3), np.ones(3), np.zeros(3)); "
            "assert 'torch' not in sys.modules and 'train' not in sys.modules")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          cwd=Path(__file__).resolve().parents[1])
    assert done.returncode == 0, done.stderr


def test_the_loops_smooth_coulomb_sign_replaces_sign_by_tanh_and_zero_restores_the_model(saved):
    """set_coulomb_velocity(v0): each Coulomb-type term's sign(dq) becomes tanh(dq / v0); the rest of the
    prediction is untouched, and v0 = 0 gives load_model(dir).predict again."""
    from crane_io.errors import ConfigError

    for method in ("rigid-body", "hybrid"):
        loop = LoopModel.load(saved[method])
        ref = load_model(saved[method])
        test = _data(60, 3)
        expected = ref.predict(test.q, test.dq, test.ddq)
        rigid = next(p for p in loop.paths if hasattr(p, "set_coulomb_velocity"))
        terms = [(effect.name, j, c, s) for j, effect, c, s in rigid.scalar_terms]
        coulomb = {j: c[0] for name, j, c, s in terms if name == "coulomb"}
        assert sorted(coulomb) == [0, 1, 2]
        stribeck = next((c[0], s["stribeck_velocity"]) for name, j, c, s in terms if name == "stribeck")
        v0 = 0.3
        loop.set_coulomb_velocity(v0)
        assert loop.coulomb_velocity == v0
        got = np.array([loop.predict_one(q, dq, ddq).copy() for q, dq, ddq in zip(test.q, test.dq, test.ddq)])
        change = np.tanh(test.dq / v0) - np.sign(test.dq)
        want = expected + change * np.array([coulomb[0], coulomb[1], coulomb[2]])
        want[:, 1] += stribeck[0] * np.exp(-(test.dq[:, 1] / stribeck[1]) ** 2) * change[:, 1]
        np.testing.assert_allclose(got, want, rtol=RTOL, atol=ATOL)
        assert np.abs(got - expected).max() > 0.01  # a real change
        loop.set_coulomb_velocity(0.0)
        got = np.array([loop.predict_one(q, dq, ddq).copy() for q, dq, ddq in zip(test.q, test.dq, test.ddq)])
        np.testing.assert_allclose(got, expected, rtol=RTOL, atol=ATOL)
        for bad in (-0.1, float("nan")):
            with pytest.raises(ConfigError, match="smoothing velocity"):
                loop.set_coulomb_velocity(bad)
    mlp = LoopModel.load(saved["mlp-masked"])
    before = mlp.predict_one(test.q[0], test.dq[0], test.ddq[0]).copy()
    mlp.set_coulomb_velocity(0.3)  # a network has no Coulomb term: nothing changes
    np.testing.assert_array_equal(mlp.predict_one(test.q[0], test.dq[0], test.ddq[0]), before)
