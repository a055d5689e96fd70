"""`crane-train fit --model rigid-body --start-from arm_model.toml`: the fit starts from an identified arm
model and is regularised towards it (train/models/rigid_body_prior.py), and the model records it."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from crane_io.errors import ConfigError
from crane_io.physics.dynamics import ArmDynamics
from crane_io.physics.identified_model import IdentifiedArm
from tests.sessions import write_synthetic_session
from train.api import fit, load_model
from train.cli import main as train_main

EFFECTS = ("viscous", "coulomb")


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """A short synthetic session, the plain fit on it, and an arm model whose bodies are 30 % heavier
    than the description's (so the start is far from what the data say) with friction of its own."""
    tmp = tmp_path_factory.mktemp("start")
    session, _ = write_synthetic_session(tmp / "s.h5", 60.0, rate_hz=100, seed=3)
    plain = fit([str(session)], "rigid-body", effects=EFFECTS, scale_to_data=True)
    model = plain.model
    joints = model.joint_names
    dyn = ArmDynamics(joints, locked=model.locked_resolved)
    phi = dyn.standard_parameters() * 1.3
    bodies = {n: phi[10 * b:10 * b + 10].copy() for b, n in enumerate(dyn.body_names())}
    friction = {j: {"viscous": 0.5, "coulomb": 0.9} for j in joints}
    arm = IdentifiedArm(tuple(joints), dict(model.locked_resolved), bodies, 0.0, friction)
    path = tmp / "arm_model.toml"
    path.write_text(arm.to_toml())
    return tmp, session, plain, dyn, path


def _start_fit(session, path, weight):
    return fit([str(session)], "rigid-body", effects=EFFECTS, scale_to_data=True, start_from=path,
               start_weight=weight).model


def test_a_heavy_weight_keeps_the_identified_parameters_and_a_light_one_gives_the_plain_fit(setup):
    _, session, plain, dyn, path = setup
    held = _start_fit(session, path, 1e12)
    n = held.n_base
    expected_base = dyn.base_map_rows(held.joint_names) @ (dyn.standard_parameters() * 1.3)
    assert np.allclose(held.theta[:n], expected_base, rtol=1e-4, atol=1e-6)
    friction = dict(zip(held.names[n:], held.theta[n:]))
    assert friction["viscous.viscous@joint2"] == pytest.approx(0.5, rel=1e-4)
    assert friction["coulomb.coulomb@joint4"] == pytest.approx(0.9, rel=1e-4)
    free = _start_fit(session, path, 1e-6)
    assert np.allclose(free.theta, plain.model.theta, rtol=1e-4, atol=1e-6)
    middle = _start_fit(session, path, 100.0)  # pulled towards the start, not onto it
    gap = np.linalg.norm(held.theta - plain.model.theta)
    assert 0.01 * gap < np.linalg.norm(middle.theta - plain.model.theta)
    assert 0.01 * gap < np.linalg.norm(middle.theta - held.theta) < gap
    assert middle.fit_info["start"] == {"arm_model": str(path), "weight": 100.0}


def test_the_cli_fit_records_the_start_and_the_saved_model_predicts_alike(setup):
    tmp, session, _, _, path = setup
    out = tmp / "started"
    r = CliRunner().invoke(train_main, ["fit", str(session), "--model", "rigid-body", "--effect", "viscous",
                                        "--effect", "coulomb", "--scale-to-data", "--start-from", str(path),
                                        "--start-weight", "50", "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert f"started from the identified arm model {path} (weighing as much as 50 torque" in r.output
    options = json.loads((out / "model.json").read_text())["options"]
    assert options["start_weight"] == 50.0 and options["start_from"]["free"] == ["joint1", "joint2", "joint4"]
    again = load_model(out)
    direct = _start_fit(session, path, 50.0)
    assert np.allclose(again.theta, direct.theta)


def test_a_start_that_does_not_fit_is_one_sentence(setup, tmp_path):
    _, session, plain, _, path = setup
    r = CliRunner().invoke(train_main, ["fit", str(session), "--model", "mlp-mse", "--start-from", str(path),
                                        "-o", str(tmp_path / "m")])
    assert r.exit_code == 2 and "applies to the rigid-body model" in r.output and "Traceback" not in r.output
    arm = IdentifiedArm.from_toml(path)
    arm.locked = {**arm.locked, "joint3": arm.locked.get("joint3", 0.0) + 0.5}
    other = tmp_path / "other.toml"
    other.write_text(arm.to_toml())
    with pytest.raises(ConfigError, match="joint3 held at .* cannot start from it"):
        _start_fit(session, other, 100.0)
    r = CliRunner().invoke(train_main, ["fit", str(session), "--model", "rigid-body", "--start-from",
                                        str(path), "--start-weight", "0", "-o", str(tmp_path / "m")])
    assert r.exit_code == 2 and "--start-weight" in r.output
