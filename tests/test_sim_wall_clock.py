"""The wall-clock simulator answers every instruction within a bounded time whatever the load: a plant
that cannot keep up with real time makes simulated time slip (counted in `chain.stats`), it never holds
up the wire. Slowness is made certain with a plant whose every step sleeps (tests/fakes/timing.py), so
these tests assert what the simulator does about it, not how fast the machine is."""

from __future__ import annotations

import time

import pytest
from dynamixel_sdk import COMM_SUCCESS, GroupSyncWrite, PacketHandler, PortHandler
from fakes import SlowPlant, TickingClock

from crane_io.description import default_arm
from crane_io.dynamixel.control_table import MODE_CURRENT
from crane_io.sim import protocol as p
from crane_io.sim.chain import SimulatedChain
from crane_io.sim.simple_plant import SimplePlant
from crane_io.sim.transport import PtyServer

ARM = default_arm()
TORQUE, MODE, WATCHDOG, GOAL_CURRENT = 64, 11, 98, 102
REPLY_TIMEOUT_S = 5.0  # generous: a reply must come, however busy the machine


def chain_with(cost_s: float, **kwargs) -> tuple[SimulatedChain, SlowPlant]:
    plant = SlowPlant(SimplePlant.from_arm(ARM), cost_s)
    return SimulatedChain.for_arm(ARM, plant, clock="wall", return_delay_time=0, **kwargs), plant


def write1(chain, sid, address, value) -> bytes:
    return chain.feed(p.instruction_packet(sid, p.INST_WRITE, bytes((address & 0xFF, address >> 8, value))))


def read1(chain, sid, address) -> int:
    reply = chain.feed(p.instruction_packet(sid, p.INST_READ, bytes((address & 0xFF, address >> 8, 1, 0))))
    assert reply[4] == sid and reply[8] == 0, reply.hex()
    return reply[9]


class PatientPort(PortHandler):
    """The SDK's port with a generous reply timeout: the test waits for replies, it does not time them."""

    def setPacketTimeout(self, packet_length):  # noqa: N802 (SDK name)
        self.setPacketTimeoutMillis(REPLY_TIMEOUT_S * 1000.0)


def test_a_plant_slower_than_real_time_does_not_hold_up_a_reply():
    chain, plant = chain_with(cost_s=0.05)  # 50 ms of real time per substep of at most 1 ms
    time.sleep(0.3)  # 0.3 s to catch up: 300 substeps, 15 s of stepping, if the reply waited for them
    steps = chain.stats.plant_steps
    assert chain.feed(p.instruction_packet(2, p.INST_PING)) == p.status_packet(2, 0, bytes((0xFC, 3, 52)))
    assert chain.stats.plant_steps - steps == 1  # one substep, then the step budget was spent
    st = chain.stats
    assert st.slips == 1 and st.slip_s >= 0.25 and st.max_slip_s == st.slip_s
    assert chain.time >= 0.3  # simulated time skipped ahead to now


def test_slipped_and_stepped_time_add_up_and_substeps_stay_small():
    """Physics stays right: every substep is at most max_substep_s, and stepped time plus slipped time
    is all the simulated time that passed."""
    chain, plant = chain_with(cost_s=0.0, max_substep_s=0.0005)
    start = chain.time
    for k in range(30):
        time.sleep(0.002 if k % 10 else 0.15)  # now and then a pause longer than the lag allowed
        chain.touch() if k % 2 else write1(chain, 2, 65, k % 2)  # LED
    assert max(plant.dts) <= 0.0005 + 1e-12
    assert sum(plant.dts) + chain.stats.slip_s == pytest.approx(chain.time - start, abs=1e-9)
    assert chain.stats.slips >= 3  # the long pauses, nobody touching the chain: slipped, not simulated


def test_a_plant_behind_by_less_than_max_lag_catches_up_over_several_touches(monkeypatch):
    """Each reading of the clock costs 20 us of real time, so a 1 ms substep costs about 40 us whatever
    the machine's load: the plant is faster than real time and must catch up without slipping."""
    import crane_io.sim.chain

    clock = TickingClock(tick_s=2e-5)
    monkeypatch.setattr(crane_io.sim.chain, "time", clock)
    chain, plant = chain_with(cost_s=0.0, max_lag_s=10.0, step_budget_s=0.0002)
    start = chain.time
    clock.advance(0.2)  # 200 substeps to catch up: more than one touch's budget
    touches = 1
    while chain.touch() >= chain.max_substep_s:
        touches += 1
    assert touches > 1  # the work was spread over several touches (the line is looked at in between)
    assert chain.stats.slips == 0 and chain.stats.slip_s == 0.0
    assert sum(plant.dts) == pytest.approx(chain.time - start, abs=1e-9)  # every instant was simulated
    assert chain.time - start >= 0.2


def test_a_host_silent_through_a_slip_still_trips_the_bus_watchdog():
    chain, _ = chain_with(cost_s=0.02)
    write1(chain, 2, MODE, MODE_CURRENT)
    write1(chain, 2, WATCHDOG, 5)  # 100 ms
    write1(chain, 2, TORQUE, 1)
    time.sleep(0.4)  # the host is silent for 0.4 s; the plant cannot catch up and slips
    assert read1(chain, 2, WATCHDOG) == 0xFF  # expired: the silence counts, whatever the plant did
    assert chain.stats.slips >= 1
    assert not chain.actuator_command().torque_enabled[0]


def test_a_host_that_keeps_talking_never_trips_the_watchdog_of_a_slow_plant():
    chain, _ = chain_with(cost_s=0.02)  # 20 times slower than real time: slips all the time
    write1(chain, 2, MODE, MODE_CURRENT)
    write1(chain, 2, WATCHDOG, 127)  # 2.54 s: only a host silent that long may trip it
    write1(chain, 2, TORQUE, 1)
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        write1(chain, 2, 65, 1)
        time.sleep(0.005)
    assert read1(chain, 2, WATCHDOG) == 127
    assert chain.stats.slips >= 1 and chain.actuator_command().torque_enabled[0]


def test_over_a_pty_every_instruction_is_answered_while_the_plant_lags(tmp_path):
    """sim-serve with a plant slower than real time answers every instruction of a dynamixel-sdk client."""
    chain, _ = chain_with(cost_s=0.02)
    with PtyServer(chain, tmp_path / "crane") as server:
        port = PatientPort(str(tmp_path / "crane"))
        assert port.openPort() and port.setBaudRate(3_000_000)
        ph = PacketHandler(2.0)
        try:
            time.sleep(0.3)  # the server thread falls behind while nobody talks
            write = GroupSyncWrite(port, ph, GOAL_CURRENT, 2)
            write.addParam(2, [0, 0])
            results = []
            for k in range(10):
                results.append(ph.ping(port, 2 + k % 8)[1])
                write.txPacket()
            assert results == [COMM_SUCCESS] * 10
        finally:
            port.closePort()
    assert server.error is None
    assert chain.stats.slips >= 1 and chain.stats.slip_s > 0.1
    assert chain.stats.replies_sent >= 10


def test_lockstep_never_slips():
    chain, _ = chain_with(cost_s=0.0)
    chain.set_clock("lockstep")
    time.sleep(0.15)
    assert chain.touch() == 0.0 and chain.lag_s == 0.0
    write1(chain, 2, 65, 1)
    assert chain.stats.slips == 0 and chain.stats.slip_s == 0.0


def test_sim_serve_reports_slip_in_its_status_and_summary():
    from collect.cli.sim_serve import slip_summary, status_line

    chain, _ = chain_with(cost_s=0.0)
    assert "slipped    0.00 s (0 times)" in status_line(chain)
    assert slip_summary(chain) == "Simulated time never slipped: the plant kept up with real time."
    chain.stats.slips, chain.stats.slip_s, chain.stats.max_slip_s = 3, 1.25, 0.8
    assert "slipped    1.25 s (3 times)" in status_line(chain)
    assert slip_summary(chain).startswith("Simulated time slipped 3 times, 1.25 s in all (largest 0.800 s)")
    chain.set_clock("lockstep")
    assert "slipped" not in status_line(chain)  # lockstep time never slips: nothing to report


def test_the_pty_server_keeps_stepping_a_plant_that_is_behind(tmp_path, monkeypatch):
    """While the plant is behind real time the server looks at the line without waiting (select with
    timeout 0) and steps on; only an up-to-date plant lets it idle for idle_touch_s."""
    from crane_io.sim import transport

    chain, plant = chain_with(cost_s=0.0, max_lag_s=10.0, step_budget_s=1e-9)  # one substep per touch
    waits = []
    real_select = transport.select.select

    def recording_select(r, w, x, timeout=None):
        if r and w == []:
            waits.append(timeout)
        return real_select(r, w, x, timeout)

    monkeypatch.setattr(transport.select, "select", recording_select)
    time.sleep(0.05)  # 50 ms behind: 50 touches of one substep each to catch up
    with PtyServer(chain, tmp_path / "crane") as server:
        deadline = time.monotonic() + 30
        while len(waits) < 20 and time.monotonic() < deadline:
            time.sleep(0.01)
    assert server.error is None
    assert waits.count(0.0) >= 10  # came straight back to step on, instead of idling 5 ms per substep
    assert chain.stats.slips == 0


def test_return_delay_counts_from_the_instructions_arrival(monkeypatch):
    """Time spent stepping the plant is part of the Return Delay Time, not added to it: after a 50 ms
    plant step the eight replies of a Sync Read (500 us each) are already due, so nothing sleeps."""
    import crane_io.sim.chain as chain_module

    plant = SlowPlant(SimplePlant.from_arm(ARM), 0.0)
    chain = SimulatedChain.for_arm(ARM, plant, clock="wall")  # factory Return Delay Time: 500 us
    slept = []
    real_sleep = time.sleep

    def recording_sleep(seconds):
        slept.append(seconds)
        real_sleep(seconds)

    monkeypatch.setattr(chain_module.time, "sleep", recording_sleep)
    sync_read = p.instruction_packet(p.BROADCAST_ID, p.INST_SYNC_READ, bytes((126, 0, 10, 0, *range(2, 10))))
    plant.cost_s = 0.05
    real_sleep(0.002)  # a substep to take: 50 ms
    assert len(p.PacketParser().feed(chain.feed(sync_read))) == 8
    assert [s for s in slept if s != 0.05] == []  # the replies were due when the plant was done
    plant.cost_s = 0.0
    slept.clear()
    start = time.monotonic()
    assert len(p.PacketParser().feed(chain.feed(sync_read))) == 8
    assert time.monotonic() - start >= 8 * 500e-6  # a quick plant: the replies wait their turn
    assert sum(slept) <= 8 * 500e-6 + 1e-9  # each to its deadline, never more than the delays
