"""crane-train used as a lab user uses it: command-line behaviour found by trying every command on
recorded and hand-made files (options that must take effect, errors that must be one sentence)."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from tests.sessions import write_synthetic_session
from train.cli import main


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    path, _ = write_synthetic_session(tmp_path_factory.mktemp("user") / "s.h5", 60, seed=5)
    return path


def run(*args):
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert "Traceback" not in result.output, result.output
    return result


def test_fit_hybrid_takes_seed_and_epochs_for_its_network(session, tmp_path):
    result = run("fit", session, "--model", "hybrid", "--scale-to-data", "--seed", 3, "--epochs", 2,
                 "-o", tmp_path / "h")
    assert result.exit_code == 0, result.output
    options = json.loads((tmp_path / "h" / "model.json").read_text())["options"]
    assert options["seed"] == 3 and options["epochs"] == 2
    net = json.loads((tmp_path / "h" / "mlp" / "model.json").read_text())["options"]
    assert net["seed"] == 3 and net["epochs"] == 2


@pytest.mark.parametrize("epochs", ["0", "-3"])
def test_fit_refuses_a_number_of_epochs_below_one(session, tmp_path, epochs):
    result = run("fit", session, "--model", "mlp-mse", "--scale-to-data", "--epochs", epochs,
                 "-o", tmp_path / "m")
    assert result.exit_code == 2 and "Error:" in result.output and "--epochs" in result.output
    assert not (tmp_path / "m").exists()
