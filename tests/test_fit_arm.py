"""`crane-train fit --arm leader|follower`: the arm the operator's hand moved (root attribute
`hand_on`, "leader" when absent) holds the hand's force in its torque and is refused; the model records
the arm it was fitted on, and report/compare/diagnose evaluate on that arm."""

from __future__ import annotations

import json
import shutil

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from tests.sessions import write_synthetic_session
from train.cli import main
from train.data.session import HandOnArmError, read_sessions


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A synthetic session with a leader group: the follower's signals, the leader's torque scaled by 1.5
    (so a model of either arm is recognisably that arm's)."""
    path, _ = write_synthetic_session(tmp_path_factory.mktemp("arm") / "base.h5", 40, seed=11)
    with h5py.File(path, "a") as f:
        g = f.create_group("leader")
        g.create_dataset("t", data=f["follower/t"][()])
        g.create_dataset("q", data=f["follower/q"][()])
        g.create_dataset("tau", data=1.5 * f["follower/tau"][()])
    return path


def with_hand_on(base, path, value):
    shutil.copy(base, path)
    if value is not None:
        with h5py.File(path, "a") as f:
            f.attrs["hand_on"] = value
    return path


def run(*args):
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert "Traceback" not in result.output, result.output
    return result


def fit(session, out, *extra):
    return run("fit", session, "--model", "rigid-body", "--scale-to-data", "-o", out, *extra)


def saved_arm(model_dir):
    return json.loads((model_dir / "model.json").read_text())["preprocessing"]["arm"]


@pytest.mark.parametrize("hand", [None, "leader"])
def test_the_follower_fits_when_the_hand_was_on_the_leader(base, tmp_path, hand):
    session = with_hand_on(base, tmp_path / "s.h5", hand)
    result = fit(session, tmp_path / "m")  # --arm follower is the default
    assert result.exit_code == 0, result.output
    assert saved_arm(tmp_path / "m") == "follower"
    assert json.loads((tmp_path / "m" / "fit_metrics.json").read_text())["arm"] == "follower"
    assert "on the follower" in result.output


@pytest.mark.parametrize("hand", [None, "leader"])
def test_the_leader_is_refused_when_the_hand_moved_it(base, tmp_path, hand):
    session = with_hand_on(base, tmp_path / "s.h5", hand)
    before = session.read_bytes()
    result = fit(session, tmp_path / "m", "--arm", "leader")
    assert result.exit_code != 0
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: ")
    assert "hand moved the leader" in lines[0] and "hand_on = leader" in lines[0]
    assert "crane-collect run --hand-on follower" in lines[0]
    assert not (tmp_path / "m").exists()
    assert session.read_bytes() == before


def test_the_leader_fits_when_the_hand_was_on_the_follower(base, tmp_path):
    from train.models.registry import load_model

    session = with_hand_on(base, tmp_path / "s.h5", "follower")
    result = fit(session, tmp_path / "m", "--arm", "leader")
    assert result.exit_code == 0, result.output
    assert saved_arm(tmp_path / "m") == "leader"
    assert "on the leader" in result.output
    # the leader's torque (1.5 x the follower's) is what was fitted: a linear fit's prediction is 1.5 x
    # the follower model's
    assert fit(with_hand_on(base, tmp_path / "f.h5", None), tmp_path / "f").exit_code == 0
    lead, fol = load_model(tmp_path / "m"), load_model(tmp_path / "f")
    raw = read_sessions([session], "leader")[0]
    cols = [raw.joint_names.index(j) for j in lead.joint_names]
    q = raw.q[::200][:, cols]
    dq = np.full_like(q, 0.3)
    np.testing.assert_allclose(lead.predict(q, dq, dq), 1.5 * fol.predict(q, dq, dq), rtol=0.05, atol=0.02)


def test_the_follower_is_refused_when_the_hand_moved_it(base, tmp_path):
    session = with_hand_on(base, tmp_path / "s.h5", "follower")
    result = fit(session, tmp_path / "m")
    assert result.exit_code != 0
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and "hand moved the follower" in lines[0] and "hand_on = follower" in lines[0]
    assert not (tmp_path / "m").exists()


def test_the_library_error_names_the_attribute_not_the_command_line(base, tmp_path):
    session = with_hand_on(base, tmp_path / "s.h5", "leader")
    with pytest.raises(HandOnArmError) as info:
        read_sessions([session], "leader", hand_free=True)
    assert "hand_on = leader" in str(info.value) and "--" not in str(info.value)
    assert info.value.arm == "leader"
    assert len(read_sessions([session], "leader")) == 1  # reading without hand_free stays possible


def test_an_unknown_hand_on_value_is_one_sentence(base, tmp_path):
    session = with_hand_on(base, tmp_path / "s.h5", "both")
    result = fit(session, tmp_path / "m")
    assert result.exit_code != 0 and "hand_on = 'both'" in result.output


def test_evaluation_commands_use_the_models_arm(base, tmp_path):
    session = with_hand_on(base, tmp_path / "s.h5", "follower")
    assert fit(session, tmp_path / "lead", "--arm", "leader").exit_code == 0
    result = run("compare", tmp_path / "lead", "--session", session, "--json")
    assert result.exit_code == 0, result.output
    doc = json.loads(result.output)
    assert doc["models"][0]["arm"] == "leader"
    # evaluated on the leader's data: the same test error as fit measured on them (the follower's torque,
    # 1/1.5 of the leader's, would give another)
    fitted = json.loads((tmp_path / "lead" / "fit_metrics.json").read_text())["test"]["mse"]
    for joint, value in fitted.items():
        assert doc["models"][0]["test"]["mse"][joint] == pytest.approx(value, rel=1e-6)
    result = run("diagnose", tmp_path / "lead", session, "--json", "--folds", 2)
    assert result.exit_code == 0, result.output
    result = run("report", tmp_path / "lead", session, "-o", tmp_path / "r.html", "--no-diagnosis")
    assert result.exit_code == 0, result.output
    # the same model on a session where the hand moved the leader: refused
    other = with_hand_on(base, tmp_path / "o.h5", "leader")
    result = run("compare", tmp_path / "lead", "--session", other)
    assert result.exit_code != 0 and "hand moved the leader" in result.output


def test_info_describes_either_arm(base, tmp_path):
    session = with_hand_on(base, tmp_path / "s.h5", "follower")
    result = run("info", session, "--arm", "leader", "--json")
    assert result.exit_code == 0, result.output
    doc = json.loads(result.output)
    assert doc["arm"] == "leader" and doc["files"][0]["hand_on"] == "follower"
