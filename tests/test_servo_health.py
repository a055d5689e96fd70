"""The simulated servos' health (crane_io.sim.servo_health): the heating curve, the trip times of the
overheating and overload bits, the input voltage bit, and what the servos of a simulated chain make of them
(Shutdown mask, alert bit, torque off, cleared by a reboot once the cause is gone)."""

import math
from dataclasses import replace

import numpy as np
import pytest

from crane_io.dynamixel.control_table import X_SERIES
from crane_io.errors import ConfigError
from crane_io.sim.arm_plant import ArmPlant
from crane_io.sim.chain import SimulatedChain
from crane_io.sim.plant_config import load_plant_config
from crane_io.sim.servo_health import (
    INPUT_VOLTAGE_BIT,
    MOTOR_THERMAL,
    OVERHEATING_BIT,
    OVERLOAD_BIT,
    OverloadConfig,
    ServoHealth,
    SupplyConfig,
    ThermalConfig,
)

XM430, XM540 = "XM430-W350", "XM540-W270"
OFF_O, OFF_T, OFF_S = OverloadConfig(), ThermalConfig(), SupplyConfig()


def _run(health, current, seconds, dt=0.01, velocity=0.0, enabled=True):
    n = len(health.temperature)
    for _ in range(round(seconds / dt)):
        health.step([enabled] * n, [current] * n, [velocity] * n, dt)


# ---- temperature -------------------------------------------------------------------------------------

def test_the_winding_follows_the_first_order_heating_curve_whatever_the_step():
    thermal = ThermalConfig(enabled=True, ambient_c=25.0)
    m = MOTOR_THERMAL[XM430]
    rise = 1.5 ** 2 * m.resistance_ohm * m.thermal_resistance  # K at 1.5 A, steady state
    for dt in (0.002, 0.5):
        h = ServoHealth([XM430], OFF_O, thermal, OFF_S)
        assert h.readings()[1] == [25.0]  # starts at the ambient
        _run(h, 1.5, 60.0, dt=dt)
        want = 25.0 + rise * (1 - math.exp(-60.0 / m.time_constant_s))
        assert h.temperature[0] == pytest.approx(want, rel=1e-9)
    _run(h, 0.0, 3000.0, dt=1.0)  # no current: back to the ambient
    assert h.temperature[0] == pytest.approx(25.0, abs=1e-3)


def test_each_model_heats_with_its_own_parameters_and_a_plant_may_override_them():
    h = ServoHealth([XM430, XM540], OFF_O, ThermalConfig(enabled=True), OFF_S)
    _run(h, 1.0, 30.0, dt=0.5)
    assert h.temperature[0] > h.temperature[1] > 25.0  # the XM540's winding has less resistance
    fast = ServoHealth([XM430, XM540], OFF_O, ThermalConfig(enabled=True, time_constant_s=1.0,
                                                             thermal_resistance=10.0), OFF_S)
    _run(fast, 1.0, 20.0, dt=0.5)
    steady = [25.0 + 10.0 * MOTOR_THERMAL[m].resistance_ohm for m in (XM430, XM540)]
    assert fast.temperature.tolist() == pytest.approx(steady, abs=1e-3)


def test_the_overheating_bit_comes_when_the_temperature_exceeds_the_limit():
    thermal = ThermalConfig(enabled=True, ambient_c=25.0, time_constant_s=10.0, thermal_resistance=20.0)
    h = ServoHealth([XM430], OFF_O, thermal, OFF_S)
    current = 1.0
    rise = current ** 2 * MOTOR_THERMAL[XM430].resistance_ohm * 20.0  # 104 K
    # Present Temperature (1 C) reads 81 once T >= 80.5: t = -tau ln(1 - 55.5 / rise)
    trip = -10.0 * math.log(1 - 55.5 / rise)
    dt = 0.01
    t = 0.0
    while not h.error_bits()[0]:
        h.step([True], [current], [0.0], dt)
        t += dt
        assert t < 60
    assert t == pytest.approx(trip, abs=dt)
    assert h.error_bits().tolist() == [OVERHEATING_BIT]


# ---- overload ----------------------------------------------------------------------------------------

def test_the_overload_bit_after_a_stall_at_the_maximum_output_for_time_s():
    overload = OverloadConfig(enabled=True, time_s=0.5)
    stall = 12.0 / MOTOR_THERMAL[XM540].resistance_ohm  # 4.4 A at 12 V
    h = ServoHealth([XM540], overload, OFF_T, OFF_S)
    _run(h, stall, 0.48)
    assert h.error_bits().tolist() == [0]
    _run(h, stall, 0.04)
    assert h.error_bits().tolist() == [OVERLOAD_BIT]
    _run(h, stall, 0.01, velocity=0.5)  # the output moves: the timer starts again
    assert h.error_bits().tolist() == [0]
    _run(h, stall, 0.3)
    _run(h, stall, 0.3, enabled=False)  # torque off: no output at all
    _run(h, stall, 0.3)
    assert h.error_bits().tolist() == [0]


def test_a_stall_below_the_maximum_output_never_overloads():
    h = ServoHealth([XM430], OverloadConfig(enabled=True, time_s=0.2), OFF_T, OFF_S)
    _run(h, 0.6, 5.0)  # e.g. a Current Limit of 600 mA holding against a wall
    assert h.error_bits().tolist() == [0]


def test_a_lower_supply_lowers_the_maximum_output():
    overload = OverloadConfig(enabled=True, time_s=0.2)
    current = 0.96 * 11.0 / MOTOR_THERMAL[XM430].resistance_ohm
    at_12 = ServoHealth([XM430], overload, OFF_T, OFF_S)
    at_11 = ServoHealth([XM430], overload, OFF_T, SupplyConfig(enabled=True, voltage=11.0))
    _run(at_12, current, 1.0)
    _run(at_11, current, 1.0)
    assert at_12.error_bits().tolist() == [0]
    assert at_11.error_bits().tolist() == [OVERLOAD_BIT | 0]


# ---- supply ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("volts, bits", [(9.0, INPUT_VOLTAGE_BIT), (9.5, 0), (12.0, 0), (16.0, 0),
                                         (16.2, INPUT_VOLTAGE_BIT)])
def test_the_input_voltage_bit_outside_the_min_max_voltage_limit(volts, bits):
    h = ServoHealth([XM430, XM540], OFF_O, OFF_T, SupplyConfig(enabled=True, voltage=volts))
    h.step([True, True], [0.0, 0.0], [0.0, 0.0], 0.002)
    assert h.readings()[0] == [volts, volts]
    assert h.error_bits().tolist() == [bits, bits]


def test_the_supply_sags_under_load():
    supply = SupplyConfig(enabled=True, voltage=10.0, resistance_ohm=0.2)
    h = ServoHealth([XM430, XM540], OFF_O, OFF_T, supply)
    h.step([True, True], [0.5, 1.0], [0.0, 0.0], 0.002)
    assert h.readings()[0] == pytest.approx([9.7, 9.7])
    assert h.error_bits().tolist() == [0, 0]
    h.step([True, True], [1.5, 2.0], [0.0, 0.0], 0.002)
    assert h.readings()[0] == pytest.approx([9.3, 9.3])
    assert h.error_bits().tolist() == [INPUT_VOLTAGE_BIT] * 2


def test_bad_health_values_are_one_sentence(tmp_path):
    path = tmp_path / "p.toml"
    path.write_text('base = "crane-x7"\n[thermal]\nenabled = true\nambient_c = 120\n')
    with pytest.raises(ConfigError, match=r"\[thermal\] ambient_c must be between 0 and 100 C"):
        load_plant_config(path)
    path.write_text('base = "crane-x7"\n[supply]\nvoltag = 9\n')
    with pytest.raises(ConfigError, match="voltag"):
        load_plant_config(path)


# ---- the servos of a simulated chain ------------------------------------------------------------------

def _plant(**health) -> ArmPlant:
    cfg = replace(load_plant_config("crane-x7"), **health)
    return ArmPlant(cfg, seed=1)


def _write(servo, name: str, value: int, now: float) -> None:
    r = X_SERIES[name]
    assert servo.write(r.address, value.to_bytes(r.size, "little", signed=r.signed), now) == 0


def _stall_joint2(chain, amps: float) -> object:
    """joint2's servo (ID 3) in current mode pushing `amps` into its upper end stop."""
    q, _ = chain.plant.state()
    q[1] = math.radians(90.0) + 0.03
    chain.plant.set_state(q=q, dq=np.zeros(len(q)))
    s = chain.servos[3]
    _write(s, "operating_mode", 0, chain.time)
    _write(s, "torque_enable", 1, chain.time)
    _write(s, "goal_current", round(amps / 2.69e-3), chain.time)
    return s


def _until_error(chain, servo, seconds: float) -> int:
    """Advance the chain in 10 ms steps until the servo reports a hardware error (at most `seconds`)."""
    for _ in range(round(seconds / 0.01)):
        chain.advance(0.01)
        if servo.read_register("hardware_error_status"):
            break
    return servo.read_register("hardware_error_status")


@pytest.fixture(scope="module")
def hot_chain():
    plant = _plant(thermal=ThermalConfig(enabled=True, time_constant_s=0.5, thermal_resistance=20.0))
    return SimulatedChain.for_arm(plant.arm, plant, clock="lockstep", period_s=0.002)


def test_overheating_shuts_the_servo_down_until_a_reboot_after_it_cooled(hot_chain):
    chain = hot_chain
    s = _stall_joint2(chain, 2.0)  # 2 A through 2.7 ohm x 20 K/W: 25 C + 218 K
    chain.advance(0.02)
    assert s.read_register("hardware_error_status") == 0 and s.read_register("torque_enable") == 1
    assert _until_error(chain, s, 2.0) == OVERHEATING_BIT
    assert s.read_register("torque_enable") == 0 and s.status_error() & 0x80
    assert s.read_register("present_temperature") > 80
    assert chain.servos[2].read_register("hardware_error_status") == 0  # the others are cool
    _write(s, "temperature_limit", 60, chain.time)  # (EEPROM: the torque is off)
    s.reboot(chain.time)  # still over 60 C: the bit comes back at once
    chain.advance(0.01)
    assert s.read_register("hardware_error_status") == OVERHEATING_BIT
    _write(s, "torque_enable", 1, chain.time)
    assert s.read_register("torque_enable") == 0  # refused while the shutdown is latched
    chain.advance(5.0)  # torque off, no current: it cools
    assert s.read_register("present_temperature") < 30
    s.reboot(chain.time)
    chain.advance(0.01)
    assert s.read_register("hardware_error_status") == 0 and not s.status_error() & 0x80


def test_the_temperature_limit_register_sets_the_trip_point(hot_chain):
    chain = hot_chain
    s = chain.servos[3]
    _write(s, "temperature_limit", 40, chain.time)  # EEPROM: torque is off after the reboot
    _stall_joint2(chain, 1.0)  # 25 C + 54 K: under 80 C, over 40 C
    assert _until_error(chain, s, 3.0) == OVERHEATING_BIT
    assert 40 < s.read_register("present_temperature") < 80


def test_a_stalled_servo_overloads_and_a_low_supply_raises_the_input_voltage_bit():
    plant = _plant(overload=OverloadConfig(enabled=True, time_s=0.3), supply=SupplyConfig(enabled=True,
                                                                                          voltage=9.0))
    chain = SimulatedChain.for_arm(plant.arm, plant, clock="lockstep", period_s=0.002)
    chain.advance(0.01)
    for s in chain.servos.values():  # Input Voltage is not in the default Shutdown mask: alert only
        assert s.read_register("hardware_error_status") == INPUT_VOLTAGE_BIT and s.status_error() & 0x80
        assert s.read_register("present_input_voltage") == 90
    s = _stall_joint2(chain, 4.0)  # over the XM540's 3.3 A stall current at 9 V, into its end stop
    chain.advance(0.2)  # (it bounces off the stop before it settles)
    assert s.read_register("torque_enable") == 1
    for _ in range(300):
        chain.advance(0.01)
        if s.read_register("hardware_error_status") != INPUT_VOLTAGE_BIT:
            break
    assert s.read_register("hardware_error_status") == INPUT_VOLTAGE_BIT | OVERLOAD_BIT
    assert s.read_register("torque_enable") == 0
    assert plant.state()[1][1] == 0.0  # it stood still
    s.reboot(chain.time)  # the overload is gone with the torque; the supply is still low
    chain.advance(0.01)
    assert s.read_register("hardware_error_status") == INPUT_VOLTAGE_BIT


# ---- end to end: crane-collect run ends in a safety stop naming the servo's error ----------------------

QUIET = """
[loop]
status_hz = 0
status_log_s = 10
"""
LEAN_OPERATOR = QUIET + """
[operator]
task = "contact"
press_fraction = 0.8
press_torque_min = 5.5
press_torque_max = 6.0
press_min_s = 3.0
press_max_s = 5.0
"""


def _physics(sims, name: str):
    plant = sims[name].chain.plant
    return getattr(plant, "plant", plant)  # (the hand's wrapper around the arm plant)


def _hot_elbow(k, ctx):  # a user lowers the leader's elbow's Temperature Limit; the winding is at 50 C
    if k == 1:
        ctx.sims["leader"].chain.servos[5].write_register("temperature_limit", 55)


def _brown_out(k, ctx):  # the follower's supply drops to 9 V
    if k == 100:
        health = _physics(ctx.sims, "follower").health
        health.supply = replace(health.supply, voltage=9.0)


@pytest.mark.parametrize("plant, hook, duration, words", [
    ("stall-overload", None, 4.0, "joint4 (ID 5): overload; the servo switched its torque off"),
    ("hot-motor", _hot_elbow, 3.0, "leader: hardware error on dxlsim://leader-"),
    ("supply", _brown_out, 3.0, "follower: hardware error on dxlsim://follower-"),
])
def test_a_fault_from_the_physics_ends_the_session_in_a_safety_stop(tmp_path, plant, hook, duration, words):
    import h5py

    from collect.recorder import read_events
    from collect.runner import RunOptions, SafetyStop, run_session
    from tests.recording import torque_off_everywhere

    fault = {"stall-overload": "overload", "hot-motor": "overheating", "supply": "input voltage error"}[plant]
    if plant == "supply":
        plant = tmp_path / "supply.toml"
        plant.write_text('base = "crane-x7"\n[supply]\nenabled = true\n')
    elif plant == "stall-overload":  # the preset, overloading sooner
        plant = tmp_path / "stall.toml"
        plant.write_text('base = "stall-overload"\n[overload]\nenabled = true\ntime_s = 0.3\n')
    config = tmp_path / "operator.toml"
    config.write_text(LEAN_OPERATOR if fault == "overload" else QUIET)
    seen = {}

    def on_cycle(k, ctx):
        seen["sims"] = ctx.sims
        if hook is not None:
            hook(k, ctx)

    out = tmp_path / "s.h5"
    with pytest.raises(SafetyStop) as info:
        run_session(RunOptions(output=out, sim=True, plant=str(plant), duration=duration, config=config,
                               seed=2, status=False, on_cycle=on_cycle))
    assert words in str(info.value) and fault in str(info.value)
    with h5py.File(out, "r") as f:
        assert f.attrs["complete"] and f.attrs["end_reason"] == "safety_stop"
        stops = [e["message"] for e in read_events(f) if e["kind"] == "safety_stop"]
        assert len(stops) == 1 and fault in stops[0]
    assert torque_off_everywhere(seen["sims"])


@pytest.mark.slow
def test_a_sagging_supply_stops_a_session_recorded_over_ptys(tmp_path):
    """sim-serve --pair on the low-supply preset, crane-collect run over the two links: the servos' input
    voltage error ends the session in a safety stop that names it, torque off everywhere."""
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    import h5py

    from collect.recorder import read_events
    from crane_io.dynamixel import link_registry

    bin_dir = Path(sys.executable).parent
    env = dict(os.environ, **{link_registry.RUNTIME_ENV: str(tmp_path / "run")})
    leader, follower, session = tmp_path / "leader", tmp_path / "follower", tmp_path / "s.h5"
    serve = subprocess.Popen(
        [str(bin_dir / "crane-collect"), "sim-serve", "--pair", "--leader-link", str(leader),
         "--follower-link", str(follower), "--clock", "lockstep", "--seed", "1", "--plant", "low-supply"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 300
        while not (leader.exists() and follower.exists()):
            assert serve.poll() is None and time.monotonic() < deadline, "sim-serve did not come up"
            time.sleep(0.2)
        run = subprocess.run([str(bin_dir / "crane-collect"), "run", "--skip-selftest",
                              "--leader-port", str(leader), "--follower-port", str(follower),
                              "-o", str(session), "--duration", "60", "--quiet"],
                             env=env, capture_output=True, text=True, timeout=900)
    finally:
        serve.send_signal(signal.SIGTERM)
        serve.communicate(timeout=60)
    assert run.returncode == 3, run.stdout + run.stderr
    assert "safety stop" in run.stderr and "input voltage error" in run.stderr
    assert "reboot the servo to clear it" in run.stderr  # not in the Shutdown mask: no torque-off claim
    with h5py.File(session, "r") as f:
        assert f.attrs["complete"] and f.attrs["end_reason"] == "safety_stop"
        events = read_events(f)
        assert [e["kind"] for e in events if e["kind"] == "safety_stop"] == ["safety_stop"]
        assert "input voltage error" in next(e["message"] for e in events if e["kind"] == "safety_stop")
        assert [e["message"] for e in events if e["kind"] == "torque_state"] == [
            "leader: torque off on 8 of 8 servos", "follower: torque off on 8 of 8 servos"]
