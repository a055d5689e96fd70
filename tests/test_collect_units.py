"""collect building blocks: cycle timer, safety monitor, simulated operator, session recorder."""

import h5py
import numpy as np
import pytest

from collect.config import load_config
from collect.operator import SimulatedOperator
from collect.pacing import CycleTimer
from collect.recorder import SessionRecorder, read_events
from collect.safety import SafetyMonitor
from crane_io.description import default_arm
from crane_io.dynamixel.faults import CommunicationError
from crane_io.errors import CraneError

ARM = default_arm()
BIL = np.array([n in ARM.bilateral_joints for n in ARM.joint_names])


class FakeClock:
    def __init__(self):
        self.t = 100.0
        self.slept = []

    def __call__(self):
        self.t += 1e-6  # every look at the clock costs a microsecond (so spin loops end)
        return self.t

    def sleep(self, s):
        self.slept.append(s)
        self.t += s


# ---- pacing -------------------------------------------------------------------------------------------

def test_deadlines_are_absolute_so_work_does_not_drift_the_rate():
    clock = FakeClock()
    timer = CycleTimer(500, clock=clock, sleep=clock.sleep, spin_s=2e-4)
    timer.start()
    t0 = clock.t
    for k in range(1000):
        clock.t += 0.0013 if k % 2 else 0.0007  # uneven work, always under the period
        timer.wait()
    assert clock.t - t0 == pytest.approx(1000 * 0.002, abs=1e-4)  # no accumulated drift
    s = timer.summary()
    assert s["period_mean_s"] == pytest.approx(0.002, abs=1e-5)
    assert s["overruns"] == 0 and s["rate_hz"] == pytest.approx(500, rel=1e-3)


def test_overruns_are_counted_and_missed_deadlines_skipped():
    clock = FakeClock()
    timer = CycleTimer(500, clock=clock, sleep=clock.sleep)
    timer.start()
    clock.t += 0.0075  # one cycle takes 3.75 periods
    timer.wait()
    assert timer.last_overrun and timer.overruns == 1 and timer.skipped_deadlines == 2
    clock.t += 0.0005
    timer.wait()
    assert not timer.last_overrun
    s = timer.summary()
    assert s["period_max_s"] >= 0.0075 and s["period_p99_s"] <= s["period_max_s"]


def test_lockstep_never_sleeps_and_sections_accumulate():
    clock = FakeClock()
    timer = CycleTimer(500, lockstep=True, clock=clock, sleep=clock.sleep)
    timer.start()
    for _ in range(10):
        timer.add("bus_leader", 1e-4)
        timer.add("compute", 2e-5)
        timer.wait()
    assert clock.slept == [] and timer.overruns == 0
    s = timer.summary()
    assert s["bus_leader_mean_s"] == pytest.approx(1e-4 * 10 / 11)
    assert s["compute_max_s"] == pytest.approx(2e-5)


# ---- safety -------------------------------------------------------------------------------------------

def _safety():
    return SafetyMonitor(load_config(), ARM)


def test_soft_limit_cuts_outward_current_and_pushes_back():
    s = _safety()
    i = ARM.index("joint2")
    q = np.zeros(8)
    q[i] = ARM.joint("joint2").upper - np.radians(2)  # 3 deg into the 5 deg soft zone
    tau = np.where(BIL, 1.0, 0.0)
    out = s.limit_torque(q, tau)
    assert out[i] < 0  # the outward push is gone and the wall pushes back
    assert out[ARM.index("joint1")] == 1.0  # other joints untouched
    assert np.all(out[~BIL] == 0)
    inward = s.limit_torque(q, -tau)
    assert inward[i] < -1.0  # pushing inward is allowed (plus the wall)


def test_current_clamp_at_a_fraction_of_the_limit():
    s = _safety()
    out = s.limit_torque(-0.5 * BIL, np.where(BIL, 100.0, 0.0))
    kt = np.array([j.torque_constant for j in ARM.joints])
    limits = np.array([j.current_limit for j in ARM.joints])
    assert out[BIL] / kt[BIL] == pytest.approx(0.8 * limits[BIL])


def test_joint_limit_and_velocity_breaches_name_the_joint():
    s = _safety()
    q = np.zeros(8)
    q[ARM.index("joint4")] = np.radians(4.0)  # upper limit 0 deg + 3 deg overshoot
    b = s.check("follower", q, np.zeros(8))
    assert b.kind == "joint_limit" and b.joint == "joint4" and "follower joint4" in b.message
    assert s.check("follower", np.zeros(8) - 0.1 * BIL, np.zeros(8)) is None
    dq = np.zeros(8)
    dq[ARM.index("joint2")] = 2.1
    b = s.check("leader", np.zeros(8) - 0.1 * BIL, dq)
    assert b.kind == "velocity" and b.joint == "joint2"


def test_communication_budget_consecutive_and_per_second():
    s = _safety()
    err = CommunicationError("no reply")
    assert s.bus_error("leader", 0.0, err) is None
    assert s.bus_error("leader", 0.002, err) is None
    assert s.bus_error("leader", 0.004, err).kind == "communication"  # 3 in a row
    s = _safety()
    t = 0.0
    breach = None
    for _ in range(10):  # isolated failures, but 10 within a second
        breach = s.bus_error("follower", t, err)
        s.bus_ok("follower")
        t += 0.05
    assert breach is not None and "within one second" in breach.message
    s = _safety()
    for k in range(30):  # one failure every 0.2 s is tolerated
        assert s.bus_error("leader", k * 0.2, err) is None
        s.bus_ok("leader")


def test_hardware_errors_are_a_breach():
    s = _safety()
    assert s.hardware("leader", {}) is None
    b = s.hardware("leader", {"joint2": ["overload"]})
    assert b.kind == "hardware_error" and "overload" in b.message and b.joint == "joint2"


# ---- operator -----------------------------------------------------------------------------------------

def _reference(seed, seconds, step=0.01):
    op = SimulatedOperator(seed, ARM, 500)
    q0 = np.array([0, 0.2, 0, -1.2, 0, 0, 0, 0.0])
    op.start(q0)
    out = [op.reference(k * step) for k in range(int(seconds / step))]
    return op, np.array([q for q, _ in out]), np.array([dq for _, dq in out])


def test_operator_is_seeded_smooth_and_stays_in_the_workspace():
    op, q, dq = _reference(3, 120)
    _, q2, _ = _reference(3, 120)
    _, q3, _ = _reference(4, 120)
    assert np.array_equal(q, q2) and not np.array_equal(q, q3)
    assert (q >= op.lo - 1e-9).all() and (q <= op.hi + 1e-9).all()
    assert np.abs(dq).max() <= op.o.peak_speed + 1e-9
    assert np.abs(np.diff(q, axis=0)).max() < op.o.peak_speed * 0.01 + 1e-9  # continuous
    assert (q.max(0) - q.min(0) > 1.0).all()  # varied, large motions


def test_operator_joints_move_about_70_percent_and_together_a_third():
    # the reference moves a little more than the paper's ~70 % / ~1/3: stiction holds the simulated arm
    # at the start of each push, so the arm itself moves about 65-70 % of the time (docs/collect.md)
    _, _, dq = _reference(1, 600, step=0.02)
    moving = np.abs(dq) > 0.05
    assert moving.mean(0) == pytest.approx([0.75, 0.75, 0.75], abs=0.07)
    assert moving.all(1).mean() == pytest.approx(0.4, abs=0.08)
    # the pauses differ per joint: the on/off patterns are not the same
    assert (moving[:, 0] != moving[:, 1]).mean() > 0.2


def test_operator_torque_is_an_impedance_on_bilateral_joints_only():
    op = SimulatedOperator(0, ARM, 500)
    q0 = np.array([0, 0.2, 0, -1.2, 0, 0, 0, 0.0])
    op.start(q0)
    tau = op.torque(0.0, q0 + 0.1, np.zeros(8))
    assert np.all(tau[~BIL] == 0)
    assert tau[BIL] == pytest.approx(-op.o.stiffness * 0.1)


# ---- recorder ----------------------------------------------------------------------------------------

def test_recorder_layout_flush_and_complete_flag(tmp_path):
    p = tmp_path / "s.h5"
    names = ARM.joint_names
    rec = SessionRecorder(p, joint_names=names, rate_hz=100, source="sim", attrs={"seed": 3},
                          flush_interval_s=0.1)
    for k in range(25):
        rec.append({"follower/t": k * 0.01, "follower/q": np.full(8, k), "follower/tau": np.ones(8),
                    "leader/t": k * 0.01, "timing/overrun": False})
    rec.event(0.1, "comm_error", "leader: no reply", "joint2")
    # 10 rows per flush at 100 Hz x 0.1 s: 20 are on disk, 5 still buffered; readable while open (SWMR)
    with h5py.File(p, "r", libver="latest", swmr=True) as f:
        assert f["follower/q"].shape == (20, 8)
        assert not f.attrs["complete"]
        assert read_events(f)[0]["kind"] == "comm_error"
    rec.close(attrs={"rate_hz_achieved": 99.0}, group_attrs={"timing": {"period_mean_s": 0.01}})
    with h5py.File(p, "r") as f:
        assert f.attrs["format"] == "crane-session" and f.attrs["format_version"] == 1
        assert list(f.attrs["joint_names"]) == list(names)
        assert f.attrs["complete"] and f.attrs["seed"] == 3 and f.attrs["rate_hz_achieved"] == 99.0
        assert f["follower/q"].shape == (25, 8) and f["follower/q"][24, 0] == 24
        assert np.isnan(f["leader/q"][0]).all()  # members not given stay NaN, never stale
        assert f["timing"].attrs["period_mean_s"] == 0.01
        assert f["follower/q"].chunks is not None and f["follower/q"].maxshape == (None, 8)


def test_recorder_never_overwrites_without_force(tmp_path):
    p = tmp_path / "s.h5"
    p.write_bytes(b"precious")
    with pytest.raises(CraneError, match="already exists; pass `force`"):
        SessionRecorder(p, joint_names=["a"], rate_hz=1, source="sim")
    assert p.read_bytes() == b"precious"
    SessionRecorder(p, joint_names=["a"], rate_hz=1, source="sim", force=True).close()
    with h5py.File(p, "r") as f:
        assert f.attrs["complete"]
