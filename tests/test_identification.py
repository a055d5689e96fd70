"""`crane-train identify` (train/identification): weighted least squares with block-jackknife errors, the
physically consistent projection (pseudo-inertia >= 0 for every body, an SDP) and the verdict."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from crane_io.physics.dynamics import ArmDynamics
from crane_io.physics.identified_model import IdentifiedArm, pseudo_inertia
from tests.sessions import write_synthetic_session
from train.cli import main as train_main
from train.evaluation.block_uncertainty import sample_blocks
from train.identification.consistency import body_summary, project
from train.identification.estimate import IdentificationError, weighted_least_squares

pytest.importorskip("cvxpy")


@pytest.fixture(scope="module")
def arm():
    return ArmDynamics()


def _exciting(arm, n, rng):
    t = np.arange(n) / 50.0
    q = np.stack([0.8 * np.sin(0.7 * t + 0.3), 0.6 + 0.5 * np.sin(1.1 * t),
                  -1.2 + 0.6 * np.sin(0.9 * t + 1)], 1)
    dq = np.stack([0.56 * np.cos(0.7 * t + 0.3), 0.55 * np.cos(1.1 * t), 0.54 * np.cos(0.9 * t + 1)], 1)
    ddq = np.stack([-0.392 * np.sin(0.7 * t + 0.3), -0.605 * np.sin(1.1 * t),
                    -0.486 * np.sin(0.9 * t + 1)], 1)
    return q, dq, ddq


def _blocks(n: int):
    return sample_blocks(np.arange(n, dtype=float), 50.0)


def _ar1(rng, shape, rho, sd):
    e = rng.normal(0, sd * np.sqrt(1 - rho ** 2), shape)
    for k in range(1, shape[0]):
        e[k] += rho * e[k - 1]
    return e


def test_the_estimate_recovers_the_truth_and_its_interval_covers_it_under_correlated_noise(arm):
    rng = np.random.default_rng(3)
    q, dq, ddq = _exciting(arm, 6000, rng)
    phi = arm.base_regressor(q, dq, ddq)
    truth = arm.base_parameters()
    hits, trials = 0, 12
    for k in range(trials):
        tau = phi @ truth + _ar1(np.random.default_rng(k), (6000, 3), 0.9, 0.02)
        est = weighted_least_squares(phi, tau, np.ones_like(tau, bool), _blocks(len(tau)))
        z = np.abs(est.theta - truth) / est.stderr
        hits += int(np.mean(z < 1.96) >= 0.8)
        assert np.all(est.stderr > 0)
    assert hits >= trials - 2
    assert est.condition < 1e4 and est.rows == 18000


def test_a_consistent_estimate_is_left_alone_and_an_inconsistent_one_is_projected(arm):
    rng = np.random.default_rng(0)
    q, dq, ddq = _exciting(arm, 3000, rng)
    phi = arm.base_regressor(q, dq, ddq)
    truth = arm.base_parameters()
    tau = phi @ truth + rng.normal(0, 0.01, (3000, 3))
    est = weighted_least_squares(phi, tau, np.ones_like(tau, bool), _blocks(len(tau)))
    k = arm.base_map_rows(arm.joint_names)
    proj = project(truth, est.cov, k, arm.standard_parameters(), arm.body_names(), np.zeros(0, bool))
    assert proj.as_estimated and np.allclose(proj.theta, truth, rtol=1e-5, atol=1e-8)
    # noise puts some estimates just outside the consistent set: moved back, within their uncertainty
    proj = project(est.theta, est.cov, k, arm.standard_parameters(), arm.body_names(), np.zeros(0, bool))
    assert proj.within_uncertainty
    # a base parameter no real arm has: the forearm's moment of inertia about its own joint axis negative
    bad = est.theta.copy()
    names = arm.base_parameter_names_rows(arm.joint_names)
    i = names.index("joint4.Iyy")
    bad[i] = -abs(bad[i])
    proj = project(bad, est.cov, k, arm.standard_parameters(), arm.body_names(), np.zeros(0, bool))
    assert not proj.as_estimated and not proj.within_uncertainty
    for b in range(len(arm.body_names())):
        v = proj.phi[10 * b:10 * b + 10]
        assert np.linalg.eigvalsh(pseudo_inertia(v)).min() > -1e-6 and v[0] > 0


def test_excitation_blocks_are_its_speeds_and_a_parameter_within_noise_of_zero_is_not_identifiable(arm):
    from train.evaluation.block_uncertainty import t_factor
    from train.identification.blocks import speed_blocks

    # two sessions (the first in two pieces), each 5 periods cycling through 3 speeds, at 10 Hz
    starts = np.array([0.0, 1.0, 3.0, 7.0, 8.0, 10.0])
    schedule = (starts, np.array([1.0, 0.5, 0.25, 1.0, 0.5]))
    t = np.concatenate([np.arange(0.0, 4.0, 0.1), np.arange(5.0, 10.0, 0.1), np.arange(0.0, 10.0, 0.1)])
    segment = np.repeat([0, 1, 2], [40, 50, 100])
    plan = speed_blocks(t, segment, t, segment, [schedule, schedule], 10.0)
    assert plan.count == 6
    speed = np.array([1.0, 0.5, 0.25, 1.0, 0.5])[np.clip(np.searchsorted(starts, t, "right") - 1, 0, 4)]
    for k in range(6):  # each block is one speed of one session
        rows = plan.ids == k
        assert len(set(speed[rows])) == 1 and len(set(segment[rows] == 2)) == 1
    assert speed_blocks(t, segment, t, segment, [schedule, None], 10.0) is None  # a bilateral session
    one_speed = (starts, np.ones(5))
    assert speed_blocks(t, segment, t, segment, [one_speed, one_speed], 10.0) is None
    # a parameter whose truth is zero is found within noise of zero: not identifiable; the others are
    rng = np.random.default_rng(5)
    q, dq, ddq = _exciting(arm, 3000, rng)
    phi = np.concatenate([arm.base_regressor(q, dq, ddq), np.sign(dq)[:, :, None] * np.eye(3)[None]], 2)
    truth = np.concatenate([arm.base_parameters(), [0.15, 0.25, 0.0]])
    est = weighted_least_squares(phi, phi @ truth + rng.normal(0, 0.01, (3000, 3)), np.ones((3000, 3), bool),
                                 _blocks(3000))
    assert not est.identifiable[-1] and est.identifiable[-3:-1].all()
    assert est.blocks >= 2 and np.allclose(est.interval95, t_factor(est.blocks) * est.stderr)


def test_a_body_summary_names_its_mass_and_moments():
    # a 1 kg point mass at x = 0.1 m from the joint: pseudo-inertia rank one, consistent at the edge
    phi = np.array([1.0, 0.1, 0, 0, 0, 0, 0.01, 0, 0, 0.01])
    s = body_summary("joint1", phi)
    assert s["mass"] == 1.0 and s["com"] == [pytest.approx(0.1), 0.0, 0.0]
    assert np.allclose(s["principal_moments"], 0, atol=1e-12)
    assert s["min_pseudo_inertia_eigenvalue"] > -1e-12


def test_a_joint_that_never_moves_is_refused_in_one_sentence(arm):
    rng = np.random.default_rng(1)
    q, dq, ddq = _exciting(arm, 500, rng)
    phi = arm.base_regressor(q, dq, ddq)
    moving = np.ones((500, 3), bool)
    moving[:, 2] = False
    with pytest.raises(IdentificationError, match="joint #3 moves in only 0 samples"):
        weighted_least_squares(phi, phi @ arm.base_parameters(), moving, _blocks(500))


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    path, _ = write_synthetic_session(tmp_path_factory.mktemp("id") / "s.h5", 200.0, rate_hz=100, seed=4)
    return path


def test_identify_writes_a_model_with_its_identification_and_a_verdict(session, tmp_path):
    out = tmp_path / "id"
    r = CliRunner().invoke(train_main, ["identify", str(session), "-o", str(out), "--scale-to-data",
                                       "--json", "--causal"])  # the filters of the control loop
    assert r.exit_code in (0, 1), r.output
    doc = json.loads(r.output)
    assert doc["format"] == "crane-identification" and doc["joints"] == ["joint1", "joint2", "joint4"]
    assert doc["filter"] == {"zero_phase": False, "cutoff_rad_s": 25.0}  # the settings' cutoff
    assert (out / "model.json").exists() and (out / "loop_model.npz").exists()
    assert json.loads((out / "identification.json").read_text())["verdict"] == doc["verdict"]
    friction = {p["name"]: p for p in doc["parameters"] if p["kind"] == "other"}
    # the session's truth: Coulomb 0.15 / 0.25 / 0.12 N m, viscous 0.05 / 0.08 / 0.04 N m s/rad
    for name, truth in (("coulomb.coulomb@joint1", 0.15), ("coulomb.coulomb@joint2", 0.25),
                        ("coulomb.coulomb@joint4", 0.12)):
        assert abs(friction[name]["consistent"] - truth) < 0.2 * truth, (name, friction[name])
    assert doc["consistency"]["within_uncertainty"]
    assert all(b["mass"] > 0 for b in doc["consistency"]["bodies"])
    names = [c["name"] for c in doc["verdict"]["checks"]]
    assert names == ["condition number", "parameter uncertainty", "physical consistency", "held-out error"]
    assert r.exit_code == (0 if doc["verdict"]["passed"] else 1)
    # the identified bodies as an arm model the dynamics read: its torques are the model's rigid-body part
    arm_model = IdentifiedArm.from_toml(out / "arm_model.toml")
    assert arm_model.free == ("joint1", "joint2", "joint4") and set(arm_model.friction) == set(arm_model.free)
    dyn = ArmDynamics(locked=arm_model.locked, identified=arm_model)  # the session held joint3 at 0.2 rad
    q, dq, ddq = np.array([[0.2, 0.7, -1.1]]), np.array([[0.3, -0.2, 0.1]]), np.array([[1.0, -2.0, 0.5]])
    base = np.array([p["consistent"] for p in doc["parameters"] if p["kind"] == "base"])
    assert np.allclose(dyn.inverse_dynamics(q, dq, ddq), dyn.base_regressor(q, dq, ddq) @ base, atol=1e-6)
    # the model folder is an ordinary rigid-body model: compare reads it
    r = CliRunner().invoke(train_main, ["compare", str(out), "--session", str(session)])
    assert r.exit_code == 0, r.output


def test_a_threshold_the_data_cannot_meet_fails_the_verdict_with_exit_1(session, tmp_path):
    r = CliRunner().invoke(train_main, ["identify", str(session), "-o", str(tmp_path / "id"),
                                       "--scale-to-data", "--max-condition", "1"])
    assert r.exit_code == 1, r.output
    assert "FAIL  condition number" in r.output and "verdict: FAIL" in r.output
    assert (tmp_path / "id" / "identification.json").exists()


def test_bad_thresholds_are_one_sentence(session, tmp_path):
    r = CliRunner().invoke(train_main, ["identify", str(session), "-o", str(tmp_path / "id"),
                                       "--negligible", "2"])
    assert r.exit_code == 2 and "Traceback" not in r.output and "--negligible" in r.output
    r = CliRunner().invoke(train_main, ["identify", str(session), "-o", str(tmp_path / "id"),
                                       "--cutoff", "0"])
    assert r.exit_code == 2 and "Traceback" not in r.output and "--cutoff" in r.output


def test_an_effect_can_be_identified_on_one_joint(session, tmp_path):
    r = CliRunner().invoke(train_main, ["identify", str(session), "-o", str(tmp_path / "id"),
                                       "--scale-to-data", "--json", "--effect", "viscous",
                                       "--effect", "coulomb:joint=joint2"])
    assert r.exit_code in (0, 1), r.output
    others = [p["name"] for p in json.loads(r.output)["parameters"] if p["kind"] == "other"]
    assert sorted(others) == ["coulomb.coulomb@joint2", "viscous.viscous@joint1", "viscous.viscous@joint2",
                              "viscous.viscous@joint4"]


def test_slow_samples_are_left_out_of_the_fit_and_an_effect_only_they_hold_is_refused(session, tmp_path):
    docs = {}
    for speed in ("0", None):
        args = ["identify", str(session), "-o", str(tmp_path / f"id{speed}"), "--scale-to-data", "--json"]
        r = CliRunner().invoke(train_main, args + (["--min-speed", speed] if speed else []))
        assert r.exit_code in (0, 1), r.output
        docs[speed] = json.loads(r.output)
    assert docs["0"]["min_speed"] == 0 and docs[None]["min_speed"] == 0.3
    assert docs[None]["filter"] == {"zero_phase": True, "cutoff_rad_s": 60.0}  # identify's zero-phase cutoff
    assert 0 < docs[None]["rows"] < docs["0"]["rows"]
    assert all(0 < v <= 0.3 for v in docs[None]["fit_speed"].values())
    assert all(v == 0 for v in docs["0"]["fit_speed"].values())
    r = CliRunner().invoke(train_main, ["identify", str(session), "-o", str(tmp_path / "s"),
                                       "--scale-to-data", "--effect", "stribeck:stribeck_velocity=0.05"])
    assert r.exit_code == 2 and "Traceback" not in r.output and "minimum speed of 0.3 rad/s" in r.output
    assert not (tmp_path / "s").exists()


def test_no_parameter_gets_a_smaller_standard_error_than_its_independent_sample_value():
    from train.evaluation.block_uncertainty import BlockPlan, least_squares_covariance

    rng = np.random.default_rng(1)
    n, p = 1000, 4
    phi = rng.normal(size=(n, 1, p))
    ids = np.repeat(np.arange(5), n // 5)
    offset = rng.normal(size=5)[ids]  # an error that differs between the blocks, in the first column only
    tau = phi @ np.array([1.0, -2.0, 0.5, 3.0]) + 0.1 * rng.normal(size=(n, 1)) \
        + 0.05 * offset[:, None] * phi[:, :, 0]
    a, y = phi[:, 0], tau[:, 0]
    resid = y - a @ np.linalg.lstsq(a, y, rcond=None)[0]
    iid = np.sqrt(np.diag(resid @ resid / (n - p) * np.linalg.inv(a.T @ a)))
    jack = np.sqrt(np.diag(least_squares_covariance(a, y, ids, 5)))
    assert jack[0] > 2 * iid[0] and np.any(jack[1:] < 0.99 * iid[1:])  # five blocks' spread: some below
    est = weighted_least_squares(phi, tau, np.ones((n, 1), bool), BlockPlan(ids, 5, 1.0, 0))
    assert est.blocks == 5  # the jackknife's covariance, not the textbook one
    assert np.all(est.stderr >= iid * (1 - 1e-9))
    assert est.stderr[0] == pytest.approx(jack[0], rel=1e-6)  # a larger jackknife variance is kept
