"""Learning and diagnosis for any joint subset: context joints in the rigid-body kinematics,
per-joint evaluation sets at many joints, `--joints all` through the command line, planted wrist effects.

The sessions are synthetic and made here WITHOUT the simulated plant: every arm joint (joint1..joint7)
either moves in strokes with stick phases (tests/sessions.py's stroke_trajectory) or is held at an angle;
the torque is crane_io.physics.dynamics.ArmDynamics over all seven joints (nothing locked but the gripper)
plus the friction, springs and noise a test plants, written in the session format (tests/sessions.py).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from crane_io.errors import ConfigError, CraneError
from crane_io.physics.dynamics import ArmDynamics
from tests.sessions import stroke_trajectory, write_minimal_session
from train.cli import main

ARM = ("joint1", "joint2", "joint3", "joint4", "joint5", "joint6", "joint7")
COLUMNS = ARM + ("gripper",)
CENTERS = {"joint1": 0.0, "joint2": 0.6, "joint3": 0.3, "joint4": -1.2, "joint5": 0.4, "joint6": 0.5,
           "joint7": 0.2}
PAPER = ("joint1", "joint2", "joint4")
_DYN = {}


def _dynamics():
    if "all" not in _DYN:
        _DYN["all"] = ArmDynamics(joints=ARM)
    return _DYN["all"]


def seven_joint_session(path, duration_s, *, moving=ARM, held=None, seed=0, coulomb=None, viscous=None,
                        spring=None, noise=0.003, rate_hz=500.0, stick_fraction=0.3):
    """Write a session of all 8 columns; joints in `moving` move in strokes (about 70 % of the time),
    the others are held at `held[name]` (default CENTERS). coulomb / viscous: {joint: N m, N m s/rad};
    spring: {joint: (stiffness, rest_angle)}. Returns the path and the noiseless truth."""
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * rate_hz))
    t = np.arange(n) / rate_hz
    q, dq, ddq = (np.zeros((n, 7)) for _ in range(3))
    held = dict(held or {})
    for j, name in enumerate(ARM):
        if name in moving:
            q[:, j], dq[:, j], ddq[:, j] = stroke_trajectory(duration_s, rate_hz, rng, stick_fraction,
                                                             amplitude=0.6, center=CENTERS[name])
        else:
            q[:, j] = held.get(name, CENTERS[name])
    tau = _dynamics().inverse_dynamics(q, dq, ddq)
    for name, fc in (coulomb or {}).items():
        j = ARM.index(name)
        mov = np.abs(dq[:, j]) > 1e-9
        wander = np.cumsum(rng.normal(0, 1, n))
        wander = fc * 0.8 * np.tanh(0.02 * (wander - wander.mean()))
        tau[:, j] += np.where(mov, fc * np.sign(dq[:, j]), wander)
    for name, fv in (viscous or {}).items():
        j = ARM.index(name)
        tau[:, j] += fv * dq[:, j]
    for name, (k, q0) in (spring or {}).items():
        j = ARM.index(name)
        tau[:, j] += k * (q[:, j] - q0)
    truth = tau.copy()
    q_rec = np.zeros((n, 8))
    tau_rec = np.zeros((n, 8))
    q_rec[:, :7] = q + rng.normal(0, 2e-4, q.shape)
    tau_rec[:, :7] = tau + rng.normal(0, noise, tau.shape)
    write_minimal_session(path, t, q_rec, tau_rec, COLUMNS, rate_hz, seed=seed)
    return path, {"q": q, "dq": dq, "ddq": ddq, "tau": truth}


def _dataset(path, joints=PAPER):
    from train.data.preprocess import PreprocessConfig, read_preprocessed

    return read_preprocessed([str(path)], PreprocessConfig(joints=tuple(joints)))


def _fit_rigid(ds, **options):
    from train.models.rigid_body import RigidBodyModel

    half = len(ds) // 2  # train on the first half, judge on the second (every row: no mask needed)
    train, test = ds.subset(np.arange(half)), ds.subset(np.arange(half, len(ds)))
    model = RigidBodyModel(ds.joint_names, **options).fit(train)
    err = test.tau - model.predict_dataset(test)
    return model, float(np.sqrt((err ** 2).mean())), test


# ---- context joints ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def context_sessions(tmp_path_factory):
    d = tmp_path_factory.mktemp("context")
    held, _ = seven_joint_session(d / "held.h5", 90, moving=PAPER,
                                  held={"joint3": 1.0, "joint5": -0.8, "joint6": 0.9, "joint7": 0.4}, seed=1)
    moving, _ = seven_joint_session(d / "moving.h5", 90, moving=PAPER + ("joint3", "joint5"),
                                    held={"joint6": 0.9, "joint7": 0.4}, seed=2)
    zeros, _ = seven_joint_session(d / "zeros.h5", 90, moving=PAPER,
                                   held={n: 0.0 for n in ARM if n not in PAPER}, seed=3)
    return {"held": held, "moving": moving, "zeros": zeros}


def test_a_subset_model_uses_the_held_joints_recorded_angles(context_sessions):
    ds = _dataset(context_sessions["held"])
    assert ds.context_names == ("joint3", "joint5", "joint6", "joint7")
    new, rms_new, _ = _fit_rigid(ds)
    old, rms_old, _ = _fit_rigid(ds, context=False)
    assert new.context_joints == ()  # held still: locked at the recorded medians, not free
    assert new.locked_resolved == pytest.approx({"joint3": 1.0, "joint5": -0.8, "joint6": 0.9, "joint7": 0.4},
                                                abs=2e-3)
    assert rms_new < 0.03, rms_new
    assert rms_new < 0.5 * rms_old, (rms_new, rms_old)


def test_a_subset_model_uses_the_moving_joints_recorded_motion(context_sessions, tmp_path):
    ds = _dataset(context_sessions["moving"])
    new, rms_new, test = _fit_rigid(ds)
    _, rms_old, _ = _fit_rigid(ds, context=False)
    assert new.context_joints == ("joint3", "joint5")
    assert rms_new < 0.05, rms_new
    assert rms_new < 0.3 * rms_old, (rms_new, rms_old)
    # the model records its context joints; data without them is refused in one sentence
    new.save(tmp_path / "m")
    doc = json.loads((tmp_path / "m" / "model.json").read_text())
    assert doc["state"]["context_joints"] == ["joint3", "joint5"]
    from train.models.registry import load_model

    again = load_model(tmp_path / "m")
    assert np.allclose(again.predict_dataset(test), new.predict_dataset(test))
    with pytest.raises(ConfigError) as exc:
        again.predict(test.q, test.dq, test.ddq)
    assert "joint3, joint5" in str(exc.value) and str(exc.value).count(". ") == 0
    # the control loop passes the model's own joints only: loading it for the loop is one sentence
    from crane_io.physics.loop_model import LoopModel, LoopModelError

    with pytest.raises(LoopModelError, match="context joints") as exc:
        LoopModel.load(tmp_path / "m")
    assert "\n" not in str(exc.value)


def test_three_joint_results_with_joints_held_at_zero_are_unchanged(context_sessions, tmp_path):
    """Held at 0 rad (what the old model assumed): the new model is the old one, and its loop export
    loads and agrees with it."""
    ds = _dataset(context_sessions["zeros"])
    new, rms_new, test = _fit_rigid(ds)
    old, rms_old, _ = _fit_rigid(ds, context=False)
    assert rms_new == pytest.approx(rms_old, rel=1e-3)
    assert np.allclose(new.theta, old.theta, rtol=1e-6, atol=1e-9)
    new.save(tmp_path / "m")
    from crane_io.physics.loop_model import LoopModel

    loop = LoopModel.load(tmp_path / "m")
    pred = new.predict_dataset(test)
    for i in range(0, len(test), max(len(test) // 5, 1)):
        got = loop.predict_one(test.q[i], test.dq[i], test.ddq[i])
        assert np.allclose(got, pred[i], rtol=1e-5, atol=1e-6)


def test_a_held_context_model_exports_to_the_loop_with_its_medians(context_sessions, tmp_path):
    ds = _dataset(context_sessions["held"])
    new, _, test = _fit_rigid(ds)
    new.save(tmp_path / "m")
    from crane_io.physics.loop_model import LoopModel

    loop = LoopModel.load(tmp_path / "m")
    pred = new.predict_dataset(test)
    for i in (0, len(test) // 2, len(test) - 1):
        got = loop.predict_one(test.q[i], test.dq[i], test.ddq[i])
        assert np.allclose(got, pred[i], rtol=1e-5, atol=1e-6)


def test_base_regressor_rows_equals_the_plain_one_for_every_row_and_fits_a_subset():
    dyn = ArmDynamics(joints=("joint1", "joint2", "joint4", "joint3"))
    rng = np.random.default_rng(0)
    q, dq, ddq = rng.uniform(-1, 1, (30, 4)), rng.normal(size=(30, 4)), rng.normal(size=(30, 4))
    plain = dyn.base_regressor(q, dq, ddq)
    assert np.array_equal(dyn.base_regressor_rows(q, dq, ddq, dyn.joint_names), plain)
    rows = ("joint1", "joint2", "joint4")
    y = dyn.base_regressor_rows(q, dq, ddq, rows) @ dyn.base_parameters_rows(rows)
    assert np.allclose(y, dyn.inverse_dynamics(q, dq, ddq)[:, :3], atol=1e-10)


# ---- splits at seven joints ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def seven(tmp_path_factory):
    """A short 7-joint session with a Coulomb friction on joint6 and a spring on joint5."""
    path, _ = seven_joint_session(tmp_path_factory.mktemp("seven") / "seven.h5", 60, seed=7,
                                  coulomb={"joint6": 0.3}, spring={"joint5": (1.5, 0.0)})
    return path


def test_per_joint_evaluation_sets_at_seven_joints(seven):
    from train.data.splits import SplitConfig, make_splits

    ds = _dataset(seven, ARM)
    assert ds.all_moving.mean() < 0.2
    cfg = SplitConfig(n_pool=1000, n_val=150, n_test=150)
    splits = make_splits(ds, cfg, seed=0)
    assert splits.test.meta["eval_set"] == "per-joint"
    assert (splits.test.moving.sum(axis=0) >= 150).all() and (splits.val.moving.sum(axis=0) >= 150).all()
    assert splits.test.moving.any(axis=1).all()
    used = [set(np.asarray(splits.index[k]).tolist()) for k in ("pool", "val", "test", "window")]
    assert all(not (a & b) for i, a in enumerate(used) for b in used[i + 1:])
    # the paper's all-moving sets on the same data need far more recording
    with pytest.raises(CraneError, match="need about"):
        make_splits(ds, SplitConfig(n_pool=1000, n_val=150, n_test=150, eval_set="all-moving"), seed=0)


def test_too_short_for_seven_joints_is_one_sentence_with_the_seconds_needed(seven):
    r = CliRunner().invoke(main, ["fit", str(seven), "--joints", "all", "--model", "rigid-body",
                                  "-o", "unused", "--no-progress"])
    assert r.exit_code != 0
    msg = r.output.strip()
    assert msg.startswith("Error: ") and msg.count("\n") == 0, msg
    assert "for 7 joints" in msg and "s of recording" in msg and "record longer" in msg


def _cli(args):
    return CliRunner().invoke(main, args)


def test_fit_sweep_diagnose_on_seven_joints_through_the_cli(seven, tmp_path):
    r = _cli(["info", str(seven), "--joints", "all", "--json"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    assert doc["joints"] == list(ARM)
    r = _cli(["fit", str(seven), "--joints", "all", "--model", "rigid-body", "--scale-to-data",
              "-o", str(tmp_path / "rb"), "--no-progress"])
    assert r.exit_code == 0, r.output
    metrics = json.loads((tmp_path / "rb" / "fit_metrics.json").read_text())
    assert set(metrics["test"]["mse"]) == set(ARM) and metrics["eval_set"] == "per-joint"
    r = _cli(["sweep", str(seven), "--joints", "all", "--scale-to-data", "--sizes", "300,900",
              "--trials", "2", "--epochs", "5", "-o", str(tmp_path / "sw"), "--no-progress"])
    assert r.exit_code == 0, r.output
    res = json.loads((tmp_path / "sw" / "results.json").read_text())
    assert res["joints"] == list(ARM)
    for m in ("rigid-body", "mlp-mse", "mlp-masked"):
        assert len(res["methods"][m]["mse_mean"][-1]) == 7
    for png in ("mse_vs_samples.png", "window_torque.png"):
        assert (tmp_path / "sw" / png).is_file()
    # diagnosis of the plain rigid-body model: the planted wrist effects are named first
    r = _cli(["diagnose", str(tmp_path / "rb"), str(seven), "--json"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    first = {j: min((c for c in doc["candidates"] if c["joint"] == j), key=lambda c: c["rank"])
             for j in ("joint5", "joint6")}
    assert first["joint6"]["effect"] == "coulomb", first["joint6"]
    assert first["joint5"]["effect"] == "spring", first["joint5"]


def test_adding_the_planted_wrist_effects_halves_their_error_compare_report_hybrid(seven, tmp_path):
    """fit with the diagnosed effects, a hybrid, then compare and report, all on seven joints."""
    common = [str(seven), "--joints", "all", "--scale-to-data", "--no-progress"]
    for name, extra in (("rb", ["--model", "rigid-body"]),
                        ("rb2", ["--model", "rigid-body", "--effect", "coulomb:joint=joint6",
                                 "--effect", "spring:joint=joint5"]),
                        ("hy", ["--model", "hybrid", "--epochs", "5"])):
        r = _cli(["fit", *common, *extra, "-o", str(tmp_path / name)])
        assert r.exit_code == 0, r.output
    r = _cli(["compare", str(tmp_path / "rb"), str(tmp_path / "rb2"), str(tmp_path / "hy"),
              "--session", str(seven), "--json"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    assert doc["joints"] == list(ARM)
    before, after = (doc["models"][k]["test"]["mse"] for k in (0, 1))
    for joint in ("joint5", "joint6"):
        assert after[joint] < 0.5 * before[joint], (joint, before[joint], after[joint])
    r = _cli(["report", str(tmp_path / "rb2"), str(seven), "-o", str(tmp_path / "r.html"),
              "--no-diagnosis"])
    assert r.exit_code == 0, r.output
    page = (tmp_path / "r.html").read_text()
    assert all(j in page for j in ARM)


def test_eval_set_option_and_the_model_records_it(seven, tmp_path):
    r = CliRunner().invoke(main, ["fit", str(seven), "--joints", "joint1,joint2,joint4",
                                  "--model", "rigid-body", "--eval-set", "per-joint", "--scale-to-data",
                                  "-o", str(tmp_path / "m"), "--no-progress"])
    assert r.exit_code == 0, r.output
    assert "each joint scored where it moves" in r.output
    assert json.loads((tmp_path / "m" / "fit_metrics.json").read_text())["eval_set"] == "per-joint"
    doc = json.loads((tmp_path / "m" / "model.json").read_text())
    assert doc["preprocessing"]["splits"] == {"eval_set": "per-joint"}
    # 3 joints by default: the paper's all-moving sets
    r = CliRunner().invoke(main, ["fit", str(seven), "--model", "rigid-body", "--scale-to-data",
                                  "-o", str(tmp_path / "p"), "--no-progress"])
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "p" / "fit_metrics.json").read_text())["eval_set"] == "all-moving"
