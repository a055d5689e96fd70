"""DynamixelBus (the real dynamixel-sdk client) against the simulated CRANE-X7 chain."""

import gc
import time
import warnings

import numpy as np
import pytest

from crane_io.description import default_arm
from crane_io.dynamixel import units
from crane_io.dynamixel.bus import BusState, CommandError, DynamixelBus
from crane_io.dynamixel.faults import ServoMissingError, WatchdogExpiredError, WrongModelError
from crane_io.errors import ConfigError, HardwareError
from crane_io.sim import simulated_arm
from crane_io.sim.transport import PtyServer

ARM = default_arm()
CURRENT_IDS = (2, 3, 5)
HELD_IDS = (4, 6, 7, 8, 9)


@pytest.fixture
def sim():
    arm = simulated_arm()
    yield arm
    arm.close()


@pytest.fixture
def bus(sim):
    with DynamixelBus(sim.url) as b:
        b.ping_all()
        b.configure(watchdog_s=0.1)
        b.torque_on()
        yield b


def reg(sim, sid, name):
    return sim.chain.servos[sid].read_register(name)


def test_ping_all_reports_every_servo_with_model_and_firmware(sim):
    with DynamixelBus(sim.url) as bus:
        infos = bus.ping_all()
    assert sorted(infos) == list(range(2, 10))
    assert infos[3].model == "XM540-W270" and infos[3].joint == "joint2" and infos[3].model_number == 1120
    assert all(i.model == "XM430-W350" for sid, i in infos.items() if sid != 3)
    assert infos[2].firmware == reg(sim, 2, "firmware_version")


def test_wrong_model_names_joint_expected_and_found(sim):
    from dataclasses import replace

    joints = tuple(replace(j, model="XM540-W270") if j.name == "joint3" else j for j in ARM.joints)
    with DynamixelBus(sim.url, replace(ARM, joints=joints)) as bus:
        with pytest.raises(WrongModelError) as info:
            bus.ping_all()
    msg = str(info.value)
    assert "joint3 (ID 4)" in msg and "1020 (XM430-W350)" in msg and "expects a XM540-W270" in msg
    assert sim.url in msg and info.value.found == 1020


def test_missing_servo_names_joint_id_and_port(sim):
    sim.chain.remove_servo(5)
    with DynamixelBus(sim.url) as bus:
        with pytest.raises(ServoMissingError) as info:
            bus.ping_all()
    assert str(info.value) == f"servo joint4 (ID 5) does not answer on {sim.url} (check its cable and power)"
    assert info.value.missing == {"joint4": 5}


def test_no_servo_at_all_says_so(sim):
    for sid in range(2, 10):
        sim.chain.remove_servo(sid)
    with DynamixelBus(sim.url, retries=0) as bus:
        with pytest.raises(ServoMissingError, match="no servo answers on .* at 3000000 bps"):
            bus.ping_all()


def test_configure_sets_modes_delay_limits_and_watchdog(sim):
    with DynamixelBus(sim.url) as bus:
        bus.ping_all()
        bus.configure(watchdog_s=0.1, current_limits={"joint1": 1.0, "joint2": 2.0})
        for sid in CURRENT_IDS:
            assert reg(sim, sid, "operating_mode") == 0
        for sid in HELD_IDS:
            assert reg(sim, sid, "operating_mode") == 3
        for sid in range(2, 10):
            assert reg(sim, sid, "return_delay_time") == 0
            assert reg(sim, sid, "bus_watchdog") == 5
            assert reg(sim, sid, "torque_enable") == 0
        assert reg(sim, 2, "current_limit") == round(1.0 / 2.69e-3)
        assert bus.current_limits[0] == pytest.approx(1.0, abs=2.69e-3)
        assert bus.current_limits[1] == pytest.approx(2.0, abs=2.69e-3)
        assert bus.current_limits[3] == pytest.approx(1193 * 2.69e-3)


@pytest.mark.parametrize("kwargs,match", [
    ({"watchdog_s": 5.0}, "watchdog_s must be between"),
    ({"current_limits": {"joint1": 4.0}}, r"current limit 4.0 A for joint1 is outside 0..3.21 A"),
    ({"current_limits": [1.0, 2.0]}, "current_limits must have 8 entries"),
])
def test_bad_configuration_is_refused_before_anything_is_written(sim, kwargs, match):
    with DynamixelBus(sim.url) as bus:
        with pytest.raises(ConfigError, match=match):
            bus.configure(**kwargs)
    assert reg(sim, 2, "operating_mode") == 3 and reg(sim, 2, "return_delay_time") == 250


def test_torque_on_holds_held_joints_where_they_are(sim):
    held = sim.chain.servos[4]
    held.write_register("goal_position", 3000)  # a stale goal the servo would jump to
    with DynamixelBus(sim.url) as bus:
        bus.configure()
        bus.torque_on()
        assert all(reg(sim, sid, "torque_enable") == 1 for sid in range(2, 10))
        assert reg(sim, 4, "goal_position") == reg(sim, 4, "present_position")
        assert all(reg(sim, sid, "goal_current") == 0 for sid in CURRENT_IDS)


def test_read_state_matches_the_plant_within_one_quantum(sim, bus):
    amps = np.array([0.3, 0.8, 0.0, -0.2, 0.0, 0.0, 0.0, 0.0])
    for _ in range(40):
        bus.read_state()
        bus.write_goal_current(amps)
    state = bus.read_state()
    truth = sim.plant.read()
    assert isinstance(state, BusState) and state.fast
    assert state.position.shape == state.velocity.shape == state.current.shape == (8,)
    assert np.all(np.abs(state.position - truth.position) <= units.RAD_PER_PULSE / 2 + 1e-9)
    assert np.all(np.abs(state.velocity - truth.velocity) <= units.RADS_PER_VELOCITY_LSB / 2 + 1e-9)
    assert np.all(np.abs(state.current - truth.current) <= units.AMPERE_PER_CURRENT_LSB / 2 + 1e-9)
    assert abs(state.velocity[0]) > 0.1, "joint1 should be moving under 0.3 A"


def test_byte_stuffed_fast_reply_is_decoded_correctly(sim, bus):
    # current -1 (FF FF) followed by velocity -3 (FD FF FF FF) puts FF FF FD on the wire: it gets stuffed
    servo = sim.chain.servos[2]
    servo.write_register("present_current", -1)
    servo.write_register("present_velocity", -3)
    servo.write_register("present_position", 2100)
    state = bus.read_state()
    assert state.current[0] == pytest.approx(-2.69e-3)
    assert state.velocity[0] == pytest.approx(-3 * units.RADS_PER_VELOCITY_LSB)
    assert state.position[0] == pytest.approx(float(units.position_to_rad(2100)))


def test_goal_current_reaches_current_mode_servos_clamped(sim, bus):
    sent = bus.write_goal_current(np.array([10.0, -10.0, 5.0, 0.5, 5.0, 5.0, 5.0, 5.0]))
    assert reg(sim, 2, "goal_current") == 1193 and reg(sim, 3, "goal_current") == -2047
    assert reg(sim, 5, "goal_current") == round(0.5 / 2.69e-3)
    np.testing.assert_allclose(sent[[0, 1, 3]], [1193 * 2.69e-3, -2047 * 2.69e-3, 186 * 2.69e-3])
    assert np.all(sent[[2, 4, 5, 6, 7]] == 0)
    assert bus.stats.writes == 1


def test_nan_goal_current_sends_nothing(sim, bus):
    bus.write_goal_current(np.full(8, 0.1))
    before = [reg(sim, sid, "goal_current") for sid in CURRENT_IDS]
    with pytest.raises(CommandError, match="goal current for joint2 is not a finite number"):
        bus.write_goal_current(np.array([0.1, np.nan, 0, 0, 0, 0, 0, 0]))
    with pytest.raises(CommandError, match="needs 8 values"):
        bus.write_goal_current(np.zeros(3))
    assert [reg(sim, sid, "goal_current") for sid in CURRENT_IDS] == before


def test_goal_position_goes_to_held_joints_within_limits(sim, bus):
    goal = np.zeros(8)
    goal[2] = 0.5  # joint3
    goal[5] = 3.0  # joint6: limit is 90 deg
    sent = bus.write_goal_position(goal)
    assert reg(sim, 4, "goal_position") == units.rad_to_position(0.5)
    assert reg(sim, 7, "goal_position") == units.rad_to_position(np.pi / 2)
    assert sent[5] == pytest.approx(np.pi / 2, abs=units.RAD_PER_PULSE)


def test_fast_sync_read_falls_back_to_plain_sync_read_once():
    sim = simulated_arm(fast_sync_read=False)
    try:
        with DynamixelBus(sim.url) as bus:
            bus.configure()
            states = [bus.read_state() for _ in range(4)]
            assert bus.stats.fast is False and "plain sync read" in bus.stats.fallback_note
            assert not states[-1].fast
            truth = sim.plant.read()
            assert np.all(np.abs(states[-1].position - truth.position) <= units.RAD_PER_PULSE)
            ignored = sim.chain.stats.ignored_fast_sync_reads
            bus.read_state()
            assert sim.chain.stats.ignored_fast_sync_reads == ignored, "no fast sync read after fallback"
    finally:
        sim.close()


def test_one_fast_cycle_is_one_read_and_one_write_on_the_wire(sim, bus):
    bus.read_state()
    w0, r0 = bus._port.bytes_written, bus._port.bytes_read
    bus.read_state()
    bus.write_goal_current(np.zeros(8))
    # fast sync read: 14 + 8 instruction bytes; reply 8 + 8 * (10 + 4) bytes; sync write 14 + 3 * 3
    assert bus._port.bytes_written - w0 == 22 + 23
    assert bus._port.bytes_read - r0 == 8 + 8 * 14


def test_leaving_the_block_zeroes_current_and_turns_torque_off(sim):
    bus = DynamixelBus(sim.url)
    with bus:
        bus.configure()
        bus.torque_on()
        bus.write_goal_current(np.full(8, 0.5))
        assert reg(sim, 2, "goal_current") > 0
    assert all(reg(sim, sid, "torque_enable") == 0 for sid in range(2, 10))
    assert all(reg(sim, sid, "goal_current") == 0 for sid in CURRENT_IDS)
    bus.close()  # idempotent
    with pytest.raises(HardwareError, match="closed"):
        bus.read_state()


def test_an_exception_inside_the_block_still_stops_the_arm(sim):
    with pytest.raises(KeyboardInterrupt):
        with DynamixelBus(sim.url) as bus:
            bus.configure()
            bus.torque_on()
            bus.write_goal_current(np.full(8, 0.5))
            raise KeyboardInterrupt
    assert all(reg(sim, sid, "torque_enable") == 0 for sid in range(2, 10))
    assert all(reg(sim, sid, "goal_current") == 0 for sid in CURRENT_IDS)


def test_an_unclosed_bus_warns_when_collected(sim):
    bus = DynamixelBus(sim.url).open()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        del bus
        gc.collect()
    assert any(issubclass(w.category, ResourceWarning) and "was not closed" in str(w.message) for w in caught)


def test_servo_report_and_hardware_errors(sim, bus):
    rows = bus.servo_report()
    assert [r["id"] for r in rows] == list(range(2, 10))
    r = rows[1]
    assert r["answering"] and r["model"] == "XM540-W270" and r["operating_mode"] == 0
    assert r["torque_enabled"] and r["hardware_errors"] == [] and r["voltage_v"] == pytest.approx(12.0)
    assert r["bus_watchdog_s"] == pytest.approx(0.1) and r["return_delay_s"] == 0
    assert bus.read_hardware_errors() == {}
    sim.chain.servos[7].set_hardware_error(0b100100)
    assert bus.read_hardware_errors() == {"joint6": ["overheating", "overload"]}
    sim.chain.remove_servo(4)  # the one sync read fails: servo by servo, naming the silent one
    assert bus.read_hardware_errors() == {"joint3": ["not answering"], "joint6": ["overheating", "overload"]}
    sim.chain.restore_servo(4)


def test_the_watchdog_stops_servos_whose_host_went_silent(sim, bus):
    bus.write_goal_current(np.full(8, 0.2))
    sim.chain.advance(0.3)  # 300 ms without a packet: longer than the 100 ms watchdog
    assert all(sim.chain.servos[sid].watchdog_expired for sid in range(2, 10))
    assert all(row["watchdog_expired"] for row in bus.servo_report())
    # the hardware-error poll (what crane-collect polls) names the stopped servos
    assert bus.read_hardware_errors() == {j: ["bus watchdog expired"] for j in ARM.joint_names}
    with pytest.raises(WatchdogExpiredError, match=r"stopped joint1 \(ID 2\), .*gripper \(ID 9\)") as exc:
        bus.check_watchdog()
    assert set(exc.value.faults) == set(ARM.joint_names)
    # configure re-arms the watchdog: the servos take goal currents again
    bus.configure(watchdog_s=0.1)
    bus.torque_on()
    bus.check_watchdog()
    bus.write_goal_current(np.full(8, 0.2))
    assert reg(sim, 2, "goal_current") == round(0.2 / units.AMPERE_PER_CURRENT_LSB)


def test_a_stalled_loop_learns_that_the_watchdog_stopped_the_arm():
    """Wall clock: the host stalls longer than the watchdog; its next read names the stopped servos
    (a sync write alone would never tell), and leaving the block still turns torque off."""
    sim = simulated_arm(clock="wall", return_delay_time=0)
    try:
        with pytest.raises(WatchdogExpiredError, match="Bus Watchdog .*paused") as exc:
            with DynamixelBus(sim.url) as bus:
                bus.ping_all()
                bus.configure(watchdog_s=0.2)  # long enough that a busy machine does not trip it early
                bus.torque_on()
                bus.read_state()
                bus.write_goal_current(np.full(8, 0.1))
                time.sleep(0.6)  # the loop stalls
                bus.read_state()
        assert set(exc.value.faults) == set(ARM.joint_names)
        assert isinstance(exc.value, HardwareError)
        assert all(reg(sim, sid, "torque_enable") == 0 for sid in range(2, 10))
    finally:
        sim.close()


def test_a_pause_shorter_than_the_watchdog_is_checked_but_not_an_error():
    sim = simulated_arm(clock="wall", return_delay_time=0)
    try:
        with DynamixelBus(sim.url) as bus:
            bus.ping_all()
            bus.configure(watchdog_s=1.0)
            bus.torque_on()
            bus.read_state()
            before = bus.stats.attempts
            time.sleep(0.55)  # over half the watchdog time: the bus confirms, the servos still run
            bus.read_state()
            assert bus.stats.attempts == before + 2  # the watchdog check, then the read itself
            bus.write_goal_current(np.full(8, 0.1))
            assert not any(s.watchdog_expired for s in sim.chain.servos.values())
    finally:
        sim.close()


def test_the_bus_runs_over_a_real_pty(tmp_path):
    sim = simulated_arm()
    try:
        with PtyServer(sim.chain, tmp_path / "crane_x7") as server:
            # a generous reply timeout: the pty's server thread may wait for the CPU on a busy machine
            with DynamixelBus(str(tmp_path / "crane_x7"), latency_ms=250) as bus:
                assert len(bus.ping_all()) == 8
                bus.configure()
                bus.torque_on()
                for _ in range(5):
                    state = bus.read_state()
                    bus.write_goal_current(np.full(8, 0.2))
                assert state.fast and reg(sim, 2, "goal_current") == round(0.2 / 2.69e-3)
            assert server.error is None
        assert all(reg(sim, sid, "torque_enable") == 0 for sid in range(2, 10))
    finally:
        sim.close()
