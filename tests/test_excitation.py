"""Exciting trajectories (crane_io/physics/excitation_*.py) and `crane-collect excite`
(collect/excitation.py)."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from collect.cli import main
from collect.config import load_config
from collect.excitation import design_space, models
from crane_io import session_format as sf
from crane_io.description import default_arm
from crane_io.errors import ConfigError
from crane_io.physics import excitation_trajectory as et
from crane_io.physics.excitation_design import optimise, trajectory

JOINTS = ("joint1", "joint2", "joint4")


@pytest.fixture(scope="module")
def setting():
    config = load_config(None)
    space, _ = design_space(config, default_arm(), JOINTS, 2.0)
    dynamics, clearance = models(config, JOINTS)
    return space, dynamics, clearance


def _fine(traj):
    return traj.evaluate(np.linspace(0.0, traj.period, 20001))


def test_any_variables_give_a_trajectory_within_the_limits_that_starts_and_ends_at_rest(setting):
    space, _, _ = setting
    rng = np.random.default_rng(3)
    for scale in (0.1, 1.0, 10.0):
        traj = trajectory(rng.normal(0.0, scale, space.size), space)
        q, dq, ddq = _fine(traj)
        assert np.all(q >= space.lower) and np.all(q <= space.upper)
        assert np.all(np.abs(dq) <= space.vmax)
        assert np.all(np.abs(ddq) <= space.amax)
        assert traj.at_rest()
        assert np.allclose(dq[[0, -1]], 0.0, atol=1e-9) and np.allclose(ddq[[0, -1]], 0.0, atol=1e-9)
    # the largest swing fills its limit: the scaling is not needlessly timid
    assert np.max(np.abs(dq) / space.vmax) > 0.95 or np.max(np.abs(ddq) / space.amax) > 0.95


def test_the_optimiser_lowers_the_condition_number_and_keeps_clear(setting):
    space, dynamics, clearance = setting
    lines = []
    result = optimise(space, dynamics, clearance, seed=1, evaluations=80, progress=lines.append,
                      progress_every=40)
    assert result.trajectory.condition_number < result.initial_condition
    assert result.clearance >= space.min_clearance
    assert result.evaluations == 80 and len(lines) == 2 and "best condition number" in lines[0]
    q, dq, ddq = result.trajectory.evaluate(np.linspace(0.0, space.period, 60, endpoint=False))
    assert et.regressor_condition(dynamics, q, dq, ddq) == pytest.approx(result.trajectory.condition_number)


def test_a_saved_trajectory_reads_back_the_same(setting, tmp_path):
    space, _, _ = setting
    traj = trajectory(np.random.default_rng(0).normal(0.0, 0.5, space.size), space, periods=3)
    traj = traj.with_condition(42.5)
    path = et.save(traj, tmp_path / "t.json")
    back = et.load(path)
    assert back == traj and back.condition_number == 42.5 and back.periods == 3
    t = np.linspace(0.0, traj.duration, 97)
    for a, b in zip(traj.evaluate(t), back.evaluate(t)):
        np.testing.assert_array_equal(a, b)


def test_periods_played_at_their_speeds_join_at_rest_and_stay_within_the_limits(setting, tmp_path):
    from collect.excitation import SPEED_CYCLE, speed_schedule

    space, _, _ = setting
    base = trajectory(np.random.default_rng(2).normal(0.0, 0.5, space.size), space)
    traj = base.with_periods(4, (1.0, 0.5))
    assert traj.duration == pytest.approx(base.period * (1 + 2 + 1 + 2))
    starts = traj.period_starts()
    t = np.linspace(0.0, traj.duration, 24001)
    q, dq, ddq = traj.play(t)
    assert np.all(np.abs(dq) <= space.vmax) and np.all(np.abs(ddq) <= space.amax)
    q_joins, dq_joins, _ = traj.play(starts)
    np.testing.assert_allclose(q_joins, np.repeat(base.start()[None], 5, axis=0), atol=1e-9)
    np.testing.assert_allclose(dq_joins, 0.0, atol=1e-9)
    # the second period is the first's path at half the speed
    _, dq_fast, _ = traj.play(0.3 * base.period)
    _, dq_slow, _ = traj.play(starts[1] + 0.6 * base.period)
    np.testing.assert_allclose(dq_slow, 0.5 * dq_fast, atol=1e-12)
    back = et.load(et.save(traj, tmp_path / "t.json"))
    assert back == traj and back.speeds == (1.0, 0.5) and back.periods_within(traj.duration) == 4
    old = {k: v for k, v in traj.to_dict().items() if k != "speeds"} | {"version": 1}
    assert et.from_dict(old).speeds == (1.0,)
    period, speeds, periods = speed_schedule(180.0)  # a long run cycles through the speeds
    assert speeds == SPEED_CYCLE and period * sum(1 / s for s in speeds) * periods / len(speeds) \
        == pytest.approx(180.0)
    assert speed_schedule(20.0) == (10.0, (1.0,), 2)


@pytest.mark.parametrize("change, words", [
    ({"format": "python"}, "is not an excitation trajectory"),
    ({"w_f": -1.0}, "positive `w_f`"),
    ({"a": [[1.0, 2.0]]}, "`b` as finite numbers"),
    ({"q0": "__import__('os')"}, "`q0` as"),
    ({"extra": 1}, "unknown key 'extra'"),
    ({"periods": 0}, "`periods`"),
    ({"speeds": [1.0, 1.5]}, "`speeds`"),
])
def test_a_bad_trajectory_file_is_refused_in_one_sentence(setting, tmp_path, change, words):
    space, _, _ = setting
    d = trajectory(np.zeros(space.size), space).to_dict()
    d.update(change)
    (tmp_path / "bad.json").write_text(json.dumps(d))
    with pytest.raises(ConfigError, match=words.replace("(", r"\(").replace("`", "`")):
        et.load(tmp_path / "bad.json")


def test_excite_refuses_a_bad_trajectory_file_with_exit_2(tmp_path):
    (tmp_path / "bad.json").write_text("{not json")
    res = CliRunner().invoke(main, ["excite", "--sim", "-o", str(tmp_path / "s.h5"), "--trajectory",
                                    str(tmp_path / "bad.json"), "--quiet"])
    assert res.exit_code == 2
    lines = [ln for ln in res.output.strip().splitlines() if ln]
    assert len(lines) == 1 and "is not JSON" in lines[0] and "Traceback" not in res.output
    assert not (tmp_path / "s.h5").exists()


@pytest.fixture(scope="module")
def excitation_session(tmp_path_factory):
    folder = tmp_path_factory.mktemp("excite")
    out = folder / "e.h5"
    res = CliRunner().invoke(main, ["excite", "--sim", "--duration", "2", "--budget", "30", "-o", str(out)])
    assert res.exit_code == 0, res.output
    return out, res.output


def test_excite_sim_records_a_session_marked_as_excitation(excitation_session):
    from train.data.session import read_session

    out, text = excitation_session
    assert "condition number" in text and "saved to" in text and "followed its reference within" in text
    with h5py.File(out, "r") as f:
        attrs = dict(f.attrs)
        q = f["follower/q"][:]
        lead = f["leader/q"][:]
    assert attrs[sf.EXCITATION_ATTR] and attrs[sf.EXCITATION_ARM_ATTR] == "follower"
    assert attrs[sf.END_REASON_ATTR] == "duration" and attrs[sf.HAND_ON] == "leader"
    traj = et.from_dict(json.loads(attrs[sf.EXCITATION_TRAJECTORY_ATTR]))
    saved = et.load(out.with_name("e.trajectory.json"))
    assert traj == saved and traj.joints == JOINTS and traj.duration == pytest.approx(2.0)
    start = float(attrs[sf.EXCITATION_START_ATTR])
    assert len(q) == round((start + traj.duration + 0.5) * 500)
    # the follower moved along the trajectory, the leader stayed where it was
    k0, k1 = round(start * 500), round((start + traj.duration) * 500)
    cols = [0, 1, 3]
    assert np.ptp(q[k0:k1, cols], axis=0).max() > 0.2
    assert np.ptp(lead[:, cols], axis=0).max() < 0.05
    # never past a joint limit, never into the table or its own links
    arm = default_arm()
    lower, upper = np.array([j.lower for j in arm.joints]), np.array([j.upper for j in arm.joints])
    assert np.all(q >= lower) and np.all(q <= upper)
    _, clearance = models(load_config(None), JOINTS)
    assert clearance.clearance(q[::25, cols]).min() > 0.0
    session = read_session(out)  # what crane-train fit / sweep / diagnose / info read
    assert len(session.t) == len(q) and session.attrs[sf.EXCITATION_ATTR]
    from train.cli import main as train_main

    info = CliRunner().invoke(train_main, ["info", str(out), "--json"])
    assert info.exit_code == 0, info.output
    assert json.loads(info.output)["files"][0]["excitation_arm"] == "follower"
    info = CliRunner().invoke(train_main, ["info", str(out)])
    assert "excitation data (the follower alone)" in info.output and "hand on the" not in info.output


def test_a_saved_trajectory_replays_with_its_condition_number(excitation_session, tmp_path):
    out, _ = excitation_session
    saved = out.with_name("e.trajectory.json")
    res = CliRunner().invoke(main, ["excite", "--sim", "--trajectory", str(saved), "-o",
                                    str(tmp_path / "r.h5"), "--joints", "joint1,joint2"])
    assert res.exit_code == 2 and "this run's joints are joint1, joint2" in res.output
    with pytest.raises(ConfigError, match="leaves this run's speed limits"):
        from collect.excitation import check_trajectory

        space, _ = design_space(load_config(None), default_arm(), JOINTS, 2.0)
        traj = et.load(saved)
        fast = et.FourierTrajectory(traj.joints, traj.w_f, traj.q0, 3 * traj.a, 3 * traj.b)
        check_trajectory(fast, space, models(load_config(None), JOINTS)[1], "the trajectory")
