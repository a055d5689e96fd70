"""In lockstep the bus measures host pauses on the simulated chain's clock: a wall-clock
pause of a lockstep simulated arm cannot reach its servos' watchdog, so it costs no extra
error-register read; a pause in simulated time (the chain advanced without a write) is still caught."""

from __future__ import annotations

import time

import numpy as np
import pytest

from crane_io.dynamixel.bus import DynamixelBus
from crane_io.dynamixel.faults import WatchdogExpiredError
from crane_io.sim import simulated_arm


def _running_bus(sim):
    bus = DynamixelBus(sim.url)
    bus.open()
    bus.ping_all()
    bus.configure(watchdog_s=0.1)
    bus.torque_on()
    return bus


def test_a_wall_clock_pause_in_lockstep_reads_no_error_registers():
    sim = simulated_arm(return_delay_time=0)
    try:
        bus = _running_bus(sim)
        bus.read_state()
        bus.write_goal_current(np.zeros(8))
        packets = sim.chain.stats.packets_received
        time.sleep(0.12)  # longer than half (and all) of the 0.1 s watchdog, on the wall clock only
        bus.read_state()
        bus.write_goal_current(np.zeros(8))
        assert sim.chain.stats.packets_received - packets == 2  # one read, one write: no poll
        assert not any(s.watchdog_expired for s in sim.chain.servos.values())
        bus.close()
    finally:
        sim.close()


def test_a_pause_in_simulated_time_is_still_caught():
    sim = simulated_arm(return_delay_time=0)
    try:
        bus = _running_bus(sim)
        bus.read_state()
        bus.write_goal_current(np.zeros(8))
        sim.chain.advance(0.3)  # the host said nothing for 0.3 s of the chain's time
        with pytest.raises(WatchdogExpiredError, match="paused 0.30"):
            bus.read_state()
        bus.close()
    finally:
        sim.close()


def test_the_chain_clock_follows_the_wall_clock_when_switched():
    sim = simulated_arm()
    try:
        chain = sim.chain
        chain.advance(0.5)
        assert chain.servo_time() == chain.time
        chain.set_clock("wall")
        assert chain.servo_time() == pytest.approx(0.5, abs=0.05)
    finally:
        sim.close()
