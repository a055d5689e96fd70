"""Stop requests are never lost and never cut a clean-up short (crane_io.shutdown, collect.runner).

Signals are sent to the main thread itself (`signal.pthread_kill`), so they arrive at a known point:
inside a garbage-collection callback, inside the safe stop, inside the alignment."""

import gc
import os
import signal
import threading
import weakref

import h5py
import numpy as np
import pytest

from collect.recorder import read_events
from collect.runner import RunOptions, SafetyStop, run_session
from crane_io.dynamixel.bus import DynamixelBus
from crane_io.shutdown import Terminated, handle_termination
from tests.recording import TEST_CONFIG, torque_off_everywhere


def _kill_self(sig=signal.SIGINT):
    signal.pthread_kill(threading.main_thread().ident, sig)


class _Litter:
    pass


def _signal_inside_a_gc_callback(sig=signal.SIGINT):
    """Send `sig` while Python runs a weakref finaliser: an exception raised there is printed and lost."""
    def finaliser():
        _kill_self(sig)
        for _ in range(2000):  # give the interpreter its chance to run the Python-level handler here
            pass

    obj = _Litter()
    weakref.finalize(obj, finaliser)
    del obj
    gc.collect()


@pytest.fixture
def cfg(tmp_path):
    p = tmp_path / "test.toml"
    p.write_text(TEST_CONFIG)
    return p


def _opts(tmp_path, cfg, **kw):
    base = dict(output=tmp_path / "s.h5", sim=True, plant="simple", duration=2.0, config=cfg, seed=5,
                status=False)
    base.update(kw)
    return RunOptions(**base)


# ---- crane_io.shutdown ---------------------------------------------------------------------------------
@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_a_signal_lost_in_a_gc_callback_stays_recorded_and_the_next_one_still_raises():
    with handle_termination([signal.SIGINT]) as stop:
        _signal_inside_a_gc_callback()  # its Terminated is swallowed by the finaliser machinery
        assert stop.requested and stop.signum == signal.SIGINT
        with pytest.raises(Terminated):
            stop.check()  # the loop's checkpoint takes it
        with pytest.raises(Terminated):  # and a second Ctrl+C is not ignored
            _kill_self()
            for _ in range(1000):
                pass


def test_deferred_takes_the_first_signal_at_the_checkpoint_and_a_second_at_once():
    with handle_termination([signal.SIGINT]) as stop, stop.deferred():
        _kill_self()
        for _ in range(1000):
            pass
        assert stop.requested and stop.count == 1  # recorded, nothing raised mid-cycle
        with pytest.raises(Terminated):
            _kill_self()
            for _ in range(1000):
                pass
        assert stop.count == 2


def test_stopping_never_raises_and_says_the_stop_is_in_progress(capfd):
    with handle_termination([signal.SIGINT, signal.SIGTERM], notice="stop in progress, wait") as stop:
        stop.begin_stop()
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGINT):
            _kill_self(sig)
            for _ in range(1000):
                pass
        assert stop.count == 3 and stop.signum == signal.SIGINT
        stop.check()  # inside the stop a checkpoint does not raise either
    assert capfd.readouterr().err.count("stop in progress, wait") == 3


def test_a_signal_inside_bus_close_does_not_skip_a_torque_off_write(monkeypatch):
    from crane_io.sim import simulated_arm

    sim = simulated_arm()
    sent = []
    original = DynamixelBus._write

    def write(self, sid, name, value, joint):
        if name == "torque_enable" and value == 0 and not sent:
            sent.append(sid)
            _kill_self(signal.SIGTERM)  # lands between the torque-off writes of two servos
        return original(self, sid, name, value, joint)

    try:
        with handle_termination():
            bus = DynamixelBus(sim.url).open()
            bus.ping_all()
            bus.configure(watchdog_s=None)
            bus.torque_on()
            monkeypatch.setattr(DynamixelBus, "_write", write)
            bus.close()
        assert sent and all(s.read_register("torque_enable") == 0 for s in sim.chain.servos.values())
    finally:
        sim.close()


# ---- collect.runner ------------------------------------------------------------------------------------
def test_ctrl_c_lost_in_a_gc_callback_still_ends_the_run(tmp_path, cfg):
    seen = {}

    def hook(k, ctx):
        seen["sims"] = ctx.sims
        if k == 100:
            _signal_inside_a_gc_callback()

    r = run_session(_opts(tmp_path, cfg, duration=4.0, on_cycle=hook))
    assert r.end_reason == "interrupted" and r.cycles <= 102
    assert torque_off_everywhere(seen["sims"])
    with h5py.File(r.path, "r") as f:
        assert f.attrs["complete"] and f.attrs["end_reason"] == "interrupted"
        assert [e["message"] for e in read_events(f) if e["kind"] == "interrupted"] == \
            ["stopped by Ctrl+C (SIGINT)"]


@pytest.mark.parametrize("where", ["safe_stop", "torque_report", "recorder_close"])
def test_signals_during_the_clean_up_let_it_run_to_its_end(tmp_path, cfg, monkeypatch, capfd, where):
    """After a run ended by its duration, two Ctrl+C and a SIGTERM arrive during the clean-up: the arms
    are stopped, the torque read back, the file closed complete with every row, the summary printed."""
    from collect import arm_pair, recorder

    seen = {}
    targets = {"safe_stop": (arm_pair.ArmPair, "safe_stop"),
               "torque_report": (arm_pair.ArmPair, "torque_report"),
               "recorder_close": (recorder.SessionRecorder, "close")}
    cls, name = targets[where]
    original = getattr(cls, name)

    def interrupted(self, *args, **kwargs):
        for sig in (signal.SIGINT, signal.SIGINT, signal.SIGTERM):
            _kill_self(sig)
            for _ in range(1000):
                pass
        return original(self, *args, **kwargs)

    monkeypatch.setattr(cls, name, interrupted)
    r = run_session(_opts(tmp_path, cfg, duration=1.0, status=True,
                          on_cycle=lambda k, ctx: seen.setdefault("sims", ctx.sims)))
    assert r.end_reason == "duration" and r.cycles == 500
    assert torque_off_everywhere(seen["sims"])
    err = capfd.readouterr().err
    assert "stop is in progress" in err and "ended after the requested duration" in err
    with h5py.File(r.path, "r") as f:
        assert f.attrs["complete"] and f.attrs["end_reason"] == "duration"
        assert f["follower/t"].shape[0] == 500 and f["leader/q"].shape[0] == 500
        states = [e["message"] for e in read_events(f) if e["kind"] == "torque_state"]
        assert states == ["leader: torque off on 8 of 8 servos", "follower: torque off on 8 of 8 servos"]


def test_sigterm_during_the_alignment_stops_the_arms_and_writes_no_file(tmp_path, cfg, monkeypatch):
    from collect import arm_pair

    seen = {"calls": 0}
    original = arm_pair.ArmPair.write_positions  # only the alignment writes goal positions

    def write_positions(self, q_l, q_f):
        seen["calls"] += 1
        seen["pair"] = self
        if seen["calls"] == 50:
            _kill_self(signal.SIGTERM)
        return original(self, q_l, q_f)

    monkeypatch.setattr(arm_pair.ArmPair, "write_positions", write_positions)
    r = run_session(_opts(tmp_path, cfg))
    assert r.end_reason == "terminated" and r.cycles == 0
    assert 50 <= seen["calls"] <= 51  # taken at the next cycle
    assert not (tmp_path / "s.h5").exists()
    for bus in seen["pair"].buses.values():
        assert bus.torque_enabled is False and not bus.is_open


def test_events_after_a_safety_stop_come_after_it_on_the_hardware_path(tmp_path, cfg):
    """On hardware the session time is the leader's clock and the breaching cycle can start well after
    the last recorded one: the torque read-back still carries a later time than the safety stop that
    caused it. Two simulated arms on pseudo-terminals (lockstep chains, so load cannot trip them)."""
    import time

    from crane_io.description import default_arm
    from crane_io.sim.chain import SimulatedChain
    from crane_io.sim.simple_plant import SimplePlant
    from crane_io.sim.transport import PtyServer

    arm = default_arm()
    chains, servers = {}, []
    try:
        for name in ("leader", "follower"):
            chains[name] = SimulatedChain.for_arm(arm, SimplePlant.from_arm(arm), clock="lockstep",
                                                  return_delay_time=0)
            servers.append(PtyServer(chains[name], link=tmp_path / name).start())

        def hook(k, ctx):
            if k == 100:
                time.sleep(0.05)  # a late cycle: the breaching read comes 50 ms after the previous one
                chains["leader"].servos[5].set_hardware_error(0x20)

        with pytest.raises(SafetyStop):
            run_session(RunOptions(output=tmp_path / "s.h5", leader_port=str(tmp_path / "leader"),
                                   follower_port=str(tmp_path / "follower"), duration=60.0, config=cfg,
                                   status=False, on_cycle=hook, skip_selftest=True))
    finally:
        for server in servers:
            server.stop()
    with h5py.File(tmp_path / "s.h5", "r") as f:
        events = read_events(f)
        last_row_t = float(f["leader/t"][-1])
    times = [e["t"] for e in events]
    assert times == sorted(times), events
    stop = next(e for e in events if e["kind"] == "safety_stop")
    states = [e for e in events if e["kind"] == "torque_state"]
    assert len(states) == 2 and all(e["t"] >= stop["t"] for e in states)
    assert stop["t"] >= last_row_t + 0.04  # the breaching cycle was the late one
    assert np.isfinite(times).all()


def test_the_previous_handlers_come_back_after_a_run(tmp_path, cfg):
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    run_session(_opts(tmp_path, cfg, duration=0.2))
    assert {s: signal.getsignal(s) for s in before} == before
    assert os.getpid()  # the process is still here
