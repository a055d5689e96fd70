"""crane-train used as a lab user uses it: command-line behaviour found by trying every command on
recorded and hand-made files (options that must take effect, errors that must be one sentence)."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
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


# the documented example effect under its own name (the effect registry is shared within the run)
CABLE_DRAG = (Path(__file__).parents[1] / "docs" / "examples" / "cable_drag.py").read_text().replace(
    'name = "cable-drag"', 'name = "cable-drag-user-test"')


def test_a_model_with_a_user_effect_file_given_relative_loads_only_with_that_file_named(session, tmp_path,
                                                                                       monkeypatch):
    from crane_io.physics.effects import spec

    work = tmp_path / "work"
    work.mkdir()
    (work / "my_effects.py").write_text(CABLE_DRAG)
    monkeypatch.chdir(work)
    result = run("fit", session, "--model", "rigid-body", "--scale-to-data", "--effect-file", "my_effects.py",
                 "--effect", "cable-drag-user-test:joint=joint1", "-o", "models/drag")
    assert result.exit_code == 0, result.output
    monkeypatch.chdir(tmp_path)  # elsewhere, as a later session in another terminal would be
    monkeypatch.setattr(spec, "_RUN", {})  # as in a new process: the file has not run there
    monkeypatch.setattr(spec, "_OFFERED", {})
    result = run("compare", "work/models/drag", "--session", session)
    assert result.exit_code == 2 and result.output.startswith("Error: ") and result.output.count("\n") == 1
    assert "my_effects.py" in result.output and "--effect-file" in result.output
    result = run("compare", "work/models/drag", "--session", session, "--effect-file", "work/my_effects.py")
    assert result.exit_code == 0, result.output


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
    assert "Split seed 0. None of these samples" in out


def test_the_same_session_twice_is_refused(session):
    result = run("info", session, session.parent / "." / session.name)
    assert result.exit_code == 2 and result.output.startswith("Error: ") and "is given twice" in result.output


def test_a_session_too_short_to_preprocess_says_how_long_it_must_be(tmp_path):
    path, _ = write_synthetic_session(tmp_path / "short.h5", 0.2, seed=1)  # 100 samples at 500 Hz
    result = run("info", path)
    assert result.exit_code == 2 and result.output.startswith("Error: ")
    assert "short.h5 is too short to preprocess" in result.output and "0.24 s are needed" in result.output


def test_a_held_joint_that_only_jitters_by_an_encoder_count_never_moves(tmp_path):
    # joint3 is held in position mode by crane-collect: its angle toggles between -1, 0 and +1 encoder
    # counts, so its velocity has a tiny but non-zero spread that the dead-zone mask would call motion
    path, _ = write_synthetic_session(tmp_path / "s.h5", 30, seed=2)
    with h5py.File(path, "a") as f:
        q = f["follower/q"][()]
        q[:, 2] = np.random.default_rng(0).integers(-1, 2, len(q)) * 2 * np.pi / 4096
        f["follower/q"][...] = q
    result = run("info", path, "--joints", "joint3")
    assert result.exit_code == 2 and result.output.startswith("Error: joint3 never moves in the data")
    result = run("fit", path, "--joints", "joint1,joint3", "--model", "rigid-body", "--scale-to-data",
                 "-o", tmp_path / "m")
    assert result.exit_code == 2 and "joint3 never moves" in result.output


@pytest.fixture(scope="module")
def models(session, tmp_path_factory):
    root = tmp_path_factory.mktemp("models")
    for method in ("rigid-body", "mlp-masked"):
        result = run("fit", session, "--model", method, "--scale-to-data", "--epochs", 2, "-o", root / method)
        assert result.exit_code == 0, result.output
    return root


DAMAGE = {  # what a damaged model directory looks like -> what the sentence must say
    "junk weights": ("mlp-masked", "mlp.pt", b"junk\n", "mlp.pt is corrupt"),
    "empty weights": ("mlp-masked", "mlp.pt", b"", "mlp.pt is corrupt"),
    "junk parameters": ("rigid-body", "rigid_body.npz", b"junk\n", "rigid_body.npz is corrupt"),
    "model.json without joints": ("rigid-body", "model.json",
                                  b'{"format": "crane-model", "format_version": 1, "method": "rigid-body"}',
                                  "model.json lacks 'joint_names'"),
}


@pytest.mark.parametrize("case", sorted(DAMAGE))
def test_a_damaged_model_directory_is_one_plain_sentence(models, tmp_path, case):
    import shutil

    method, name, content, fragment = DAMAGE[case]
    broken = tmp_path / "broken"
    shutil.copytree(models / method, broken)
    (broken / name).write_bytes(content)
    result = run("compare", broken)
    assert result.exit_code == 2 and result.output.startswith("Error: ") and fragment in result.output
    # no library internals (pickle advice, a torch magic number, a KeyError repr in parentheses)
    assert "pickle" not in result.output and "(" not in result.output, result.output


@pytest.mark.parametrize("velocity", ["-1", "0"])
def test_an_effect_shape_that_adds_nothing_is_refused_not_silently_ignored(session, tmp_path, velocity):
    # a Stribeck velocity <= 0 makes the effect's column zero: the "model with Stribeck" was the plain one
    result = run("fit", session, "--model", "rigid-body", "--scale-to-data", "-o", tmp_path / "m",
                 "--effect", f"stribeck:joint=joint2,stribeck_velocity={velocity}")
    assert result.exit_code == 2 and result.output.startswith("Error: effect stribeck on joint2 with "
                                                             f"stribeck_velocity={velocity} adds nothing")
    assert not (tmp_path / "m").exists()


def test_an_arm_wide_effect_given_a_joint_is_refused(session, tmp_path):
    result = run("fit", session, "--model", "rigid-body", "--scale-to-data", "-o", tmp_path / "m",
                 "--effect", "payload:joint=joint1")
    assert result.exit_code == 2 and "payload acts on the whole arm" in result.output
    result = run("fit", session, "--model", "rigid-body", "--scale-to-data", "-o", tmp_path / "m",
                 "--effect", "payload")
    assert result.exit_code == 0, result.output


def test_an_output_under_a_file_is_one_sentence_before_any_work(session, models, tmp_path):
    blocker = tmp_path / "notes.txt"
    blocker.write_text("a file where a folder was meant")
    commands = {
        "fit": ["fit", session, "--model", "rigid-body", "--scale-to-data", "-o", blocker / "model"],
        "sweep": ["sweep", session, "--sizes", "50", "--trials", "2", "--epochs", "1", "--scale-to-data",
                  "-o", blocker / "sweep"],
        "report": ["report", models / "rigid-body", session, "-o", blocker / "r.html"],
        "compare": ["compare", models / "rigid-body", "-o", blocker / "c.png"],
    }
    for name, args in commands.items():
        result = run(*args)
        assert result.exit_code == 2, (name, result.output)
        assert result.output.startswith(f"Error: cannot write {blocker}/"), (name, result.output)
        assert "is a file, not a folder" in result.output, (name, result.output)
    assert blocker.read_text() == "a file where a folder was meant"
