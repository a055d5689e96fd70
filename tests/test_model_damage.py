"""Damaged model directories: loading refuses them in one sentence (a CraneError), never with another
exception, never touching a file (train.models.model_files, crane_io.physics.loop_model_check); what a
loader accepts predicts finite torques.

How effects are stored (options.effects, options.effect_files, state.terms, the export's rigid_effects)
is the effects' loader's to check, so the mutations of model.json leave those keys' contents alone."""

from __future__ import annotations

import hashlib
import io
import json
import math
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from crane_io.errors import CraneError
from crane_io.physics.loop_model import EXPORT_FILE, LoopModel
from train.cli import main
from train.data.dataset import Dataset
from train.data.preprocess import PreprocessConfig
from train.models.base import ModelFileError
from train.models.registry import load_model, make_model

JOINTS = ("joint1", "joint2", "joint4")
FUZZ = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
EFFECT_KEYS = ("effects", "effect_files", "terms")
torch.set_num_threads(1)


def _data(n=240, seed=2):
    from crane_io.physics.dynamics import ArmDynamics

    rng = np.random.default_rng(seed)
    q, dq, ddq = rng.uniform(-1, 1, (n, 3)), rng.uniform(-2, 2, (n, 3)), rng.uniform(-10, 10, (n, 3))
    tau = ArmDynamics(joints=JOINTS).inverse_dynamics(q, dq, ddq) + 0.05 * dq
    return Dataset(JOINTS, np.arange(n) * 0.02, q, dq, ddq, tau, np.ones((n, 3), bool), 50.0)


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    root = tmp_path_factory.mktemp("models")
    ds = _data()
    pre = {**PreprocessConfig(joints=JOINTS).to_dict(), "dead_zone_rad_s": [0.01] * 3,
           "input_range": {"q_min": [-1.0] * 3, "q_max": [1.0] * 3}}
    options = {"rigid-body": {"effects": [["viscous", None, None]]},
               "mlp-masked": {"epochs": 2, "hidden": 8}, "hybrid": {"epochs": 2, "hidden": 8}}
    return {m: make_model(m, JOINTS, preprocessing=pre, **o).fit(ds, ds).save(root / m)
            for m, o in options.items()}


def _copy(source: Path) -> Path:
    target = Path(tempfile.mkdtemp(prefix="damaged-", dir=source.parent)) / "model"  # pytest's folder
    shutil.copytree(source, target)
    return target


def _digests(directory: Path) -> dict:
    files = (p for p in sorted(directory.rglob("*")) if p.is_file())
    return {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in files}


def _sample():
    return np.array([[0.1, -0.2, 0.3]]), np.array([[0.5, 0.0, -0.4]]), np.array([[1.0, 2.0, -3.0]])


def _check_load(directory: Path) -> str | None:
    """Load with the train loader and the loop's: None when both accept (then they predict finite
    torques), else the sentence; any other exception or a changed file fails the test."""
    before = _digests(directory)
    message = None
    try:
        model = load_model(directory)
        pred = model.predict(*_sample())
        assert np.all(np.isfinite(pred)), pred
    except CraneError as exc:
        message = str(exc)
    try:
        loop = LoopModel.load(directory)
        q, dq, ddq = (a[0] for a in _sample())
        assert np.all(np.isfinite(loop.predict_one(q, dq, ddq)))
    except CraneError as exc:
        message = message or str(exc)
    assert message is None or (message and "\n" not in message), message
    assert _digests(directory) == before, "loading changed a file"
    return message


# -- model.json --------------------------------------------------------------------------------------------
JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-2 ** 70, 2 ** 70) | st.text(max_size=8)
    | st.floats(allow_nan=True, allow_infinity=True),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
    max_leaves=8)


def _paths(doc, prefix=()):
    """Every key path of a JSON document, effects' contents excluded."""
    out = []
    if isinstance(doc, dict):
        items = doc.items()
    elif isinstance(doc, list):
        items = enumerate(doc)
    else:
        return out
    for key, value in items:
        path = (*prefix, key)
        out.append(path)
        if key not in EFFECT_KEYS:
            out += _paths(value, path)
    return out


def _mutate(doc, path, action, value):
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    if action == "delete" and isinstance(parent, dict):
        del parent[path[-1]]
    else:
        parent[path[-1]] = value
    return doc


@FUZZ
@given(method=st.sampled_from(["rigid-body", "mlp-masked", "hybrid"]), data=st.data())
def test_a_mutated_model_json_is_one_sentence_or_a_working_model(saved, method, data):
    directory = _copy(saved[method])
    sub = data.draw(st.sampled_from(["", "rigid/", "mlp/"] if method == "hybrid" else [""]), "part")
    path = directory / sub / "model.json"
    doc = json.loads(path.read_text())
    if data.draw(st.integers(0, 9), "whole") == 0:
        doc = data.draw(JSON_VALUES, "document")
    else:
        where = data.draw(st.sampled_from(_paths(doc)), "key")
        doc = _mutate(doc, where, data.draw(st.sampled_from(["delete", "replace"]), "action"),
                      data.draw(JSON_VALUES, "value"))
    path.write_text(json.dumps(doc))
    _check_load(directory)


@pytest.mark.parametrize("edit, words", [
    (lambda doc: [doc], "top level is not a crane-model object"),
    (lambda doc: {**doc, "format_version": 99}, "format_version 99"),
    (lambda doc: {**doc, "joint_names": [1, 2, 3]}, "joint_names"),
    (lambda doc: {**doc, "options": {**doc["options"], "epochs": -5}}, "epochs"),
    (lambda doc: {**doc, "state": {**doc["state"], "norm": {**doc["state"]["norm"], "x_std": [0.0] * 9}}},
     "x_std"),
])
def test_model_json_refusals_name_the_directory_and_the_file(saved, edit, words):
    directory = _copy(saved["mlp-masked"])
    path = directory / "model.json"
    path.write_text(json.dumps(edit(json.loads(path.read_text()))))
    with pytest.raises(ModelFileError, match=words) as info:
        load_model(directory)
    assert str(path) in str(info.value)


@pytest.mark.parametrize("content", [b"\x00\xff binary", b"[" * 100000, b""])
def test_an_unreadable_model_json_is_one_sentence(saved, content):
    directory = _copy(saved["rigid-body"])
    (directory / "model.json").write_bytes(content)
    assert "model.json" in _check_load(directory)


def test_a_model_json_that_is_a_folder_is_one_sentence(saved):
    directory = _copy(saved["rigid-body"])
    (directory / "model.json").unlink()
    (directory / "model.json").mkdir()
    with pytest.raises(ModelFileError, match="model.json"):
        load_model(directory)


def test_a_hybrid_whose_part_is_itself_is_refused_before_loading_goes_round(saved):
    directory = _copy(saved["hybrid"])
    shutil.rmtree(directory / "rigid")
    (directory / "rigid").symlink_to(".")
    with pytest.raises(ModelFileError, match="rigid part must be rigid-body"):
        load_model(directory)


# -- weight files --------------------------------------------------------------------------------------------
ARRAYS = st.sampled_from([
    np.array(["a", "b"]), np.array([None, 1], dtype=object), np.full(3, np.nan), np.full(3, np.inf),
    np.full(3, 1e308), np.ones((2, 2)), np.float64(1.0), np.zeros(0), np.ones(1000),
    np.zeros(2, dtype=[("a", "f8")]), np.array([True, False]), np.array([1 + 2j])])


def _rewrite_npz(path: Path, edit) -> None:
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    edit(arrays)
    buf = io.BytesIO()
    np.savez(buf, **arrays)  # object arrays are pickled here: the loaders must refuse them
    path.write_bytes(buf.getvalue())


def _rewrite_export(directory: Path, edit) -> None:
    """Edit loop_model.npz's arrays and record the new file's digest in model.json (so the loader gets
    past the digest to the content)."""
    path = directory / EXPORT_FILE
    _rewrite_npz(path, edit)
    doc = json.loads((directory / "model.json").read_text())
    doc["loop_export"]["sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    (directory / "model.json").write_text(json.dumps(doc))


def _damage_bytes(data, path: Path) -> None:
    raw = path.read_bytes()
    if data.draw(st.booleans(), "garbage"):
        path.write_bytes(data.draw(st.binary(max_size=200), "bytes"))
    else:
        path.write_bytes(raw[:data.draw(st.integers(0, len(raw) - 1), "length")])


@FUZZ
@given(data=st.data())
def test_damaged_rigid_body_parameters_are_one_sentence(saved, data):
    directory = _copy(saved["rigid-body"])
    path = directory / "rigid_body.npz"
    if data.draw(st.booleans(), "bytes"):
        _damage_bytes(data, path)
    else:
        key = data.draw(st.sampled_from(["theta", "stderr"]), "key")
        value = data.draw(ARRAYS | st.none(), "value")

        def edit(arrays):
            if value is None:
                del arrays[key]
            else:
                arrays[key] = value
        _rewrite_npz(path, edit)
    assert _check_load(directory) is not None


TENSORS = st.sampled_from([torch.zeros(2, 2), torch.full((8,), float("nan")), torch.ones(9, 8) * 1e30,
                           torch.zeros(8, dtype=torch.bool), "text", 3, [1.0, 2.0], None])


@FUZZ
@given(data=st.data())
def test_damaged_network_weights_are_one_sentence(saved, data):
    directory = _copy(saved["mlp-masked"])
    path = directory / "mlp.pt"
    if data.draw(st.booleans(), "bytes"):
        _damage_bytes(data, path)
    else:
        weights = torch.load(path, weights_only=True)
        key = data.draw(st.sampled_from(["W1", "b1", "W2", "b2"]), "key")
        value = data.draw(TENSORS, "value")
        if value is None:
            del weights[key]
        else:
            weights[key] = value
        if data.draw(st.integers(0, 5), "whole") == 0:
            weights = weights.get("W1")
        torch.save(weights, path)
    assert _check_load(directory) is not None


def test_weights_are_never_unpickled(saved, tmp_path):
    directory = _copy(saved["mlp-masked"])
    marker = tmp_path / "ran"

    class Payload:
        def __reduce__(self):
            return (Path.touch, (marker,))

    torch.save({"W1": Payload()}, directory / "mlp.pt")
    with pytest.raises(ModelFileError, match="mlp.pt"):
        load_model(directory)
    assert not marker.exists()


# -- the loop's export ---------------------------------------------------------------------------------------
@FUZZ
@given(method=st.sampled_from(["rigid-body", "mlp-masked"]), data=st.data())
def test_a_damaged_loop_export_is_one_sentence_or_a_working_model(saved, method, data):
    directory = _copy(saved[method])
    path = directory / EXPORT_FILE
    with np.load(path, allow_pickle=False) as z:
        keys = sorted(k for k in z.files if k != "rigid_effects")
    key = data.draw(st.sampled_from(keys), "key")
    value = data.draw(ARRAYS, "value")

    _rewrite_export(directory, lambda arrays: arrays.__setitem__(key, value))
    before = _digests(directory)
    try:
        loop = LoopModel.load(directory)
        out = loop.predict_one(*(a[0] for a in _sample()))
        assert np.all(np.isfinite(out)) and all(math.isfinite(v) for v in out.tolist())
    except CraneError as exc:
        assert "\n" not in str(exc)
    assert _digests(directory) == before


# -- the command lines -------------------------------------------------------------------------------------
@pytest.mark.parametrize("command", ["compare", "export", "report"])
def test_a_damaged_model_makes_a_command_print_one_error_line_and_exit_2(saved, command, tmp_path):
    directory = _copy(saved["rigid-body"])
    (directory / "model.json").write_text("[1, 2, 3]")
    before = _digests(directory)
    args = {"compare": ["compare", str(directory), "--session", str(tmp_path / "s.h5")],
            "export": ["export", str(directory)],
            "report": ["report", str(directory), str(tmp_path / "s.h5"), "-o", str(tmp_path / "r.html")]}
    result = CliRunner().invoke(main, args[command])
    assert result.exit_code == 2, result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error: ")]
    assert len(errors) == 1 and "model.json" in errors[0], result.output  # after a progress line, if any
    assert result.output.strip().splitlines()[-1] == errors[0] and "Traceback" not in result.output
    assert _digests(directory) == before


def test_crane_collect_run_refuses_a_model_with_non_finite_weights_before_recording(saved, tmp_path):
    from collect.cli import main as collect_main

    directory = _copy(saved["mlp-masked"])
    _rewrite_export(directory, lambda arrays: arrays.__setitem__("mlp_b1", np.full(8, np.nan)))
    out = tmp_path / "s.h5"
    result = CliRunner().invoke(collect_main, ["run", "--sim", "--duration", "1", "-o", str(out),
                                               "--model", str(directory)])
    assert result.exit_code == 2, result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error: ")]
    assert len(errors) == 1 and "mlp_b1 holds NaN" in errors[0] and "Traceback" not in result.output
    assert not out.exists()


@pytest.mark.parametrize("method, key, value, words", [
    ("mlp-masked", "mlp_x_std", np.zeros(9), "zero or negative spread"),
    ("mlp-masked", "mlp_W2", np.full((8, 3), 1e308), "beyond any fitted value"),
    ("mlp-masked", "mlp_W1", np.array([None] * 9, dtype=object), "Python objects"),
    ("rigid-body", "rigid_theta_full", np.full(30, np.inf), "NaN or infinite"),
    ("rigid-body", "rigid_payload_mass", np.float64(-1.0), "payload"),
    ("rigid-body", "source_files", np.array(["../../elsewhere"]), "not a file inside the model directory"),
])
def test_loop_export_refusals_name_the_directory_and_the_member(saved, method, key, value, words):
    directory = _copy(saved[method])
    _rewrite_export(directory, lambda arrays: arrays.__setitem__(key, value))
    with pytest.raises(CraneError, match=words) as info:
        LoopModel.load(directory)
    assert str(directory) in str(info.value) and (key in str(info.value) or EXPORT_FILE in str(info.value))
