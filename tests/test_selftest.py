"""`crane-collect selftest` (collect/selftest.py, selftest_checks.py, selftest_record.py) on in-process
simulated arms in lockstep: healthy arms pass, each planted miswiring (crane_io/sim/wiring_faults.py)
fails on the check that should see it; the record and `run`'s refusal of hardware arms without one."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from collect.cli import main
from collect.cli.selftest import SIM_PERIOD_S, simulated_selftest_arm
from collect.selftest import run_selftest
from collect.selftest_checks import FAIL, PASS, Finding
from collect.selftest_record import (
    SelftestMissingError,
    calibration_digest,
    record_path,
    require_selftest,
    save_record,
)
from crane_io.description import default_arm
from crane_io.sim.wiring_faults import WiringFaults, apply_wiring_faults

ARM = default_arm()
FAULTS = {
    "swap": WiringFaults(swap_ids=(2, 3)),
    "reversed": WiringFaults(reversed_joints=("joint2",)),
    "model": WiringFaults(wrong_models=((5, "XM540-W270"),)),
    "sign": WiringFaults(current_sign=-1.0),
    "scale": WiringFaults(current_scale=2.0),
}


KEPT = ("current_limit", "velocity_limit", "profile_velocity")  # what the test sets low, then restores


def _selftest(faults: WiringFaults, seed: int = 0):
    with simulated_selftest_arm(ARM, seed, faults) as sim:
        def registers():
            return {(sid, r): s.read_register(r) for sid, s in sim.chain.servos.items() for r in KEPT}

        before = registers()
        result = run_selftest(sim.url, ARM, None, period_s=SIM_PERIOD_S, paced=False)
        result.restored = registers() == before
        result.torque_off = all(s.read_register("torque_enable") == 0 for s in sim.chain.servos.values())
        return result


@pytest.fixture(scope="module")
def results():
    """Every arm of this file tested once: two healthy seeds and each fault."""
    out = {f"healthy{s}": _selftest(WiringFaults(), s) for s in (0, 1)}
    out.update({name: _selftest(f) for name, f in FAULTS.items()})
    return out


def _failing(result) -> set[tuple[str, str]]:
    return {(f.check, f.joint) for f in result.findings if f.failed}


@pytest.mark.parametrize("name", ["healthy0", "healthy1"])
def test_healthy_arm_passes_every_check(results, name):
    r = results[name]
    assert r.passed and not _failing(r)
    checks = {f.check for f in r.findings}
    assert checks == {"identity", "encoder", "direction", "gravity"}
    gravity = [f for f in r.findings if f.check == "gravity"]
    assert len(gravity) == 7 and all(f.status == PASS for f in gravity)
    assert 0 < r.duration_s < 60  # the arm's own time


@pytest.mark.parametrize("name", ["healthy0", "sign", "swap"])
def test_the_arm_is_left_with_torque_off_and_its_own_limits(results, name):
    assert results[name].torque_off and results[name].restored


def test_swapped_ids_fail_on_the_model_numbers_before_torque(results):
    r = results["swap"]
    assert _failing(r) == {("identity", "joint1"), ("identity", "joint2")}
    assert r.duration_s == 0  # no torque went on
    assert "two IDs swapped" in next(f.sentence for f in r.findings if f.failed)


def test_wrong_model_fails_on_its_joint(results):
    r = results["model"]
    assert _failing(r) == {("identity", "joint4")}
    assert "XM540-W270" in next(f.sentence for f in r.findings if f.failed)


def test_reversed_joint_fails_on_gravity(results):
    r = results["reversed"]
    assert not r.passed and ("gravity", "joint2") in _failing(r)


def test_current_of_the_wrong_sign_fails_direction_and_gravity(results):
    failing = _failing(results["sign"])
    assert ("direction", "joint2") in failing and ("gravity", "joint2") in failing
    sentence = next(f.sentence for f in results["sign"].findings if f.check == "direction" and f.failed)
    assert "wrong sign" in sentence


def test_torque_constant_off_by_two_fails_gravity_naming_the_factor(results):
    r = results["scale"]
    assert {c for c, _ in _failing(r)} == {"gravity"}
    sentence = next(f.sentence for f in r.findings if f.failed)
    assert "x2.0" in sentence and "torque constant" in sentence


def test_faulty_wiring_swaps_models_and_signs():
    from crane_io.sim.simple_plant import SimplePlant

    plant = SimplePlant.from_arm(ARM, initial_position=np.full(8, 0.1))
    faults = WiringFaults(swap_ids=(3, 4), reversed_joints=("joint1",), current_scale=2.0)
    wrapped, models = apply_wiring_faults(plant, ARM, faults)
    assert wrapped.servo_ids[1:3] == (4, 3) and models[4] == "XM540-W270" and models[3] == "XM430-W350"
    reading = wrapped.read()
    assert reading.position[0] == pytest.approx(-0.1) and reading.position[1] == pytest.approx(0.1)
    healthy = apply_wiring_faults(plant, ARM, WiringFaults())
    assert healthy == (plant, {j.servo_id: j.model for j in ARM.joints})


def _result(passed: bool):
    from collect.selftest import SelftestResult

    status = PASS if passed else FAIL
    return SelftestResult([Finding("identity", "joint1", status, "ID 2 is a XM430-W350.")], 30.0)


def test_record_counts_only_for_its_calibration(tmp_path):
    from crane_io.dynamixel.calibration import build_calibration, load_calibration, save_calibration

    cal_file = save_calibration(build_calibration("left", "port-x", ARM.joint_names, np.zeros(8)),
                                tmp_path / "left.toml")
    cal = load_calibration(cal_file)
    path = record_path("/dev/ttyUSB9", cal)
    assert path == tmp_path / "left.selftest.toml"
    with pytest.raises(SelftestMissingError, match="no self-test on record.*crane-collect selftest --port"):
        require_selftest("leader", "/dev/ttyUSB9", cal)
    save_record(_result(False), path, arm_name="left", key="port-x", calibration=cal)
    with pytest.raises(SelftestMissingError, match="failed its last self-test"):
        require_selftest("leader", "/dev/ttyUSB9", cal)
    save_record(_result(True), path, arm_name="left", key="port-x", calibration=cal)
    require_selftest("leader", "/dev/ttyUSB9", cal)  # passes
    cal_file.write_text(cal_file.read_text().replace("offset_rad = 0.0", "offset_rad = 0.01", 1))
    assert calibration_digest(load_calibration(cal_file)) != calibration_digest(cal)
    with pytest.raises(SelftestMissingError, match="another calibration"):
        require_selftest("leader", "/dev/ttyUSB9", load_calibration(cal_file))


def test_run_refuses_hardware_arms_without_a_self_test_before_torque_on(tmp_path, monkeypatch):
    """The hardware path (two simulated arms on pseudo-terminals): found and configured, then refused."""
    import crane_io.dynamixel.port
    from collect.runner import RunOptions, run_session
    from crane_io.sim.chain import SimulatedChain
    from crane_io.sim.simple_plant import SimplePlant
    from crane_io.sim.transport import PtyServer

    # the pty servers' threads may wait for a core on a busy machine
    monkeypatch.setattr(crane_io.dynamixel.port, "SDK_LATENCY_MS", 250.0)
    servers, chains = [], []
    try:
        for name in ("leader", "follower"):
            chains.append(SimulatedChain.for_arm(ARM, SimplePlant.from_arm(ARM), return_delay_time=0))
            servers.append(PtyServer(chains[-1], link=tmp_path / name).start())
        options = RunOptions(output=tmp_path / "s.h5", leader_port=str(tmp_path / "leader"),
                             follower_port=str(tmp_path / "follower"), duration=0.5, status=False)
        with pytest.raises(SelftestMissingError, match=r"leader arm .*`crane-collect selftest --port .*skip"):
            run_session(options)
    finally:
        for server in servers:
            server.stop()
    assert not (tmp_path / "s.h5").exists()
    assert all(s.read_register("torque_enable") == 0 for c in chains for s in c.servos.values())
    assert all(c.stats.packets_received > 0 for c in chains)  # both arms were found first


def test_cli_reports_failing_findings_with_exit_1():
    r = CliRunner().invoke(main, ["selftest", "--sim", "--wrong-model", "5=XM540-W270"])
    assert r.exit_code == 1, r.output
    assert "identity   joint4   FAIL" in r.output and "Self-test FAILED" in r.output


@pytest.mark.parametrize("args, words", [
    (["selftest"], "give --port PORT"),
    (["selftest", "--sim", "--swap-ids", "2"], "--swap-ids takes two different servo IDs"),
    (["selftest", "--sim", "--wrong-model", "5=XM999"], "--wrong-model takes ID=MODEL"),
    (["selftest", "--port", "/dev/null", "--current-scale", "2"], "go with --sim"),
    (["sim-serve", "--pair", "--leader-link", "a", "--follower-link", "b", "--swap-ids", "2,3"],
     "serve one arm"),
])
def test_cli_bad_input_is_one_sentence(args, words):
    r = CliRunner().invoke(main, args)
    assert r.exit_code not in (0, 1) and words in r.output and "Traceback" not in r.output, r.output
