"""crane-train compare: successive models scored on the same held-out samples, table + plot + JSON."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from tests.sessions import write_synthetic_session
from train.cli import main
from train.cmd_fit import fit_model
from train.compare import compare_models, plot, table_text
from train.heldout import evaluation_data
from train.models.registry import load_model
from train.preprocess import preprocess
from train.session import read_sessions
from train.splits import make_splits


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """Two models fitted by `crane-train fit`'s code path on one session: rigid-body without and with
    the session's friction."""
    root = tmp_path_factory.mktemp("cmp")
    session, _ = write_synthetic_session(root / "s.h5", 150, seed=7)
    dirs = []
    for name, effects in (("rb", []), ("rb-friction", [("coulomb", None, None), ("viscous", None, None)])):
        fit_model([str(session)], "rigid-body", root / name, seed=2, effects=effects, scale_to_data=True,
                  progress=False)
        dirs.append(root / name)
    ds = preprocess(read_sessions([session]))
    return session, dirs, make_splits(ds, seed=2, scale_to_data=True)


def test_models_are_scored_on_the_same_held_out_samples(fitted):
    session, dirs, sp = fitted
    c = compare_models(dirs, [session])
    assert [m.method for m in c.models] == ["rigid-body", "rigid-body"]
    assert c.models[1].effects == ["coulomb", "viscous"]
    assert c.models[0].n_test == c.models[1].n_test == len(sp.index["test"])
    # the test metric equals the model's error on the split's own test set
    m1 = load_model(dirs[1])
    err = ((sp.test.tau - m1.predict_dataset(sp.test)) ** 2).mean(axis=0)
    np.testing.assert_allclose([c.models[1].test["mse"][j] for j in c.joints], err, rtol=1e-9)
    # the friction the session holds: adding it makes every joint's error fall
    for j in c.joints:
        assert c.models[1].test["mse"][j] < 0.5 * c.models[0].test["mse"][j]
    text = table_text(c)
    assert "rb-friction" in text and "%" in text


def test_held_out_data_follow_the_models_recorded_split(fitted):
    session, dirs, sp = fitted
    _, splits, held = evaluation_data(load_model(dirs[0]), [session], model_dir=dirs[0])
    np.testing.assert_array_equal(splits.index["test"], sp.index["test"])
    assert held.test.sum() == len(sp.index["test"])


def test_compare_cli_json_and_plot(fitted, tmp_path):
    session, dirs, _ = fitted
    out = tmp_path / "cmp.png"
    r = CliRunner().invoke(main, ["compare", *map(str, dirs), "--session", str(session), "--json",
                                  "-o", str(out)])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    assert [m["directory"] for m in doc["models"]] == [str(d) for d in dirs]
    assert set(doc["models"][0]["test"]) == {"mse", "rmse", "nmse"}
    assert out.stat().st_size > 5000 and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    r = CliRunner().invoke(main, ["compare", *map(str, dirs), "--session", str(session)])
    assert r.exit_code == 0 and "joint2 MSE" in r.output


def test_compare_bad_input_is_one_sentence(fitted, tmp_path):
    session, dirs, _ = fitted
    r = CliRunner().invoke(main, ["compare", str(tmp_path / "nope"), "--session", str(session)])
    assert r.exit_code != 0 and r.output.startswith("Error: ") and "Traceback" not in r.output
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not hdf5")
    r = CliRunner().invoke(main, ["compare", str(dirs[0]), "--session", str(bad)])
    assert r.exit_code != 0 and r.output.startswith("Error: ")


def test_sessions_default_to_the_ones_the_model_was_trained_on(fitted):
    _, dirs, sp = fitted
    c = compare_models(dirs)
    assert c.models[0].n_test == len(sp.index["test"])


def test_plot_writes_one_panel_per_joint(fitted, tmp_path):
    session, dirs, _ = fitted
    path = plot(compare_models(dirs, [session]), tmp_path / "p.png")
    assert path.exists() and path.stat().st_size > 5000
