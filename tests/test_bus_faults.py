"""Each injected fault is reported clearly, never turns into made-up readings, and leaves no torque on."""

import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from fakes import DropReplies, FlipCrcByte, OverloadBit, VanishingServo

from crane_io.dynamixel.bus import DynamixelBus
from crane_io.dynamixel.faults import CommunicationError, ServoFaultError, ServoMissingError
from crane_io.shutdown import Terminated, handle_termination
from crane_io.sim import simulated_arm
from crane_io.sim.transport import PtyServer

IDS = range(2, 10)
CURRENT_IDS = (2, 3, 5)


@pytest.fixture
def sim():
    arm = simulated_arm()
    yield arm
    arm.close()


def running_bus(sim, **kwargs):
    bus = DynamixelBus(sim.url, **kwargs).open()
    bus.ping_all()
    bus.configure(watchdog_s=0.1)
    bus.torque_on()
    bus.write_goal_current(np.full(8, 0.3))
    return bus


def torque(sim):
    return {sid: sim.chain.servos[sid].read_register("torque_enable") for sid in IDS}


def assert_stopped(sim, except_ids=()):
    assert all(v == 0 for sid, v in torque(sim).items() if sid not in except_ids), torque(sim)
    for sid in CURRENT_IDS:
        if sid not in except_ids:
            assert sim.chain.servos[sid].read_register("goal_current") == 0


def test_one_corrupted_reply_is_retried_and_counted(sim):
    with running_bus(sim) as bus:
        expected = bus.read_state().position
        with FlipCrcByte(sim.chain, once=True) as flip:
            state = bus.read_state()
        assert flip.hits == 1 and bus.stats.retries == 1 and bus.stats.failures == 0
        np.testing.assert_array_equal(state.position, expected)


def test_corrupted_replies_beyond_the_retries_raise_and_stop_the_arm(sim):
    with pytest.raises(CommunicationError) as info:
        with running_bus(sim, retries=2) as bus, FlipCrcByte(sim.chain, every=1):
            bus.read_state()
    assert "failed 3 times in a row" in str(info.value) and sim.url in str(info.value)
    assert bus.stats.failures == 1
    assert_stopped(sim)


def test_a_failed_read_never_returns_zeros_or_old_values(sim):
    with running_bus(sim) as bus:
        bus.read_state()
        with DropReplies(sim.chain, count=None):
            for _ in range(3):
                with pytest.raises(CommunicationError):
                    bus.read_state()
        assert bus.stats.failures == 3


def test_dropped_replies_within_the_budget_are_recovered(sim):
    with running_bus(sim, retries=2) as bus:
        bus.read_state()  # the first read decides fast vs plain sync read
        with DropReplies(sim.chain, count=2) as drop:
            state = bus.read_state()
    assert drop.hits == 2 and bus.stats.retries == 2 and state.position.shape == (8,)
    assert_stopped(sim)


def test_the_error_budget_catches_a_flaky_link_even_when_retries_succeed(sim):
    with running_bus(sim, retries=2, error_budget=5) as bus, FlipCrcByte(sim.chain, every=2):
        with pytest.raises(CommunicationError, match=r"lost or corrupted 6 replies within 1 s \(budget 5\)"):
            for _ in range(20):
                bus.read_state()
                bus.write_goal_current(np.zeros(8))
    assert_stopped(sim)


def test_a_servo_that_vanishes_mid_run_is_named_and_the_rest_are_stopped(sim):
    bus = running_bus(sim)
    cycles = 0
    with pytest.raises(ServoMissingError) as info:
        with VanishingServo(sim.chain, 5, after_cycles=3), bus:
            for _ in range(10):
                bus.read_state()
                bus.write_goal_current(np.full(8, 0.3))
                cycles += 1
    assert cycles == 3
    expected = f"servo joint4 (ID 5) stopped answering on {sim.url} (check its cable and power)"
    assert str(info.value) == expected
    assert info.value.missing == {"joint4": 5}
    assert set(bus.stop_failures) == {"joint4"}
    assert_stopped(sim, except_ids=(5,))
    # the unreachable servo is stopped by its own bus watchdog once the host is silent for 100 ms
    sim.chain.advance(0.2)
    assert not sim.chain.servos[5].driving


def test_an_overload_bit_is_reported_by_joint_and_torque_is_off_everywhere(sim):
    with pytest.raises(ServoFaultError) as info:
        with running_bus(sim) as bus, OverloadBit(sim.chain, 5):
            bus.read_state()
    assert f"hardware error on {sim.url}: joint4 (ID 5): overload" in str(info.value)
    assert info.value.faults == {"joint4": ["overload"]}
    assert_stopped(sim)


def test_a_plant_reported_fault_surfaces_the_same_way(sim):
    with running_bus(sim) as bus:
        sim.plant.errors[3] = 1 << 2  # overheating on joint2, raised by the physics
        bus.write_goal_current(np.zeros(8))  # one lockstep period lets the chain pick it up
        with pytest.raises(ServoFaultError, match=r"joint2 \(ID 3\): overheating"):
            bus.read_state()
        assert bus.read_state(check_faults=False).position.shape == (8,)


def test_sigterm_raises_terminated_and_restores_the_old_handler():
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(Terminated):
        with handle_termination():
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1)  # the signal is delivered before this returns
    assert signal.getsignal(signal.SIGTERM) is before


CHILD = textwrap.dedent("""
    import sys
    import numpy as np
    from crane_io.dynamixel.bus import DynamixelBus
    from crane_io.shutdown import handle_termination

    with handle_termination(), DynamixelBus(sys.argv[1], latency_ms=250) as bus:  # patient: a busy CPU
        bus.ping_all()
        bus.configure(watchdog_s=1.0)
        bus.torque_on()
        print("ready", flush=True)
        while True:
            bus.read_state()
            bus.write_goal_current(np.full(8, 0.2))
""")


def test_sigterm_to_a_running_bus_loop_leaves_torque_off(tmp_path):
    sim = simulated_arm()
    link = tmp_path / "arm"
    try:
        with PtyServer(sim.chain, link):
            child = subprocess.Popen([sys.executable, "-c", CHILD, str(link)], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
            try:
                assert child.stdout.readline().strip() == "ready", child.stderr.read()
                deadline = time.monotonic() + 20
                while sim.chain.servos[2].read_register("goal_current") == 0 and time.monotonic() < deadline:
                    time.sleep(0.01)
                assert all(v == 1 for v in torque(sim).values())
                child.send_signal(signal.SIGTERM)
                child.wait(timeout=20)
            finally:
                if child.poll() is None:
                    child.kill()
                    child.wait()
        assert child.returncode != 0
        assert_stopped(sim)
    finally:
        sim.close()


def test_a_port_that_goes_away_mid_run_is_one_clear_error_and_close_does_not_raise(tmp_path):
    sim = simulated_arm()
    try:
        server = PtyServer(sim.chain, tmp_path / "arm").start()
        bus = DynamixelBus(str(tmp_path / "arm"), latency_ms=250).open()  # patient: a busy machine
        bus.configure()
        bus.torque_on()
        bus.read_state()
        server.stop()  # the other end of the line disappears, like an unplugged U2D2
        with pytest.raises(CommunicationError, match=r"stopped working \(.+\); is the U2D2 still plugged in"):
            bus.read_state()
        bus.close()
        assert set(bus.stop_failures) == set(bus.joint_names)
    finally:
        sim.close()
