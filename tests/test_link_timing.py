"""Start-up's check that the ports can carry one control cycle in one period (collect/link_timing.py):
the judgement on given times, and a run refused before torque-on over two simulated U2D2 links with the
ftdi_sio default latency timer."""

import sys

import numpy as np
import pytest

from collect.link_timing import LinkTiming, LinkTooSlow, check_link_timing, verdict
from collect.runner import RunOptions, run_session
from collect.sim_lab import SimulatedLab
from crane_io.sim.adapter_timing import AdapterTiming
from crane_io.sim.transport import ADAPTER_SWITCH_INTERVAL_S

PERIOD_500HZ = 0.002


def test_a_link_slower_than_the_period_refuses_in_one_sentence_with_the_fix():
    with pytest.raises(LinkTooSlow) as refused:
        verdict(LinkTiming(best_s=0.0152, median_s=0.0158, worst_s=0.016, rounds=20), PERIOD_500HZ)
    sentence = str(refused.value)
    assert "15.80 ms" in sentence and "`rate` 500 Hz" in sentence and "latency_timer" in sentence
    assert "no rate from 100 Hz up fits this link" in sentence  # 16 ms is too slow for every rate
    assert "\n" not in sentence


def test_a_link_that_fits_a_lower_rate_names_that_rate_and_not_the_latency_timer():
    # 1 ms reads (a 1 ms latency timer) at 1 kHz: nothing to change on the adapter, the rate is too high
    with pytest.raises(LinkTooSlow, match=r"lower `rate` to at most 900 Hz$"):
        verdict(LinkTiming(best_s=0.00098, median_s=0.001, worst_s=0.002, rounds=20), 0.001)


def test_a_link_with_room_passes_and_one_with_little_room_warns():
    roomy = LinkTiming(best_s=0.0009, median_s=0.00095, worst_s=0.003, rounds=20)
    assert verdict(roomy, PERIOD_500HZ) is None
    warning = verdict(LinkTiming(best_s=0.0011, median_s=0.0013, worst_s=0.004, rounds=20), PERIOD_500HZ)
    assert warning is not None and "1.30 ms" in warning and "65%" in warning


class _FrozenClockBus:
    """A bus whose servos' Realtime Tick stands still (a lockstep simulation) and whose reads never end."""

    ids, joint_names = (2,), ("joint1",)

    def read_block(self, sid, address, size, joint):
        assert (address, size) == (120, 2)
        return (1234).to_bytes(2, "little")

    def read_state(self, **_):
        raise AssertionError("a lockstep simulation's reads are not timed")


def test_servos_whose_clock_waits_for_the_host_are_not_timed():
    assert check_link_timing({"leader": _FrozenClockBus(), "follower": _FrozenClockBus()}, 0.001) is None


@pytest.fixture
def patient_ports(monkeypatch):
    """The servers' threads share this process's interpreter with the run: let them take turns often, as
    sim-serve does; and give the ports' reply timeouts room for a loaded machine (a pty has no latency
    timer to read, so its timeout allows for the SDK's 16 ms, tight beside a 16 ms adapter)."""
    import crane_io.dynamixel.port as port

    monkeypatch.setattr(port, "SDK_LATENCY_MS", 100.0)
    before = sys.getswitchinterval()
    sys.setswitchinterval(ADAPTER_SWITCH_INTERVAL_S)
    yield
    sys.setswitchinterval(before)


def test_a_run_over_links_with_a_16_ms_latency_timer_is_refused_before_torque_on(tmp_path, patient_ports):
    lab = SimulatedLab.build(plant="simple", clock="wall", return_delay_time=0)
    links = {"leader": tmp_path / "leader", "follower": tmp_path / "follower"}
    lab.serve(links, adapter=AdapterTiming(latency_timer_s=0.016))
    try:
        output = tmp_path / "s.h5"
        with pytest.raises(LinkTooSlow, match=r"`rate` 500 Hz.*latency timer to 1 ms"):
            run_session(RunOptions(output=output, leader_port=str(links["leader"]),
                                   follower_port=str(links["follower"]), rate=500, duration=1,
                                   status=False, calibrate=False))
        assert not output.exists()
        torque = [s.read_register("torque_enable") for c in lab.chains.values() for s in c.servos.values()]
        assert np.all(np.array(torque) == 0) and len(torque) == 16
    finally:
        lab.stop()
