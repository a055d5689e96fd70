"""crane-collect run end to end in simulation: tracking, the session format, faults, signals, crashes."""

import io
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import tomllib

from collect.recorder import read_events
from collect.runner import RunOptions, SafetyStop, run_session
from crane_io.description import default_arm
from tests.recording import torque_off_everywhere, wait_for_rows

ARM = default_arm()
BIL = np.array([n in ARM.bilateral_joints for n in ARM.joint_names])
CLI = str(Path(sys.executable).parent / "crane-collect")

# a short alignment (the simple plant starts at 0) and no status line for in-process runs
TEST_CONFIG = """
[loop]
status_hz = {status}
status_log_s = {log}
[operator.start_deg]
joint2 = 0.0
joint4 = -20.0
"""

REQUIRED_ATTRS = ("format", "format_version", "rate_hz", "joint_names", "source")
OPTIONAL_ATTRS = ("tau_source", "torque_constants", "servo_ids", "servo_models", "firmware_versions",
                  "leader_firmware_versions", "follower_firmware_versions", "bilateral_joints",
                  "software_version", "start_time", "config_toml", "rate_hz_achieved", "complete", "seed")
ARM_MEMBERS = ("t", "q", "tau", "dq_servo", "current", "goal_current", "dq", "tau_dis", "tau_res", "q_goal")
TIMING = ("cycle_start", "period", "bus_time_leader", "bus_time_follower", "compute_time", "overrun")


@pytest.fixture
def cfg(tmp_path):
    p = tmp_path / "test.toml"
    p.write_text(TEST_CONFIG.format(status=0, log=10))
    return p


def _opts(tmp_path, cfg, **kw):
    base = dict(output=tmp_path / "s.h5", sim=True, plant="simple", duration=3.0, config=cfg, seed=5,
                status=False)
    base.update(kw)
    return RunOptions(**base)


def _torque_off_everywhere(sims) -> bool:
    return torque_off_everywhere(sims, min_servos=15)  # one servo may have vanished from the bus


def test_sim_session_tracks_the_leader_and_meets_the_format(tmp_path, cfg):
    seen = {}
    r = run_session(_opts(tmp_path, cfg, on_cycle=lambda k, ctx: seen.setdefault("sims", ctx.sims)))
    assert r.end_reason == "duration" and r.cycles == 1500
    with h5py.File(r.path, "r") as f:
        for a in REQUIRED_ATTRS + OPTIONAL_ATTRS:
            assert a in f.attrs, a
        assert f.attrs["format"] == "crane-session" and f.attrs["source"] == "sim"
        assert f.attrs["complete"] and f.attrs["end_reason"] == "duration"
        assert list(f.attrs["joint_names"]) == list(ARM.joint_names)
        cfg_used = tomllib.loads(f.attrs["config_toml"])
        assert cfg_used["operator"]["start_deg"]["joint4"] == -20.0
        n = f["follower/t"].shape[0]
        assert n == 1500
        for arm in ("leader", "follower"):
            for m in ARM_MEMBERS:
                ds = f[f"{arm}/{m}"]
                assert ds.shape[0] == n and (ds.ndim == 1 or ds.shape[1] == 8), (arm, m)
        for m in TIMING:
            assert f[f"timing/{m}"].shape == (n,)
        assert "period_p99_s" in f["timing"].attrs
        t = f["follower/t"][()]
        assert np.allclose(np.diff(t), 0.002)
        # tau is the commanded torque: goal current x torque constant on the bilateral joints
        kt = f.attrs["torque_constants"]
        assert np.allclose(f["follower/tau"][:, BIL], f["follower/goal_current"][:, BIL] * kt[BIL], atol=1e-5)
        q_goal = f["follower/q_goal"][()]
        assert np.isnan(q_goal[:, BIL]).all() and np.isfinite(q_goal[:, ~BIL]).all()
        # the follower tracks the leader: error small against the motion's range
        ql, qf = f["leader/q"][:, BIL], f["follower/q"][:, BIL]
        motion = ql.max(0) - ql.min(0)
        assert (motion > 0.05).any()
        rms = np.sqrt(((ql - qf) ** 2).mean(0))
        assert (rms < 0.1 * np.maximum(motion, 0.05)).all(), (rms, motion)
        kinds = [e["kind"] for e in read_events(f)]
        assert kinds[0] == "start" and "end" in kinds
        states = [e["message"] for e in read_events(f) if e["kind"] == "torque_state"]
        assert states == ["leader: torque off on 8 of 8 servos", "follower: torque off on 8 of 8 servos"]
        # every attribute and member written is documented in the session format
        doc = (Path(__file__).parents[1] / "docs" / "file-formats.md").read_text()
        written = set(f.attrs) | set(f["timing"].attrs)
        f.visit(lambda name: written.add(name.split("/")[-1]))
        assert not {w for w in written if f"`{w}`" not in doc and f"`/{w}" not in doc}
        # a simulated session never stores the plant's truth
        assert not [k for k in f.attrs if "truth" in k or "hidden" in k or "effect" in k or k == "plant"]
        assert "simple" not in str(dict(f.attrs).get("config_toml", ""))
    assert _torque_off_everywhere(seen["sims"])


class _Terminal(io.StringIO):
    def isatty(self):
        return True


@pytest.mark.parametrize("tty", [True, False])
def test_status_line_rewrites_a_terminal_and_spares_a_log(tmp_path, tty):
    """On a terminal the status line is rewritten in place as often as status_hz asks; into a pipe or a
    log file at most one line per status_log_s of wall time (here: none in a short run), and the final
    summary always comes."""
    cfg = tmp_path / "c.toml"
    cfg.write_text(TEST_CONFIG.format(status=500, log=3600))
    stream = _Terminal() if tty else io.StringIO()
    run_session(_opts(tmp_path, cfg, duration=0.5, status=True, stream=stream))
    text = stream.getvalue()
    assert "session " in text and "tracking rms" in text  # the summary
    status = text.count(" s |")
    if tty:
        assert status >= 1 and "\r" in text
    else:
        assert status == 0 and "\r" not in text


def test_refuses_to_overwrite_a_session(tmp_path, cfg):
    out = tmp_path / "s.h5"
    out.write_bytes(b"keep me")
    with pytest.raises(Exception, match="already exists; pass `force`"):
        run_session(_opts(tmp_path, cfg))
    assert out.read_bytes() == b"keep me"


@pytest.mark.parametrize("fault, words", [
    ("vanish", "joint2"),
    ("overload", "overload"),
])
def test_injected_fault_ends_in_a_safe_stop_with_an_event(tmp_path, cfg, fault, words):
    seen = {}

    def inject(k, ctx):
        seen["sims"] = ctx.sims
        if k == 250:
            if fault == "vanish":
                ctx.sims["follower"].chain.remove_servo(3)  # joint2's XM540 drops off the bus
            else:
                ctx.sims["leader"].chain.servos[5].set_hardware_error(0x20)  # joint4 overload

    with pytest.raises(SafetyStop) as info:
        run_session(_opts(tmp_path, cfg, duration=5.0, on_cycle=inject))
    assert words in str(info.value)
    with h5py.File(tmp_path / "s.h5", "r") as f:
        assert f.attrs["complete"] and f.attrs["end_reason"] == "safety_stop"
        events = read_events(f)
        stops = [e for e in events if e["kind"] == "safety_stop"]
        assert len(stops) == 1 and words in stops[0]["message"]
        assert 240 <= f["follower/t"].shape[0] <= 260  # stopped right away
    # every servo that still answers has its torque off
    assert _torque_off_everywhere(seen["sims"])


def test_an_exception_mid_run_stops_both_arms_and_closes_the_file(tmp_path, cfg):
    seen = {}

    def boom(k, ctx):
        seen["sims"] = ctx.sims
        if k == 200:
            raise RuntimeError("a bug in the loop")

    with pytest.raises(RuntimeError, match="a bug in the loop"):
        run_session(_opts(tmp_path, cfg, on_cycle=boom))
    assert _torque_off_everywhere(seen["sims"])
    with h5py.File(tmp_path / "s.h5", "r") as f:
        assert f.attrs["complete"] and f.attrs["end_reason"] == "error"
        errors = [e["message"] for e in read_events(f) if e["kind"] == "error"]
        assert errors == ["RuntimeError: a bug in the loop"]
        states = [e["message"] for e in read_events(f) if e["kind"] == "torque_state"]
        assert states == ["leader: torque off on 8 of 8 servos", "follower: torque off on 8 of 8 servos"]
        assert f["follower/t"].shape[0] <= 200


def _start(tmp_path, status=2, duration=60, log=10):
    cfg = tmp_path / "sub.toml"
    cfg.write_text(TEST_CONFIG.format(status=status, log=log))
    out = tmp_path / "sub.h5"
    proc = subprocess.Popen([CLI, "run", "--sim", "--plant", "simple", "--duration", str(duration),
                             "--config", str(cfg), "-o", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return proc, out




@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_ctrl_c_and_sigterm_leave_a_complete_file_and_torque_off(tmp_path, sig):
    proc, out = _start(tmp_path)
    wait_for_rows(proc, out, 300)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr and "session" in stderr  # the summary was printed
    with h5py.File(out, "r") as f:
        assert f.attrs["complete"]
        assert f.attrs["end_reason"] == ("interrupted" if sig == signal.SIGINT else "terminated")
        events = read_events(f)
        assert [e for e in events if e["kind"] == "interrupted"]
        # read back from the servos over the bus after the safe stop
        states = [e["message"] for e in events if e["kind"] == "torque_state"]
        assert states == ["leader: torque off on 8 of 8 servos", "follower: torque off on 8 of 8 servos"]
        n = f["follower/t"].shape[0]
        assert all(f[f"{a}/{m}"].shape[0] == n for a in ("leader", "follower") for m in ARM_MEMBERS)


def test_sigkill_loses_at_most_the_last_second(tmp_path):
    proc, out = _start(tmp_path, status=20, log=0)  # a status line every 50 ms even into the pipe
    wait_for_rows(proc, out, 1500)
    time.sleep(0.3)
    os.kill(proc.pid, signal.SIGKILL)
    stdout, stderr = proc.communicate(timeout=30)
    # the status lines say how far the session had got when the process died (at least)
    reached = [float(line.split(" s |")[0]) for line in stderr.splitlines() if " s |" in line]
    assert reached, stderr
    with h5py.File(out, "r", libver="latest", swmr=True) as f:
        assert not f.attrs["complete"]
        lengths = [f[f"{a}/{m}"].shape[0] for a in ("leader", "follower") for m in ARM_MEMBERS]
        n = min(lengths)
        t = f["follower/t"][:n]
        assert np.all(np.isfinite(t)) and np.all(np.diff(t) > 0)
        assert t[-1] >= reached[-1] - 1.0 - 0.01
        assert np.isfinite(f["follower/q"][:n]).all()


def test_hardware_path_over_ptys_refuses_arms_that_disagree(tmp_path, monkeypatch):
    """The hardware code path (real ports, one bus thread per arm) against two simulated chains served
    on pseudo-terminals: arms 90 deg apart are not brought together automatically."""
    import crane_io.dynamixel.port
    from collect.runner import StartRefused
    from crane_io.sim.chain import SimulatedChain
    from crane_io.sim.simple_plant import SimplePlant
    from crane_io.sim.transport import PtyServer

    # the pty servers' threads may wait for a core on a busy machine: replies get ~0.5 s, not ~35 ms
    monkeypatch.setattr(crane_io.dynamixel.port, "SDK_LATENCY_MS", 250.0)

    poses = {"leader": np.zeros(8), "follower": np.where(np.arange(8) == 1, np.pi / 2, 0.0)}
    servers, chains = [], {}
    try:
        for name, q0 in poses.items():
            chain = SimulatedChain.for_arm(ARM, SimplePlant.from_arm(ARM, initial_position=q0),
                                           return_delay_time=0)
            chains[name] = chain
            servers.append(PtyServer(chain, link=tmp_path / name).start())
        with pytest.raises(StartRefused, match="joint2 differ by 90 deg"):
            run_session(RunOptions(output=tmp_path / "s.h5", leader_port=str(tmp_path / "leader"),
                                   follower_port=str(tmp_path / "follower"), duration=1.0, status=False,
                                   skip_selftest=True))
    finally:
        for s in servers:
            s.stop()
    assert not (tmp_path / "s.h5").exists()  # nothing recorded
    assert all(s.read_register("torque_enable") == 0 for c in chains.values() for s in c.servos.values())


def _session_attrs(path) -> dict:
    with h5py.File(path, "r") as f:
        return {k: str(v) for k, v in f.attrs.items() if k != "start_time"}


def test_truth_of_the_follower_plant_goes_to_its_own_file_only_when_asked(tmp_path, cfg):
    import json

    from click.testing import CliRunner

    from collect.cli import main
    from crane_io.sim.arm_plant import ArmPlant
    from crane_io.sim.plant_config import load_plant_config

    common = ["run", "--sim", "--plant", "hidden-coulomb", "--seed", "3", "--duration", "0.2",
              "--config", str(cfg), "--quiet"]
    truth = tmp_path / "truth.json"
    asked = CliRunner().invoke(main, [*common, "-o", str(tmp_path / "a.h5"), "--truth", str(truth)])
    assert asked.exit_code == 0, asked.output
    written = json.loads(truth.read_text())
    follower = ArmPlant(load_plant_config("hidden-coulomb"), seed=2 * 3 + 1)  # the leader's seed is 6
    assert written == json.loads(json.dumps(follower.truth()))
    assert written["seed"] == 7 and written["hidden"]["effect"] == "coulomb"
    # the session is the same as without --truth: nothing of the truth went into it
    plain = CliRunner().invoke(main, [*common, "-o", str(tmp_path / "b.h5")])
    assert plain.exit_code == 0, plain.output
    assert _session_attrs(tmp_path / "a.h5") == _session_attrs(tmp_path / "b.h5")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.h5", "b.h5", "test.toml", "truth.json"]


@pytest.mark.parametrize("args, words", [
    (["--leader-port", "/dev/null", "--follower-port", "/dev/zero"], "Error: --truth only applies to --sim"),
    (["--sim", "--plant", "simple"], "Error: --truth needs an arm plant"),
])
def test_truth_is_refused_in_one_sentence_before_anything_starts(tmp_path, cfg, args, words):
    from click.testing import CliRunner

    from collect.cli import main

    out = tmp_path / "s.h5"
    r = CliRunner().invoke(main, ["run", *args, "--truth", str(tmp_path / "t.json"), "-o", str(out),
                                  "--config", str(cfg), "--duration", "1"])
    assert r.exit_code != 0 and r.output.startswith(words), r.output
    assert r.output.count("\n") == 1 and "Traceback" not in r.output
    assert not out.exists() and not (tmp_path / "t.json").exists()
