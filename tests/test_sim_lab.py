"""A simulated lab on the wire: `crane-collect sim-serve --pair` (two arms on ptys, a simulated hand on one)
records, through the hardware code path of `crane-collect run`, a session crane-train trains and
diagnoses; the links are announced for `crane-collect ports`, and stale announcements are not listed."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from collect.cli import main as collect_main
from collect.config import load_config
from collect.operator import SimulatedOperator
from collect.sim_lab import HandOnPlant, SimulatedLab
from crane_io.description import default_arm
from crane_io.dynamixel import link_registry
from crane_io.sim.plant_api import ActuatorCommand
from crane_io.sim.simple_plant import SimplePlant

ARM = default_arm()
BIN = Path(sys.executable).parent
N = len(ARM.joint_names)
BIL = np.array([n in ARM.bilateral_joints for n in ARM.joint_names])


@pytest.fixture
def runtime_dir(tmp_path, monkeypatch):
    root = tmp_path / "run"
    monkeypatch.setenv(link_registry.RUNTIME_ENV, str(root))
    return root


def _command(alive: bool, mode_bilateral: int = 0) -> ActuatorCommand:
    mode = np.where(BIL, mode_bilateral, 3)
    return ActuatorCommand(torque_enabled=np.full(N, alive), operating_mode=mode, goal_current=np.zeros(N),
                           goal_position=np.zeros(N), position_gains=np.zeros((N, 3)),
                           current_limit=np.full(N, 2.0))


def test_the_hand_takes_hold_after_the_delay_moves_the_arm_and_lets_go_when_the_torque_goes_off():
    plant = SimplePlant.from_arm(ARM)
    hand = HandOnPlant(plant, SimulatedOperator(4, ARM, 500.0, load_config()), ARM, hand_delay_s=0.5)
    dt = 0.002
    for _ in range(100):  # torque off: no hand
        hand.step(_command(False), dt)
    assert not hand.holding and hand.engaged_since is None
    for _ in range(200):  # alive, but in position mode (not bilateral control): no hand
        hand.step(_command(True, mode_bilateral=3), dt)
    assert not hand.holding and hand.engaged_since is None
    pushes = []
    for _ in range(2000):  # 4 s alive in current mode
        hand.step(_command(True), dt)
        pushes.append(np.abs(plant.external_torque).max())
    assert hand.holding and hand.engagements == 1
    assert abs(hand.engaged_since - 0.6) < 1e-9  # 100 + 200 steps before it
    first_push = next(i for i, p in enumerate(pushes) if p > 0) * dt
    assert first_push >= 0.5 - dt  # not before the delay
    assert max(pushes) > 0.05  # the hand really pushes (N m)
    hand.step(_command(False), dt)  # torque off: the hand lets go at once
    assert not hand.holding and np.all(plant.external_torque == 0)
    for _ in range(400):
        hand.step(_command(True), dt)
    assert hand.engagements == 2  # a new engagement, a new take


def test_announced_links_are_listed_while_live_and_stale_ones_are_dropped(runtime_dir, tmp_path):
    from crane_io.sim.chain import SimulatedChain
    from crane_io.sim.transport import PtyServer

    server = PtyServer(SimulatedChain.for_arm(ARM, SimplePlant.from_arm(ARM), clock="lockstep"),
                       tmp_path / "arm").start()
    try:
        live = link_registry.announce(link_registry.SimLink(
            link=str(tmp_path / "arm"), pty=server.slave_path, arm="leader", plant="simple", clock="lockstep",
            hand=True, pid=os.getpid()))
        dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                              text=True, check=True)
        stale = link_registry.announce(link_registry.SimLink(
            link=str(tmp_path / "gone"), pty="/dev/pts/999", arm="follower", plant="simple", clock="wall",
            hand=False, pid=int(dead.stdout)))
        (runtime_dir / "crane-x7" / "links" / "junk.json").write_text("{not json")
        assert live is not None and stale is not None
        assert [e.link for e in link_registry.live_links(clean=False)] == [str(tmp_path / "arm")]
        out = CliRunner().invoke(collect_main, ["ports"])
        assert out.exit_code == 0, out.output
        assert f"{tmp_path / 'arm'}  simulated leader (simple, lockstep clock, hand on it)" in out.output
        assert "gone" not in out.output
        assert not stale.exists() and not (runtime_dir / "crane-x7" / "links" / "junk.json").exists()
    finally:
        server.stop()
    # the server is gone, its link too: the entry is stale now
    assert link_registry.live_links() == [] and not live.exists()
    out = CliRunner().invoke(collect_main, ["ports"])
    assert "no simulated arm is being served" in out.output


@pytest.mark.parametrize("args, words", [
    (["--pair", "--leader-link", "/tmp/x"], "--pair needs both --leader-link and --follower-link"),
    (["--link", "/tmp/x", "--task", "contact"], "--task goes with --pair"),
    (["--pair", "--leader-link", "/tmp/x", "--follower-link", "/tmp/x"], "two different paths"),
    ([], "give --link PATH"),
])
def test_sim_serve_refuses_incomplete_or_mixed_options_in_one_sentence(args, words, runtime_dir):
    out = CliRunner().invoke(collect_main, ["sim-serve", *args])
    assert out.exit_code != 0 and words in out.output and "Traceback" not in out.output


def test_a_lab_builds_with_the_objects_in_the_followers_world_only():
    lab = SimulatedLab.build(plant="contact-wall", seed=2, hand_on="leader", task="contact")
    assert lab.hand.plant.environment == [] and lab.plants["follower"].environment
    swapped = SimulatedLab.build(plant="baseline", seed=2, hand_on="follower")
    assert isinstance(swapped.plants["follower"], HandOnPlant)
    assert not isinstance(swapped.plants["leader"], HandOnPlant)


def _wait_for(predicate, timeout_s: float, what: str):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.mark.slow
def test_a_session_recorded_over_sim_serve_pair_trains_and_diagnoses(tmp_path, runtime_dir):
    env = dict(os.environ, **{link_registry.RUNTIME_ENV: str(runtime_dir)})
    leader, follower = tmp_path / "leader", tmp_path / "follower"
    # lockstep: the physics waits for the controller, so a loaded test machine slows the run but
    # cannot trip the Bus Watchdog (see tests/test_collect_hardware_path.py)
    serve = subprocess.Popen([str(BIN / "crane-collect"), "sim-serve", "--pair", "--leader-link", str(leader),
                              "--follower-link", str(follower), "--clock", "lockstep", "--seed", "3"],
                             env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        _wait_for(lambda: len(link_registry.live_links(clean=False)) == 2, 120, "two announced links")
        ports = subprocess.run([str(BIN / "crane-collect"), "ports"], env=env, capture_output=True, text=True,
                               timeout=120)
        assert f"{leader}  simulated leader" in ports.stdout and "hand on it" in ports.stdout
        assert f"{follower}  simulated follower" in ports.stdout
        session = tmp_path / "s.h5"
        run = subprocess.run([str(BIN / "crane-collect"), "run", "--leader-port", str(leader),
                              "--follower-port", str(follower), "-o", str(session), "--duration", "40",
                              "--quiet", "--skip-selftest"], env=env, capture_output=True, text=True,
                             timeout=900)
        assert run.returncode == 0, run.stdout + run.stderr
    finally:
        serve.send_signal(signal.SIGTERM)
        out, _ = serve.communicate(timeout=60)
    assert serve.returncode == 0, out
    assert "The hand took hold 1 time(s)." in out
    assert link_registry.live_links(clean=False) == [] and not leader.exists()

    info = subprocess.run([str(BIN / "crane-train"), "info", str(session)], capture_output=True, text=True,
                          timeout=300)
    assert info.returncode == 0, info.stdout + info.stderr
    assert "hardware" in info.stdout and "hand on the leader" in info.stdout
    moving = [float(line.split()[2].rstrip("%")) for line in info.stdout.splitlines()
              if line.strip().startswith("joint") and "moving" in line]
    assert len(moving) == 3 and min(moving) > 40  # the hand moves every joint, most of the time
    model = tmp_path / "model"
    fit = subprocess.run([str(BIN / "crane-train"), "fit", str(session), "--model", "rigid-body",
                          "--scale-to-data", "--no-progress", "-o", str(model)], capture_output=True,
                         text=True, timeout=600)
    assert fit.returncode == 0, fit.stdout + fit.stderr
    diag = subprocess.run([str(BIN / "crane-train"), "diagnose", str(model), str(session), "--json"],
                          capture_output=True, text=True, timeout=600)
    assert diag.returncode == 0, diag.stdout + diag.stderr
    doc = json.loads(diag.stdout)
    # the crane-x7 plant has Coulomb friction on every joint and the plain rigid-body model none:
    # the diagnosis of the wire-recorded session names it
    best = {c["joint"]: c["effect"] for c in doc["candidates"] if c["rank"] == 1 and c["significant"]}
    assert best.get("joint2") in ("coulomb", "stiction", "coulomb-asym"), doc["summary"]
