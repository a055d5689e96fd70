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


CABLE_DRAG = '''
import numpy as np
from crane_io.effects import Effect, Param
from crane_io.effects.base import joint_columns

class CableDrag(Effect):
    name = "cable-drag-user-test"
    title = "cable drag"
    description = "A cable that pulls harder the further the joint turns: c q |q|."
    signature = "the residual of {joint} grows with the square of its angle"
    params = (Param("drag", "N m/rad^2", 0.1, "drag per rad squared"),)

    def _columns(self, q, dq, ddq, joint, shape):
        return joint_columns(len(q), q.shape[1], joint, q[:, joint] * np.abs(q[:, joint]))
'''


def test_a_model_with_a_user_effect_file_given_relative_loads_from_any_directory(session, tmp_path,
                                                                                 monkeypatch):
    work = tmp_path / "work"
    work.mkdir()
    (work / "my_effects.py").write_text(CABLE_DRAG)
    monkeypatch.chdir(work)
    result = run("fit", session, "--model", "rigid-body", "--scale-to-data", "--effect-file", "my_effects.py",
                 "--effect", "cable-drag-user-test:joint=joint1", "-o", "models/drag")
    assert result.exit_code == 0, result.output
    monkeypatch.chdir(tmp_path)  # elsewhere, as a later session in another terminal would be
    result = run("compare", "work/models/drag", "--session", session)
    assert result.exit_code == 0, result.output
    (work / "my_effects.py").unlink()
    result = run("compare", "work/models/drag", "--session", session)
    assert result.exit_code == 2 and result.output.startswith("Error: ")
    assert "my_effects.py" in result.output and "fit the model again" in result.output


def test_compare_from_another_directory_prints_each_models_notes(session, tmp_path, monkeypatch):
    other, _ = write_synthetic_session(tmp_path / "other.h5", 60, seed=6)
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    (work / "s.h5").write_bytes(session.read_bytes())
    fits = {"base": [], "zp": ["--zero-phase"], "seed4": ["--seed", "4"], "both": [other]}
    for name, extra in fits.items():
        result = run("fit", "s.h5", *extra, "--model", "rigid-body", "--scale-to-data",
                     "-o", f"models/{name}")
        assert result.exit_code == 0, result.output
    monkeypatch.chdir(tmp_path)  # the sessions default to those of the first model, found from here too
    result = run("compare", *(f"work/models/{name}" for name in fits))
    assert result.exit_code == 0, result.output
    out = result.output
    assert "Note on 2. zp: preprocessed with its own settings (zero_phase True instead of False)" in out
    assert "Note on 3. seed4: trained with split seed 4, not 0" in out
    assert "Note on 4. both: trained on s.h5, other.h5, not on exactly the evaluated sessions" in out
    assert "Note on 1." not in out
