"""crane-collect on the hardware code path, with the arms OUTSIDE its process.

Two simulated CRANE-X7 chains are served on pseudo-terminals by this test process;
`crane-collect run --leader-port ... --follower-port ...` drives them as hardware (ports checked, one
bus thread per arm, real-time pacing). SIGTERM or Ctrl+C mid-run must leave every servo of both arms
with goal current 0 and torque off, checked here in the servos' own memory, not through crane-collect's
own report. Also the start-up checks (every ID answers with its model) and `crane-collect check` against
ports.
"""

import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from collect.cli import main
from collect.recorder import read_events
from collect.runner import RunOptions, run_session
from crane_io.description import default_arm
from crane_io.errors import CraneError
from crane_io.sim.chain import SimulatedChain
from crane_io.sim.simple_plant import SimplePlant
from crane_io.sim.transport import PtyServer
from tests.recording import wait_for_rows

ARM = default_arm()
CLI = str(Path(sys.executable).parent / "crane-collect")
CURRENT_MODE_IDS = [sid for sid, n in zip(ARM.servo_ids, ARM.joint_names) if n in ARM.bilateral_joints]
JOINT2 = ARM.joint_names.index("joint2")


@pytest.fixture
def arms(tmp_path):
    """Two chains on ptys at tmp_path/leader and tmp_path/follower. Their clock is lockstep (one control
    period per Goal Current write): on a shared, loaded test machine crane-collect can be descheduled for
    more than the 0.1 s Bus Watchdog, and wall-clock arms would then trip it or run away, as real arms
    would; here the physics waits for the controller, so the test stays about signals."""
    chains, servers = {}, []
    try:
        for name in ("leader", "follower"):
            plant = SimplePlant.from_arm(ARM)
            chain = SimulatedChain.for_arm(ARM, plant, clock="lockstep", return_delay_time=0)
            chains[name] = chain
            servers.append(PtyServer(chain, link=tmp_path / name).start())
        yield chains
    finally:
        for s in servers:
            s.stop()


def _servos(chains):
    return [s for c in chains.values() for s in c.servos.values()]


def _signed16(raw: int) -> int:
    return raw - 0x10000 if raw >= 0x8000 else raw




def _start(tmp_path, arms):
    """crane-collect under way; once it records, a hand on the leader holds a load on the follower's
    joint2 (equal and opposite torques, so the arms stay put) and the loop commands real current."""
    cfg = tmp_path / "c.toml"
    cfg.write_text("[loop]\nstatus_hz = 0\n")
    out = tmp_path / "s.h5"
    proc = subprocess.Popen([CLI, "run", "--leader-port", str(tmp_path / "leader"),
                             "--follower-port", str(tmp_path / "follower"), "--duration", "60",
                             "--config", str(cfg), "-o", str(out), "--skip-selftest"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_for_rows(proc, out, 50)
    load = np.zeros(8)
    load[JOINT2] = 0.3  # N m
    arms["leader"].plant.set_external_torque(-load)
    arms["follower"].plant.set_external_torque(load)
    wait_for_rows(proc, out, 200)
    return proc, out


@pytest.mark.parametrize("sig, presses", [(signal.SIGTERM, 1), (signal.SIGINT, 3)])
def test_signal_mid_run_leaves_arms_outside_the_process_with_torque_off(arms, tmp_path, sig, presses):
    proc, out = _start(tmp_path, arms)
    servos = _servos(arms)
    assert len(servos) == 16
    # mid-run: every servo under torque, the current-mode ones carrying the load
    assert all(s.read_register("torque_enable") == 1 for s in servos)
    assert all(s.read_register("bus_watchdog") == 5 for s in servos)  # armed: 0.1 s = 5 x 20 ms
    assert any(_signed16(c.servos[sid].read_register("goal_current")) != 0
               for c in arms.values() for sid in CURRENT_MODE_IDS)
    # SIGTERM once, or an impatient Ctrl+C pressed three times: the repeats must not cut the safe stop
    for _ in range(presses):
        proc.send_signal(sig)
        time.sleep(0.005)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr and "session" in stderr  # the summary was printed
    # checked in the servos themselves
    assert [s.read_register("torque_enable") for s in servos] == [0] * 16
    assert [_signed16(c.servos[sid].read_register("goal_current"))
            for c in arms.values() for sid in CURRENT_MODE_IDS] == [0] * 6
    with h5py.File(out, "r") as f:
        assert f.attrs["complete"] and f.attrs["source"] == "hardware"
        assert f.attrs["end_reason"] == ("interrupted" if sig == signal.SIGINT else "terminated")
        what = "Ctrl+C (SIGINT)" if sig == signal.SIGINT else "SIGTERM"
        assert [e["message"] for e in read_events(f) if e["kind"] == "interrupted"] == [f"stopped by {what}"]
        assert f["follower/t"].shape[0] >= 200
        # the hardware path records the servos' own time stamps: increasing
        assert np.all(np.diff(f["follower/t"][()]) > 0)


@pytest.mark.parametrize("fault, words", [
    ("wrong model", "joint3 (ID 4)"),
    ("missing", "servo joint6 (ID 7) does not answer"),
])
def test_start_refuses_a_missing_or_wrong_servo_on_real_ports(tmp_path, fault, words):
    """Before any torque is on and before the session file exists."""
    servers, chains = [], {}
    joints = tuple(replace(j, model="XM540-W270") if j.name == "joint3" else j for j in ARM.joints)
    try:
        for name in ("leader", "follower"):
            arm = replace(ARM, joints=joints) if (name == "follower" and fault == "wrong model") else ARM
            chain = SimulatedChain.for_arm(arm, SimplePlant.from_arm(arm), return_delay_time=0)
            if name == "follower" and fault == "missing":
                chain.remove_servo(7)
            chains[name] = chain
            servers.append(PtyServer(chain, link=tmp_path / name).start())
        with pytest.raises(CraneError, match=words.replace("(", r"\(").replace(")", r"\)")) as info:
            run_session(RunOptions(output=tmp_path / "s.h5", leader_port=str(tmp_path / "leader"),
                                   follower_port=str(tmp_path / "follower"), duration=1.0, status=False,
                                   skip_selftest=True))
        assert "follower" in str(info.value) and "\n" not in str(info.value)
    finally:
        for s in servers:
            s.stop()
    assert not (tmp_path / "s.h5").exists()
    assert all(s.read_register("torque_enable") == 0 for c in chains.values() for s in c.servos.values())


def test_check_lists_every_servo_and_fails_on_a_hardware_error(arms, tmp_path):
    arms["follower"].servos[5].set_hardware_error(0x20)  # joint4 overload
    r = CliRunner().invoke(main, ["check", "--port", str(tmp_path / "leader"),
                                  "--port", str(tmp_path / "follower")])
    assert r.exit_code == 1, r.output
    rows = [line for line in r.output.splitlines() if line.strip().startswith("ID ")]
    assert len(rows) == 16
    assert all("fw" in x and "mode" in x and "limits" in x and " V " in x and " C " in x for x in rows)
    bad = [x for x in rows if "errors none" not in x]
    assert len(bad) == 1 and "joint4" in bad[0] and "verload" in bad[0]
    assert all(s.read_register("torque_enable") == 0 for s in _servos(arms))


def test_check_sim_is_clean():
    r = CliRunner().invoke(main, ["check", "--sim"])
    assert r.exit_code == 0, r.output
    rows = [line for line in r.output.splitlines() if line.strip().startswith("ID ")]
    assert [x.split()[3] for x in rows] == ["XM430-W350", "XM540-W270"] + ["XM430-W350"] * 6
    assert all("errors none" in x for x in rows)
