"""crane-train sweep / fit / info end to end on small synthetic sessions."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from tests.sessions import write_synthetic_session
from train.cli import main
from train.cli.options import parse_sizes
from train.data.preprocess import preprocess
from train.data.session import read_sessions
from train.data.splits import SplitConfig
from train.evaluation.sweep import SweepError, run_sweep
from train.models.batched import MLPSettings
from train.models.registry import load_model
from train.settings import parse_effect

torch.set_num_threads(1)
SMALL = SplitConfig(n_pool=1500, n_val=150, n_test=150)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    path, _ = write_synthetic_session(tmp_path_factory.mktemp("sw") / "s.h5", 150, seed=7)
    return path


@pytest.fixture(scope="module")
def dataset(session):
    return preprocess(read_sessions([session]))


def test_run_sweep_reports_every_method_size_and_joint(dataset):
    r = run_sweep(dataset, [200, 600], trials=3, seed=1, progress=False, split_config=SMALL,
                  mlp_settings=MLPSettings(epochs=4))
    doc = r.to_json()
    assert doc["joints"] == ["joint1", "joint2", "joint4"]
    assert set(doc["usable_fraction"]) == {"per_joint", "all_joints"}
    assert list(doc["methods"]) == ["rigid-body", "mlp-mse", "mlp-masked"]
    for m in doc["methods"].values():
        assert m["sizes"] == [200, 600]
        assert np.array(m["mse_mean"], dtype=float).shape == (2, 3)
        assert np.array(m["mse_ci95"], dtype=float).shape == (2, 3)
        trials = np.array(m["mse_trials"], dtype=float)
        assert trials.shape == (2, 3, 3) and np.all(np.isfinite(trials)) and np.all(trials > 0)
        assert np.array(m["mse_mean"]) == pytest.approx(trials.mean(axis=1))
        assert np.array(m["rmse_mean"]) == pytest.approx(np.sqrt(trials).mean(axis=1))
    rows = {k: v["train_rows_mean"] for k, v in doc["methods"].items()}
    assert rows["mlp-masked"] == [200, 600]  # the masked loss uses every drawn sample ...
    assert rows["mlp-mse"][1] < 0.6 * 600  # ... plain MSE only those where all joints move
    assert rows["rigid-body"] == rows["mlp-mse"]
    assert set(doc["window"]["predictions"]) == set(doc["methods"])
    assert np.array(doc["window"]["tau"]).shape == (150, 3)


def test_sweep_is_reproducible_with_a_seed(dataset):
    kw = dict(trials=2, methods=["mlp-masked"], progress=False, split_config=SMALL,
              mlp_settings=MLPSettings(epochs=2))
    a = run_sweep(dataset, [300], seed=4, **kw).methods["mlp-masked"]["mse_trials"]
    b = run_sweep(dataset, [300], seed=4, **kw).methods["mlp-masked"]["mse_trials"]
    assert a == b


def test_sweep_rejects_what_it_cannot_do(dataset):
    with pytest.raises(SweepError, match="hybrid is not one of them"):
        run_sweep(dataset, [100], 2, methods=["hybrid"], progress=False, split_config=SMALL)
    with pytest.raises(SweepError, match="exceeds the training pool of 1500"):
        run_sweep(dataset, [3000], 2, progress=False, split_config=SMALL)


def test_sweep_cli_writes_results_csv_figures_and_a_table(session, tmp_path):
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["sweep", str(session), "-o", str(out), "--sizes", "150:450:300",
                                       "--trials", "2", "--epochs", "2", "--scale-to-data", "--no-progress"])
    assert result.exit_code == 0, result.output
    doc = json.loads((out / "results.json").read_text())
    for key in ("joints", "usable_fraction", "methods"):
        assert key in doc
    for m in doc["methods"].values():
        assert {"sizes", "mse_mean", "mse_ci95", "mse_trials"} <= set(m)
    assert (out / "results.csv").read_text().startswith("method,size,joint,mse_mean,mse_ci95")
    assert (out / "mse_vs_samples.png").stat().st_size > 10000
    assert (out / "window_torque.png").stat().st_size > 10000
    assert "mlp-masked" in result.output and "+-" in result.output


def test_sweep_cli_errors_are_one_sentence(session, tmp_path):
    runner = CliRunner()
    for args, fragment in ((["--sizes", "3:1"], "--sizes '3:1'"),
                           (["--methods", "svm"], "svm is not one of them"),
                           ([], "record longer or use --scale-to-data")):
        args = ["sweep", str(session), "-o", str(tmp_path / "x"), "--no-progress", *args]
        result = runner.invoke(main, args)
        assert result.exit_code != 0 and fragment in result.output and "Traceback" not in result.output


def test_fit_cli_saves_a_model_that_loads_and_predicts(session, tmp_path):
    runner = CliRunner()
    out = tmp_path / "rb"
    result = runner.invoke(main, ["fit", str(session), "--model", "rigid-body", "-o", str(out),
                                  "--effect", "coulomb", "--effect", "viscous:joint=joint2",
                                  "--scale-to-data", "--no-progress"])
    assert result.exit_code == 0, result.output
    assert "joint4" in result.output and "NMSE" in result.output
    model = load_model(out)
    assert [v["effect"] for v in model.effect_values()] == ["coulomb"] * 3 + ["viscous"]
    metrics = json.loads((out / "fit_metrics.json").read_text())
    assert metrics["test"]["nmse"]["joint2"] < 0.2
    bad = runner.invoke(main, ["fit", str(session), "--model", "mlp-mse", "-o", str(tmp_path / "m"),
                               "--effect", "coulomb", "--scale-to-data"])
    assert bad.exit_code != 0 and "apply to rigid-body and hybrid" in bad.output


def test_info_json(session):
    result = CliRunner().invoke(main, ["info", str(session), "--json"])
    doc = json.loads(result.output)
    assert doc["files"][0]["rate_hz"] == 500 and doc["files"][0]["samples"] == 75000
    assert set(doc["usable_fraction"]["per_joint"]) == {"joint1", "joint2", "joint4"}


def test_option_parsing():
    assert parse_sizes("300:3000:300") == list(range(300, 3001, 300))
    assert parse_sizes("10,20") == [10, 20]
    assert parse_effect("stribeck:joint=joint2,stribeck_velocity=0.05") == (
        "stribeck", "joint2", {"stribeck_velocity": 0.05})
    assert parse_effect("coulomb") == ("coulomb", None, None)


def test_config_file_overrides_defaults_and_bad_config_is_one_sentence(session, tmp_path):
    from train.settings import load_config

    cfg = tmp_path / "c.toml"
    cfg.write_text("[splits]\nn_pool = 1200\nn_val = 120\nn_test = 120\n[mlp]\nepochs = 2\n")
    loaded = load_config(cfg)
    assert loaded["splits"].n_pool == 1200 and loaded["mlp"].epochs == 2 and loaded["mlp"].hidden == 64
    assert loaded["preprocess"].cutoff_rad_s == 25.0
    out = tmp_path / "o"
    result = CliRunner().invoke(main, ["sweep", str(session), "-o", str(out), "--config", str(cfg),
                                       "--sizes", "300", "--trials", "2", "--methods", "mlp-masked",
                                       "--no-progress"])
    assert result.exit_code == 0, result.output
    assert json.loads((out / "results.json").read_text())["meta"]["splits"]["pool"] == 1200
    cfg.write_text("[mlp]\nepochz = 3\n")
    result = CliRunner().invoke(main, ["sweep", str(session), "-o", str(out), "--config", str(cfg)])
    assert result.exit_code != 0 and "unknown key(s) epochz in [mlp]" in result.output


def test_fit_with_a_custom_effect_from_the_users_file(session, tmp_path, monkeypatch):
    """`fit --effect-file mine.py --effect NAME:joint=...`: the user's effect becomes a fitted column, and
    the saved model records the file with its SHA-256: it loads without the effect in the library (in
    another process only with the file named again, tests/test_effects_as_data.py)."""
    import crane_io.physics.effects as fx

    monkeypatch.setattr(fx, "_REGISTRY", dict(fx._REGISTRY))  # the user effect leaves with the test
    user = tmp_path / "mine.py"
    user.write_text(
        "from crane_io.physics.effects.base import Effect, Param, joint_columns\n"
        "class Drag(Effect):\n"
        "    name = 'drag-test'\n"
        "    title = 'quadratic drag'\n"
        "    signature = 'the residual of {joint} grows with the square of its velocity'\n"
        "    params = (Param('drag', 'N m s^2/rad^2', 0.01, 'drag per (rad/s)^2'),)\n"
        "    def _columns(self, q, dq, ddq, joint, shape):\n"
        "        return joint_columns(len(q), q.shape[1], joint, dq[:, joint] * abs(dq[:, joint]))\n")
    out = tmp_path / "rb"
    result = CliRunner().invoke(main, ["fit", str(session), "--model", "rigid-body", "-o", str(out),
                                       "--effect-file", str(user), "--effect", "drag-test:joint=joint2",
                                       "--scale-to-data", "--no-progress"])
    assert result.exit_code == 0, result.output
    monkeypatch.setattr(fx, "_REGISTRY", {k: v for k, v in fx._REGISTRY.items() if k != "drag-test"})
    model = load_model(out)  # the effect from the file that ran for this fit, by its SHA-256
    assert [(v["effect"], v["joint"]) for v in model.effect_values()] == [("drag-test", "joint2")]
    spec = json.loads((out / "model.json").read_text())["options"]["effect_specs"][0]
    assert spec["kind"] == "user" and spec["file"] == str(user.resolve()) and len(spec["sha256"]) == 64
    q = np.zeros((2, 3))
    assert np.isfinite(model.predict(q, q + 0.5, q)).all()
    bad = CliRunner().invoke(main, ["fit", str(session), "--model", "rigid-body", "-o", str(tmp_path / "x"),
                                    "--effect", "nonexistent-effect", "--scale-to-data", "--no-progress"])
    assert bad.exit_code != 0 and bad.output.startswith("Error: ") and "Traceback" not in bad.output
