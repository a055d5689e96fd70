"""The compiled controller (collect/controller_kernel.py) gives the numpy path's bits: step, hold and applied
on random poses, torques and periods (held joints, NaN, signed zeros, the deadband, every gravity and
inertia model); when it is used (not on real arms: numba is never imported for it); a simulated session
the same bit for bit with and without it; the pose-dependent inertia's shortcut."""

from __future__ import annotations

import subprocess
import sys

import h5py
import numpy as np
import pytest

pytest.importorskip("numba")

from collect import controller_kernel  # noqa: E402
from collect.config import _build, load_config  # noqa: E402
from collect.controller import ArmSignals, BilateralController  # noqa: E402
from collect.runner import RunOptions, run_arm, run_session  # noqa: E402
from crane_io.errors import ConfigError  # noqa: E402
from tests.loop_reference import control_reference  # noqa: E402

DT = 0.002


def _config(joints=None, **controller):
    cfg = load_config()
    if joints is not None:
        cfg = cfg.with_bilateral_joints(joints)
    values = cfg.values
    values["controller"].update(controller)
    return _build(values, "the test")


def _pair(cfg):
    arm = run_arm(cfg)
    return BilateralController(cfg, arm, compiled=False), BilateralController(cfg, arm, compiled=True), arm


_NAN_SIGN = [False]  # the NaN test: NaN where the numpy path has NaN, whatever its sign bit


def _same(a, b, what):
    a, b = np.asarray(a), np.asarray(b)
    assert a.dtype == b.dtype and a.shape == b.shape, what
    if _NAN_SIGN[0] and a.dtype == float:
        nan = np.isnan(a)
        assert (nan == np.isnan(b)).all(), (what, a, b)
        a, b = np.where(nan, 0.0, a), np.where(nan, 0.0, b)
    assert a.tobytes() == b.tobytes(), (what, a, b)


def _compare(ref, new, cmd_ref, cmd_new, k):
    for name in ("leader_tau", "follower_tau", "leader_current", "follower_current"):
        _same(getattr(cmd_ref, name), getattr(cmd_new, name), (k, name))
    for arm in ("leader", "follower"):
        for name in ("dq", "tau_dis", "tau_res"):
            _same(getattr(getattr(ref, arm), name), getattr(getattr(new, arm), name), (k, arm, name))


def _drive(cfg, steps=1500, seed=0, nan_held=False):
    """Both paths through `steps` cycles of hold then step on the same random inputs; every output and
    the observers' state compared bit for bit each cycle."""
    ref, new, arm = _pair(cfg)
    assert new.compiled and not ref.compiled
    rng = np.random.default_rng(seed)
    n = len(arm.joints)
    bil = np.array([j in arm.bilateral_joints for j in arm.joint_names])
    q0 = np.array([0.0, 0.3, 0.0, -1.0, 0.0, 0.2, 0.0, 0.0])
    ql, qf = q0.copy(), q0 + 0.02
    for k in range(steps):
        ql = ql + rng.normal(0, 0.01, n)
        qf = qf + rng.normal(0, 0.01, n)
        if k % 11 == 0:
            qf[k % n] = ql[k % n]  # e = 0 exactly (the deadband's sign of 0)
        if k % 13 == 0:
            ql[k % n] = -0.0
            qf[k % n] = 0.0
        a, b = ql.copy(), qf.copy()
        if nan_held and k % 7 == 0:
            a[np.flatnonzero(~bil)[k % max(1, (~bil).sum())]] = np.nan
        dt = DT if k % 97 else DT * rng.uniform(0.5, 2.0)  # a late cycle now and then (another decay)
        if k < steps // 5:
            ref_l = (q0 + 0.1 * np.sin(k * 0.01), rng.normal(0, 0.1, n))
            ref_f = (q0 - 0.1 * np.sin(k * 0.01), np.zeros(n))
            c_ref = ref.hold(ArmSignals(a), ArmSignals(b), ref_l, ref_f, dt)
            c_new = new.hold(ArmSignals(a.copy()), ArmSignals(b.copy()), ref_l, ref_f, dt)
        else:
            c_ref = ref.step(ArmSignals(a), ArmSignals(b), dt)
            c_new = new.step(ArmSignals(a.copy()), ArmSignals(b.copy()), dt)
        _compare(ref, new, c_ref, c_new, k)
        if k % 3:  # the safety clamps, or anything: what the observers are told went out
            tl = np.clip(c_ref.leader_tau, -0.5, 0.5) if k % 5 else rng.normal(0, 1.0, n)
            tf = c_ref.follower_tau * 0.9 if k % 4 else -0.0 * c_ref.follower_tau
            ref.applied(tl, tf)
            new.applied(tl.copy(), tf.copy())
        for r, m in ((ref.observer(a), new.observer(a)) for a in ("leader", "follower")):
            for name in ("z", "y", "applied", "J"):
                _same(getattr(r, name), getattr(m, name), (k, name))


@pytest.mark.parametrize("joints", [None, "all", "joint2,joint4"])
def test_the_kernel_gives_the_numpy_paths_bits(joints):
    _drive(_config(joints))


@pytest.mark.parametrize("controller", [
    {"gravity_model": "coefficients", "inertia_model": "constant"},
    {"gravity_model": "none", "inertia_update_cycles": 1},
    {"position_deadband_deg": 0.6, "inertia_update_cycles": 3},
])
def test_the_kernel_gives_the_numpy_paths_bits_with_other_models(controller):
    _drive(_config(None, **controller), steps=800, seed=1)


def test_nan_on_a_held_joint_comes_out_the_same(monkeypatch):
    # NaN's sign bit is not kept: numpy's and the kernel's additions of two NaNs may return either one
    # (no arm reads NaN: the bus gives whole counts)
    monkeypatch.setattr(sys.modules[__name__], "_NAN_SIGN", [True])
    _drive(_config(None), steps=400, seed=2, nan_held=True)


def test_a_non_finite_bilateral_angle_is_the_same_error():
    for compiled in (False, True):
        ctl = BilateralController(load_config(), compiled=compiled)
        q = np.array([0.0, 0.3, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0])
        ctl.step(ArmSignals(q), ArmSignals(q), DT)
        bad = q.copy()
        bad[1] = np.inf
        with pytest.raises(ConfigError, match="NaN or infinite"):
            ctl.step(ArmSignals(bad), ArmSignals(q), DT)


def test_inputs_of_other_types_and_layouts_take_no_new_specialisation():
    cfg = load_config()
    ref, new, arm = _pair(cfg)
    q2 = np.tile(np.array([0.0, 0.3, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0]), (2, 1)).T  # columns: not contiguous
    ro = q2[:, 0].copy()
    ro.setflags(write=False)
    before = {f: len(f.signatures) for f in controller_kernel.compiled()}
    for q in (q2[:, 0], ro, [0, 0, 0, -1, 0, 0, 0, 0], q2[:, 1].astype(np.float32)):
        c_ref = ref.step(ArmSignals(q), ArmSignals(q), 0.002)
        c_new = new.step(ArmSignals(q), ArmSignals(q), 2e-3)
        _compare(ref, new, c_ref, c_new, str(q))
    assert {f: len(f.signatures) for f in controller_kernel.compiled()} == before


def test_it_is_chosen_where_it_covers_the_run_and_refused_where_not():
    import numba  # noqa: F401  (loaded: the default picks the kernel)

    assert BilateralController(load_config()).compiled
    dither = _config(None, dither_amplitude=0.2)
    assert not BilateralController(dither).compiled
    with pytest.raises(ConfigError, match="friction dither"):
        BilateralController(dither, compiled=True)
    models = {"follower": lambda: None, "leader": None}
    assert not BilateralController(load_config(), models=models).compiled
    with pytest.raises(ConfigError, match="learned model"):
        BilateralController(load_config(), models=models, compiled=True)
    ctl = BilateralController(load_config(), compiled=True)
    ctl.step(ArmSignals(np.zeros(8)), ArmSignals(np.zeros(8)), DT)
    ctl.reset()
    assert ctl.observer("leader").z is None and ctl.leader is None


def test_a_process_without_numba_keeps_the_numpy_path():
    code = ("import sys; from collect.config import load_config; from collect.controller import "
            "BilateralController as B; c = B(load_config()); print(c.compiled, 'numba' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]


def _datasets(path):
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset)
                     and not name.startswith("timing") else None)
    return out


@pytest.mark.parametrize("joints", [None, "all"])
def test_a_simulated_session_is_the_same_with_and_without_the_kernel(tmp_path, monkeypatch, joints):
    opts = dict(sim=True, seed=4, duration=1.0, status=False, joints=joints)
    real, used = controller_kernel.compiled, []
    monkeypatch.setattr(controller_kernel, "compiled", lambda: used.append(real()) or used[-1])
    run_session(RunOptions(output=tmp_path / "k.h5", **opts))
    assert used and used[-1] is not None  # the simulated run took the kernel
    monkeypatch.setattr(controller_kernel, "compiled", lambda: None)  # the numpy path
    run_session(RunOptions(output=tmp_path / "n.h5", **opts))
    a, b = _datasets(tmp_path / "k.h5"), _datasets(tmp_path / "n.h5")
    assert a.keys() == b.keys() and "follower/tau_res" in a
    for name in a:
        assert np.asarray(a[name]).tobytes() == np.asarray(b[name]).tobytes(), name


def test_the_mass_matrix_diagonal_is_the_mass_matrix_s():
    from crane_io.physics.dynamics import ArmDynamics

    rng = np.random.default_rng(5)
    for joints in (("joint1", "joint2", "joint4"), ("joint1", "joint2", "joint3", "joint4", "joint5",
                                                    "joint6", "joint7"), ("joint4", "joint2")):
        dyn = ArmDynamics(joints)
        qs = rng.uniform(-2.0, 2.0, (50, len(joints)))
        for q in qs:
            _same(dyn.mass_matrix_diagonal(q), np.diag(dyn.mass_matrix(q)), joints)
        _same(dyn.mass_matrix_diagonal(qs), np.diagonal(dyn.mass_matrix(qs), axis1=1, axis2=2), joints)
        bad = qs[0].copy()
        bad[0] = np.nan
        with pytest.raises(ConfigError):
            dyn.mass_matrix_diagonal(bad)


@pytest.mark.parametrize("joints", [None, "all"])
@pytest.mark.parametrize("compiled", [True, False])
def test_control_is_step_clamps_applied_and_checks(joints, compiled):
    from collect.safety import SafetyMonitor

    cfg = _config(joints)
    arm = run_arm(cfg)
    ref = BilateralController(cfg, arm, compiled=False)
    new = BilateralController(cfg, arm, compiled=compiled)
    safety = SafetyMonitor(cfg, arm)
    n = len(arm.joints)
    rng = np.random.default_rng(7)
    mid, half = 0.5 * (safety.lower + safety.upper), 0.5 * (safety.upper - safety.lower)
    base = mid + 0.5 * half * rng.uniform(-1.0, 1.0, n)
    seen = {"soft": 0, "breach": 0}
    for k in range(1500):
        ql = base + 0.3 * half * np.sin(0.01 * k + np.arange(n))
        qf = ql + rng.normal(0, 0.01, n)
        if k % 9 == 0:  # a joint in its soft zone or past its stop
            j = k % n
            ql[j] = rng.choice([safety.soft_upper[j] + 1e-3, safety.soft_lower[j] - 1e-3,
                                safety.stop_upper[j] + 1e-3, safety.soft_upper[j]])
        if k % 10 == 0:
            qf[(k + 3) % n] = safety.stop_lower[(k + 3) % n] - 1e-3
        dql, dqf = rng.normal(0, 1.0, n), rng.normal(0, 1.0, n)
        if k % 7 == 0:
            dqf[k % n] = safety.vmax[k % n] * (1.5 if k % 14 else 1.0)
        if k % 11 == 0:
            dql = None
        if k % 13 == 0:
            dqf = None
        a, b = ArmSignals(ql, dql), ArmSignals(qf, dqf)
        want = control_reference(ref, safety, a, b, DT)
        got = new.control(a, b, DT, safety)
        _compare(ref, new, want[0], got[0], k)
        _same(want[1], got[1], (k, "tau_l"))
        _same(want[2], got[2], (k, "tau_f"))
        assert (want[3] is None) == (got[3] is None) and (want[3] is None or want[3] == got[3]), k
        seen["breach"] += want[3] is not None
        seen["soft"] += bool(safety._outside(ql.tolist(), safety.soft_lower.tolist(),
                                             safety.soft_upper.tolist()))
        for r, m in ((ref.observer(a), new.observer(a)) for a in ("leader", "follower")):
            _same(r.applied, m.applied, (k, "applied"))
    assert seen["soft"] > 100 and seen["breach"] > 100  # the safety monitor's own cases were met
