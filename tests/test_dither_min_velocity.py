"""The friction dither's velocity floor ([controller.jointN] dither_min_velocity; collect/controller.py
`_dither`, docs/collect.md "A velocity floor for heavy poses"): off by default and then without a trace;
on, that joint's amplitude is at least v 2 pi f J_j(q) with the follower's pose-dependent nominal inertia,
its sign (antiphase) kept, other joints and undithered joints left alone; in a simulated run it lowers
joint 1's false force where the joint stands still in free motion, which a fixed torque amplitude leaves
at the heavy (arm outstretched) poses."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from collect.config import _build, load_config
from collect.controller import ArmSignals, BilateralController
from collect.runner import RunOptions, run_session
from crane_io.description import default_arm
from crane_io.errors import ConfigError
from train.evaluation.fidelity import measure_fidelity

DT = 0.002
ARM = default_arm()
NAMES = list(ARM.joint_names)
J1, J2, J4 = (NAMES.index(n) for n in ("joint1", "joint2", "joint4"))


def _config(min_velocity=None, amplitude=0.4, **factors):
    """The default configuration with the dither on; min_velocity: {joint: v} (a number: every joint)."""
    values = load_config().values
    values["controller"]["dither_amplitude"] = amplitude
    if min_velocity is not None:
        if not isinstance(min_velocity, dict):
            min_velocity = {n: min_velocity for n in NAMES}
        for name, v in min_velocity.items():
            values["controller"][name]["dither_min_velocity"] = v
    for name, factor in factors.items():
        values["controller"][name]["dither"] = factor
    return _build(values, "the test")


def _run(cfg, q, steps=300):
    """The follower's dither (steps, n) and nominal inertia (steps, n) with both arms held at pose q."""
    ctl = BilateralController(cfg)
    d, J = [], []
    for _ in range(steps):
        ctl.step(ArmSignals(q), ArmSignals(q), DT)
        d.append(ctl.dither.copy())
        J.append(ctl.observer("follower").J.copy())
    return np.array(d), np.array(J)


def _pose(outstretched: bool) -> np.ndarray:
    q = np.zeros(len(NAMES))
    if outstretched:  # upper arm and forearm horizontal: joint 1 carries the whole arm's inertia
        q[NAMES.index("joint2")] = np.pi / 2
    return q


def test_the_key_defaults_to_off_and_is_checked(tmp_path):
    assert all(g.dither_min_velocity == 0.0 for g in load_config().controller.joints.values())
    for text in ("dither_min_velocity = -0.01", "dither_min_velocity = nan"):
        path = tmp_path / "c.toml"
        path.write_text(f"[controller.joint1]\n{text}\n")
        with pytest.raises(ConfigError) as err:
            load_config(path)
        assert "controller.joint1.dither_min_velocity" in str(err.value) and "\n" not in str(err.value)


def test_a_zero_floor_gives_exactly_the_fixed_amplitude_commands():
    q = _pose(True)
    ref = BilateralController(_config())
    off = BilateralController(_config(0.0))
    for _ in range(100):
        a = ref.step(ArmSignals(q), ArmSignals(q), DT)
        b = off.step(ArmSignals(q), ArmSignals(q), DT)
        assert np.array_equal(a.follower_tau, b.follower_tau) and np.array_equal(a.leader_tau, b.leader_tau)


def test_the_floor_raises_only_the_heavy_joints_and_keeps_sign_and_zeros():
    v, f = 0.045, 50.0
    fixed, _ = _run(_config(joint4=-1.5, joint3=0.0), _pose(True))
    floored, J = _run(_config(v, joint4=-1.5, joint3=0.0), _pose(True))
    amp_fixed, amp = np.abs(fixed).max(axis=0), np.abs(floored).max(axis=0)
    bil = np.array([n in ARM.bilateral_joints for n in NAMES])
    factor = np.array([1.0, 1.0, 0.0, -1.5, 1.0, 1.0, 1.0, 1.0]) * bil  # joint3 0, joint4 antiphase
    s = np.sin(2 * np.pi * f * np.arange(len(fixed)) * DT)[:, None]
    want = np.sign(factor) * np.maximum(np.abs(0.4 * factor), v * 2 * np.pi * f * J) * s
    assert np.allclose(floored, want, atol=1e-12)
    assert amp[J1] > 2.0 * amp_fixed[J1]  # joint 1 outstretched: about 10x its upright inertia
    assert not floored[:, ~bil].any()  # held joints: never dithered
    # antiphase kept: joint 4's wave has the opposite sign of joint 1's
    assert np.all(floored[:, J4] * floored[:, J1] <= 0) and np.abs(floored[:, J4]).max() > 0
    # upright joint 1 is light: its velocity amplitude already exceeds the floor, nothing changes
    up_fixed, _ = _run(_config(), _pose(False))
    up, J_up = _run(_config(v), _pose(False))
    assert 0.4 / (2 * np.pi * f * J_up[-1, J1]) > v
    assert np.array_equal(up[:, J1], up_fixed[:, J1])


def test_a_floor_on_joint1_leaves_the_other_joints_alone():
    fixed, _ = _run(_config(joint4=-1.5), _pose(True))
    floored, _ = _run(_config({"joint1": 0.045}, joint4=-1.5), _pose(True))
    others = [i for i in range(len(NAMES)) if i != J1]
    assert np.array_equal(floored[:, others], fixed[:, others])
    assert np.abs(floored[:, J1]).max() > 2.0 * np.abs(fixed[:, J1]).max()


def test_a_joint_without_dither_stays_undithered():
    floored, _ = _run(_config(0.2, joint2=0.0), _pose(True))
    assert not floored[:, J2].any() and np.abs(floored[:, J1]).max() > 0.4


def test_the_floor_lowers_joint1_standstill_false_force_in_a_simulated_run(tmp_path):
    """Seed 29, contact task: joint 1 stops twice with the arm far out in the first 20 s. A fixed 0.6 N m
    wave moves it too slowly there to keep its friction averaged out; the floor's larger wave does."""
    figures = {}
    for name, extra in (("fixed", ""), ("floor", "dither_min_velocity = 0.045\n")):
        cfg = tmp_path / f"{name}.toml"
        cfg.write_text("[controller]\ndither_amplitude = 0.4\n[controller.joint1]\ndither = 1.5\n" + extra +
                       "[controller.joint2]\ndither = 2.5\n[controller.joint4]\ndither = -1.5\n")
        out, trace = tmp_path / f"{name}.h5", tmp_path / f"{name}.truth.h5"
        result = run_session(RunOptions(output=out, sim=True, seed=29, duration=20.0, status=False,
                                        plant="contact-wall", task="contact", config=cfg, truth_trace=trace))
        assert result.end_reason == "duration"
        with h5py.File(out, "r") as f:
            assert np.isfinite(f["follower/tau_res"][:, J1]).all()
        figures[name] = measure_fidelity(out, trace).joints["joint1"]["follower_false_rms_still"]
    assert figures["floor"] < 0.8 * figures["fixed"], figures
