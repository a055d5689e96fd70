"""The follower's friction dither (collect/controller.py, [controller] dither_*; docs/collect.md "Friction
dither"): off by default and then without a trace in the commands; on, the follower's applied torque
carries the wave and its DOB sees it; in a simulated contact run it removes the static-friction offset of
joint1's reaction-force estimate at the wall."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from collect.config import _build, load_config
from collect.controller import ArmSignals, BilateralController
from collect.runner import RunOptions, run_session
from crane_io.description import default_arm
from crane_io.errors import ConfigError

DT = 0.002
ARM = default_arm()
BIL = np.array([n in ARM.bilateral_joints for n in ARM.joint_names])


def _config(**dither):
    cfg = load_config()
    values = cfg.values
    for key, value in dither.items():
        values["controller"][f"dither_{key}"] = value
    return _build(values, "the test")


def _signals(steps=400, seed=3):
    """Leader and follower positions (steps, n): slow sines plus a little noise, the same for every run."""
    rng = np.random.default_rng(seed)
    t = np.arange(steps) * DT
    n = len(ARM.joint_names)
    base = 0.2 * np.sin(2 * np.pi * 0.7 * t)[:, None] * np.linspace(0.5, 1.0, n)
    ql = base + 1e-4 * rng.standard_normal((steps, n))
    qf = base - 0.01 + 1e-4 * rng.standard_normal((steps, n))
    return ql, qf


def _commands(cfg, steps=400):
    ctl = BilateralController(cfg)
    ql, qf = _signals(steps)
    out = []
    for k in range(steps):
        c = ctl.step(ArmSignals(ql[k]), ArmSignals(qf[k]), DT)
        out.append((c.leader_tau.copy(), c.follower_tau.copy(), ctl.dither.copy(),
                    ctl.observer("follower").applied.copy()))
    return [np.array(x) for x in zip(*out)]


def test_the_keys_have_documented_defaults_and_are_checked(tmp_path):
    c = load_config().controller
    assert (c.dither_amplitude, c.dither_frequency, c.dither_wave) == (0.0, 50.0, "sine")
    assert c.dither_filter and all(g.dither == 1.0 for g in c.joints.values())
    for text, key in (("dither_amplitude = -0.1", "dither_amplitude"),
                      ("dither_frequency = 0.0", "dither_frequency"),
                      # above rate_hz / 4 = 125 Hz with the dither on (with it off the frequency is unused)
                      ("dither_amplitude = 0.1\ndither_frequency = 200.0", "dither_frequency"),
                      ('dither_wave = "triangle"', "dither_wave"),
                      ("dither_filter = 1", "dither_filter")):
        path = tmp_path / "c.toml"
        path.write_text(f"[controller]\n{text}\n")
        with pytest.raises(ConfigError) as err:
            load_config(path)
        assert f"controller.{key}" in str(err.value) and "\n" not in str(err.value)


def test_dither_off_gives_exactly_the_old_commands():
    ref = _commands(load_config())
    off = _commands(_config(amplitude=0.0, frequency=20.0, wave="square"))
    for a, b in zip(ref[:2], off[:2]):
        assert np.array_equal(a, b)
    assert not off[2].any()


@pytest.mark.parametrize("wave", ["sine", "square"])
def test_dither_on_the_follower_applies_the_wave_and_its_observer_sees_it(wave):
    amp, freq = 0.3, 50.0
    ref = _commands(load_config())
    on = _commands(_config(amplitude=amp, frequency=freq, wave=wave))
    leader_ref, follower_ref = ref[:2]
    leader, follower, dither, applied = on
    k = np.arange(len(dither))
    s = np.sin(2 * np.pi * freq * k * DT)
    want = amp * (s if wave == "sine" else np.where(s >= 0, 1.0, -1.0))
    clear = np.abs(s) > 1e-6  # a square wave's sign at the sine's zero crossings is rounding's choice
    assert np.allclose(dither[clear][:, BIL], want[clear, None]) and not dither[:, ~BIL].any()
    assert np.array_equal(applied, follower)  # the DOB is told the dithered torque
    assert not follower[:, ~BIL].any() and not leader[:, ~BIL].any()
    # the follower's command differs from the undithered one by the wave plus a small low-passed rest
    rest = follower - follower_ref - dither
    assert np.abs(rest[:, BIL]).max() < 0.25 * amp
    d = (follower - follower_ref)[:, BIL]
    for j in range(d.shape[1]):
        assert np.corrcoef(d[clear, j], want[clear])[0, 1] > 0.8
    # the leader (the operator's hand) gets only what leaks through the follower's observer low-pass
    # (here the worst case: the positions are given, so no motion cancels the wave in the DOB)
    assert np.abs(leader - leader_ref).max() < 0.2 * amp


@pytest.mark.parametrize("wave", ["sine", "square"])
def test_the_comb_keeps_the_wave_out_of_the_reaction_estimate(wave):
    # open loop (the positions are given): the follower's DOB sees the whole wave as a disturbance, as
    # at a standstill where the micro-motion is below one encoder count; the tone at f in the follower's
    # tau_res (what the force channel passes to the operator) is measured over whole periods
    freq, steps = 50.0, 600
    k = np.arange(200, steps)  # 20 whole periods after the first ones
    tone = {}
    for filt in (False, True):
        ctl = BilateralController(_config(amplitude=0.3, frequency=freq, wave=wave, filter=filt))
        ql, qf = _signals(steps)
        res = []
        for i in range(steps):
            ctl.step(ArmSignals(ql[i]), ArmSignals(qf[i]), DT)
            res.append(ctl.follower.tau_res[BIL])
        x = np.array(res)[k]
        basis = np.vander((k - k.mean()) / len(k), 3)  # the open loop's slow drift, taken out first
        x = x - basis @ np.linalg.lstsq(basis, x, rcond=None)[0]
        phasor = np.exp(-2j * np.pi * freq * k * DT)
        tone[filt] = np.abs(2 * (x * phasor[:, None]).mean(axis=0)).max()
    assert tone[False] > 0.01  # the observer low-pass alone leaves a few per cent of the wave
    assert tone[True] < 0.2 * tone[False]


def _contact_run(path, config=None):
    trace = path.with_suffix(".truth.h5")
    result = run_session(RunOptions(output=path, sim=True, seed=23, duration=6.0, status=False,
                                    plant="contact-wall", task="contact", config=config, truth_trace=trace))
    assert result.end_reason == "duration"
    with h5py.File(path, "r") as f, h5py.File(trace, "r") as g:
        n = min(len(f["follower/t"]), len(g["t"]))
        res, ext = f["follower/tau_res"][:n, 0], g["tau_ext"][:n, 0]
    pressing = np.abs(ext) > 0.05  # joint1 pressed against its wall (seed 23: from about 2.3 to 4.2 s)
    assert pressing.sum() > 500
    err = res[pressing] + ext[pressing]
    return err.mean(), np.sqrt(np.mean(err ** 2)), np.sqrt(np.mean(ext[pressing] ** 2))


def test_dither_removes_the_static_friction_offset_at_the_wall(tmp_path):
    offset0, rms0, true0 = _contact_run(tmp_path / "plain.h5")
    cfg = tmp_path / "dither.toml"
    cfg.write_text("[controller]\ndither_amplitude = 0.4\ndither_frequency = 50.0\n"  # docs/collect.md's
                   "[controller.joint2]\ndither = 2.5\n")
    offset1, rms1, true1 = _contact_run(tmp_path / "dither.h5", cfg)
    # without dither joint1 holds part of the press in its stick band (breakaway 0.21 N m): an offset
    # of about 0.1 N m; with the joint kept slipping the offset is gone and the error is much smaller
    assert abs(offset0) > 0.05
    assert abs(offset1) < 0.3 * abs(offset0)
    assert rms1 / true1 < 0.6 * (rms0 / true0)


def test_a_negative_joint_factor_dithers_that_joint_in_antiphase(tmp_path):
    """[controller.jointN] dither < 0: the joint's wave is the others' with the opposite sign (so two
    coupled joints' waves do not cancel each other's); non-finite factors are refused."""
    cfg = load_config()
    values = cfg.values
    values["controller"]["dither_amplitude"] = 0.4
    values["controller"]["joint4"]["dither"] = -1.5
    _, _, dither, _ = _commands(_build(values, "the test"))
    names = list(ARM.joint_names)
    j1, j4 = names.index("joint1"), names.index("joint4")
    assert np.abs(dither[:, j1]).max() > 0.3
    assert np.allclose(dither[:, j4], -1.5 * dither[:, j1])
    path = tmp_path / "c.toml"
    path.write_text("[controller.joint4]\ndither = nan\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert "controller.joint4.dither" in str(err.value)


def test_the_example_dither_configurations_load_with_their_documented_settings():
    """docs/examples/dither.toml and dither-model.toml (scripts/closing-the-loop.sh, README "Closing the
    loop") are valid configurations, and dither-model.toml holds the setting measured there."""
    from pathlib import Path

    examples = Path(__file__).resolve().parents[1] / "docs" / "examples"
    plain = load_config(examples / "dither.toml").controller
    model = load_config(examples / "dither-model.toml").controller
    assert plain.dither_amplitude == model.dither_amplitude == 0.4
    assert plain.model_filters == model.model_filters == "training"
    assert plain.model_cutoff == 0.0 and model.model_cutoff == 40.0  # the loop's two lags at 40 rad/s
    assert model.model_coulomb_velocity == 0.1
    factors = {n: model.joints[n].dither for n in ("joint1", "joint2", "joint4")}
    assert factors["joint2"] == 2.5 and factors["joint4"] == -1.5 and factors["joint1"] == 1.0
    # joint 1: a velocity floor for its heavy poses; joint 2: its loop lags at 45 rad/s
    assert model.joints["joint1"].dither_min_velocity == 0.045 and model.joints["joint2"].model_cutoff == 45.0
    assert plain.joints["joint1"].dither_min_velocity == 0.0 and plain.joints["joint2"].model_cutoff == 0.0
