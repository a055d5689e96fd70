"""Any bilateral joint set: the set as configuration and on the command line, seven-joint
bilateral control in simulation, held joints held, and the simulated operator's moving fractions.

The simulated runs are lockstep: their simulated time does not depend on the machine's load, and
nothing here asserts a speed.
"""

from __future__ import annotations

from dataclasses import replace

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from collect.alignment import SafetyStop
from collect.cli import main
from collect.config import ARM_JOINTS, PAPER_JOINTS, load_config, parse_joints
from collect.operator import SimulatedOperator
from collect.recorder import read_events
from collect.runner import RunOptions, run_arm, run_session
from crane_io.description import default_arm
from crane_io.errors import ConfigError
from tests.recording import torque_off_everywhere

SEVEN = ARM_JOINTS
NO_JOINT3 = ("joint1", "joint2", "joint4", "joint5", "joint6", "joint7")


# ---- configuration --------------------------------------------------------------------------------

def test_the_default_is_the_papers_three_joints():
    cfg = load_config()
    assert cfg.bilateral == PAPER_JOINTS == ("joint1", "joint2", "joint4")
    assert run_arm(cfg).bilateral_joints == default_arm().bilateral_joints
    assert 'joints = ["joint1", "joint2", "joint4"]' in cfg.to_toml()


@pytest.mark.parametrize("value, expect", [
    ('"all"', SEVEN),
    ('["joint7", "joint1", "joint2"]', ("joint1", "joint2", "joint7")),  # the arm's order
    ('["joint1", "joint2", "joint4", "gripper"]', ("joint1", "joint2", "joint4", "gripper")),
])
def test_the_toml_names_the_bilateral_joints(tmp_path, value, expect):
    f = tmp_path / "c.toml"
    f.write_text(f"[bilateral]\njoints = {value}\n")
    cfg = load_config(f)
    assert cfg.bilateral == expect
    assert run_arm(cfg).bilateral_joints == expect
    assert run_arm(cfg).held_joints == tuple(n for n in default_arm().joint_names if n not in expect)


@pytest.mark.parametrize("value, words", [
    ('["joint1", "joint9"]', "unknown joint 'joint9'"),
    ('["joint2", "joint2"]', "names joint2 twice"),
    ("[]", "names no joint"),
    ('"joint1,wrist"', "unknown joint 'wrist'"),  # a string is read as --joints is
    ("[1, 2]", "as text"),
    ("3", "must be a list"),
])
def test_a_bad_joint_set_in_the_toml_is_one_sentence(tmp_path, value, words):
    f = tmp_path / "c.toml"
    f.write_text(f"[bilateral]\njoints = {value}\n")
    with pytest.raises(ConfigError) as err:
        load_config(f)
    assert words in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("text, expect", [
    ("all", SEVEN), ("ALL", SEVEN), ("joint6, joint1", ("joint1", "joint6")),
    ("joint1,joint2,joint4,gripper", ("joint1", "joint2", "joint4", "gripper")),
    ("all,gripper", SEVEN + ("gripper",)),
])
def test_the_joints_option_text(text, expect):
    assert parse_joints(text) == expect
    assert load_config().with_bilateral_joints(text).bilateral == expect


@pytest.mark.parametrize("text", ["", ",", "joint8", "joint1,joint1", "all,joint3"])
def test_a_bad_joints_option_is_refused(text):
    with pytest.raises(ConfigError) as err:
        load_config().with_bilateral_joints(text)
    assert str(err.value).startswith("`joints` ") and "\n" not in str(err.value)


def test_the_coefficient_gravity_model_is_refused_beyond_the_papers_joints(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text('[controller]\ngravity_model = "coefficients"\n')
    cfg = load_config(f)  # the paper's joints: fine
    assert cfg.with_bilateral_joints("joint1,joint2").bilateral == ("joint1", "joint2")
    with pytest.raises(ConfigError, match="no gravity term for joint5"):
        cfg.with_bilateral_joints("joint1,joint2,joint4,joint5")
    f.write_text('[controller]\ngravity_model = "coefficients"\n[bilateral]\njoints = "all"\n')
    with pytest.raises(ConfigError, match="no gravity term for joint3"):
        load_config(f)


# ---- the command line ------------------------------------------------------------------------------

@pytest.mark.parametrize("cmd", [["run", "--sim", "-o", "{out}"], ["sim-serve", "--link", "{out}"]])
@pytest.mark.parametrize("joints, words", [("joint1,wrist", "unknown joint 'wrist'"),
                                           ("joint4,joint4", "joint4 twice")])
def test_a_bad_joints_option_on_the_command_line_is_one_sentence(tmp_path, cmd, joints, words):
    out = str(tmp_path / "s.h5")
    r = CliRunner().invoke(main, [c.format(out=out) for c in cmd] + ["--joints", joints])
    assert r.exit_code != 0 and r.exception is None or isinstance(r.exception, SystemExit)
    assert words in r.output and "Traceback" not in r.output
    assert r.output.strip().count("\n") == 0 and r.output.startswith("Error: ")
    assert not (tmp_path / "s.h5").exists()


@pytest.mark.parametrize("args, held", [
    (["--plant", "crane-x7", "--joints", "joint1"], "joint2"),  # the paper's preset: effects on 2 and 4
    (["--plant", "crane-x7-7dof", "--joints", ",".join(NO_JOINT3)], "joint3"),  # named: effects on all 7
])
def test_a_preset_with_effects_on_a_held_joint_is_one_sentence(tmp_path, args, held):
    r = CliRunner().invoke(main, ["run", "--sim", *args, "--duration", "1", "-o", str(tmp_path / "s.h5")])
    assert r.exit_code != 0 and "Traceback" not in r.output
    assert r.output.startswith("Error: ") and r.output.strip().count("\n") == 0
    assert held in r.output and not (tmp_path / "s.h5").exists()


def test_the_help_texts_name_the_option():
    for cmd in ("run", "sim-serve"):
        r = CliRunner().invoke(main, [cmd, "--help"])
        assert r.exit_code == 0 and "--joints LIST" in r.output and "joint1..joint7" in r.output


# ---- seven joints in simulation --------------------------------------------------------------------

def _fast_alignment(tmp_path, extra: str = "") -> str:
    f = tmp_path / "fast.toml"
    f.write_text("[safety]\nhoming_speed = 1.0\n" + extra)  # the alignment in about half the time
    return str(f)


def _run(tmp_path, joints, seed, duration=3.0, plant=None):
    out = tmp_path / f"s{seed}.h5"
    result = run_session(RunOptions(output=out, sim=True, seed=seed, duration=duration, status=False,
                                    joints=joints, config=_fast_alignment(tmp_path), plant=plant))
    return result, out


def _plant(tmp_path, joints: tuple[str, ...]) -> str:
    """A plant integrating `joints` (rotor inertia and viscous friction on each, as crane-x7-7dof has):
    the seven-joint preset itself has effects on every joint, which a run holding some refuses."""
    rotor = {"joint1": 0.0115, "joint2": 0.010, "joint3": 0.011, "joint4": 0.009, "joint5": 0.0055,
             "joint6": 0.006, "joint7": 0.006}
    lines = ['base = "crane-x7"', f"joints = {list(joints)!r}".replace("'", '"')]
    for j in joints:
        lines += ["[[effects]]", 'effect = "rotor-inertia"', f'joint = "{j}"', f"inertia = {rotor[j]}",
                  "[[effects]]", 'effect = "viscous"', f'joint = "{j}"', "viscous = 0.04"]
    f = tmp_path / "plant.toml"
    f.write_text("\n".join(lines) + "\n")
    return str(f)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_seven_joint_bilateral_control_is_stable(tmp_path, seed):
    result, out = _run(tmp_path, "all", seed)
    assert result.end_reason == "duration" and result.breach is None
    assert result.cycles == 1500
    assert tuple(result.tracking_rms) == SEVEN
    for joint, rms in result.tracking_rms.items():
        assert np.degrees(rms) < 2.0, (joint, np.degrees(rms))
    with h5py.File(out) as f:
        assert [str(n) for n in f.attrs["bilateral_joints"]] == list(SEVEN)
        assert all(str(s) == "goal_current" for s in f.attrs["tau_source"][:7])
        err = np.abs(f["leader/q"][:, :7] - f["follower/q"][:, :7])
        assert np.degrees(err.max()) < 8.0  # bounded: no joint ever runs away from its leader
        assert np.isfinite(f["follower/tau_res"][:, :7]).all()
        kinds = {e["kind"] for e in read_events(f)}
    assert "safety_stop" not in kinds


def test_held_joints_stay_held_when_the_set_is_a_subset(tmp_path):
    cfg = load_config()
    joints = ("joint1", "joint2", "joint4", "joint6")
    result, out = _run(tmp_path, ",".join(joints), 4, plant=_plant(tmp_path, joints))
    assert result.end_reason == "duration" and tuple(result.tracking_rms) == ("joint1", "joint2", "joint4",
                                                                              "joint6")
    names = default_arm().joint_names
    with h5py.File(out) as f:
        assert [str(n) for n in f.attrs["bilateral_joints"]] == ["joint1", "joint2", "joint4", "joint6"]
        for arm in ("leader", "follower"):
            q = f[f"{arm}/q"][()]
            goal = f[f"{arm}/q_goal"][()]
            for held in ("joint3", "joint5", "joint7", "gripper"):
                i = names.index(held)
                assert np.allclose(goal[:, i], cfg.held[held])
                assert np.degrees(np.abs(q[:, i] - cfg.held[held]).max()) < 1.0, (arm, held)
            j6 = names.index("joint6")
            assert np.isnan(goal[:, j6]).all()
            assert np.ptp(q[:, j6]) > 0.05  # the operator moves the bilateral wrist joint


def test_the_default_plant_runs_with_joint3_held(tmp_path):
    # without --plant the seven-joint arm is restricted to the bilateral joints: the held joint's
    # friction is no part of the physics (a plant the user names is taken as it is, above)
    result, out = _run(tmp_path, ",".join(NO_JOINT3), 3, duration=2.0)
    assert result.end_reason == "duration" and tuple(result.tracking_rms) == NO_JOINT3
    with h5py.File(out) as f:
        i = default_arm().joint_names.index("joint3")
        assert np.degrees(np.ptp(f["follower/q"][:, i])) < 1.0


def test_the_restricted_preset_keeps_only_the_integrated_joints_effects():
    from crane_io.sim.plant_config import load_plant_config

    full = load_plant_config("hidden-wrist-coulomb")
    part = full.restricted_to(NO_JOINT3)
    assert part.joints == NO_JOINT3 and part.hidden == full.hidden
    assert {e.joint for e in part.effects} == set(NO_JOINT3)
    assert all(k[1] != "joint3" for k in part.known) and "joint3" in part.description
    gone = full.restricted_to(("joint1", "joint2", "joint4"))
    assert gone.hidden is None and {e.joint for e in gone.effects} == {"joint1", "joint2", "joint4"}


def test_all_eight_servos_bilateral_with_the_gripper(tmp_path):
    # no held joint: the alignment sends no goal position (an empty sync write would be refused as a bus
    # error)
    result, out = _run(tmp_path, "all,gripper", 0, duration=1.0)
    assert result.end_reason == "duration" and tuple(result.tracking_rms) == SEVEN + ("gripper",)
    assert np.degrees(max(result.tracking_rms.values())) < 2.0
    with h5py.File(out) as f:
        assert np.isnan(f["follower/q_goal"][()]).all()
        assert [str(n) for n in f.attrs["bilateral_joints"]] == list(SEVEN) + ["gripper"]


def test_the_served_lab_integrates_and_moves_the_chosen_joints():
    from collect.sim_lab import SimulatedLab

    cfg = load_config().with_bilateral_joints("all")
    lab = SimulatedLab.build(seed=1, clock="lockstep", config=cfg, arm=run_arm(cfg))
    assert lab.plant_name == "crane-x7-7dof"
    for name in ("leader", "follower"):
        assert tuple(lab.plants[name].joints) == SEVEN  # through the hand's and the offsets' wrappers
    assert len(lab.hand.operator.idx) == 7


@pytest.mark.parametrize("fault, words", [
    ("vanish", "joint7"),  # the follower's wrist-twist servo drops off the bus
    ("overload", "joint6 (ID 7): overload"),  # a wrist servo's overload bit
])
def test_a_fault_on_a_wrist_joint_ends_in_a_safe_stop(tmp_path, fault, words):
    seen = {}

    def inject(k, ctx):
        seen["sims"] = ctx.sims
        if k == 250:
            if fault == "vanish":
                ctx.sims["follower"].chain.remove_servo(8)  # joint7
            else:
                ctx.sims["leader"].chain.servos[7].set_hardware_error(0x20)  # joint6

    with pytest.raises(SafetyStop) as info:
        run_session(RunOptions(output=tmp_path / "s.h5", sim=True, seed=1, duration=3.0, status=False,
                               joints="all", config=_fast_alignment(tmp_path), on_cycle=inject))
    assert words in str(info.value)
    with h5py.File(tmp_path / "s.h5") as f:
        assert f.attrs["complete"] and f.attrs["end_reason"] == "safety_stop"
        stops = [e for e in read_events(f) if e["kind"] == "safety_stop"]
        assert len(stops) == 1 and words in stops[0]["message"]
        assert 240 <= f["follower/t"].shape[0] <= 260  # stopped right away
    assert torque_off_everywhere(seen["sims"], min_servos=15)


# ---- the simulated operator ------------------------------------------------------------------------

def _operator_moving(joints: tuple[str, ...], seed: int, duration: float = 600.0, rate: float = 50.0):
    """The moving mask of the operator's reference over `duration` s: the paper's dead zone (|dq| above
    0.1 of the joint's velocity spread, train/data/masks.py) on the reference velocity."""
    cfg = load_config().with_bilateral_joints(list(joints))
    arm = replace(default_arm(), bilateral_joints=cfg.bilateral)
    op = SimulatedOperator(seed, arm, rate, cfg)
    op.start(np.array([cfg.operator.start.get(n, 0.0) for n in arm.joint_names]), 0.0)
    t = np.arange(0.0, duration, 1.0 / rate)
    dq = np.array([op.reference(x)[1] for x in t])
    return np.abs(dq) > 0.1 * dq.std(axis=0)


@pytest.mark.parametrize("joints", [SEVEN, PAPER_JOINTS])
def test_the_operator_moves_each_joint_about_seventy_percent_of_the_time(joints):
    moving = np.concatenate([_operator_moving(joints, seed) for seed in (0, 1)])
    per_joint = moving.mean(axis=0)
    assert np.all((per_joint > 0.6) & (per_joint < 0.8)), dict(zip(joints, per_joint))
    all_joints = moving.all(axis=1).mean()
    n = len(joints)
    # independent per-joint processes: all of them together move about the product of their fractions
    assert all_joints == pytest.approx(np.prod(per_joint), rel=0.25)
    assert 0.6 ** n < all_joints < 0.8 ** n  # near 0.7^n: 0.34 at three joints, 0.08 at seven


def test_the_operators_contact_task_presses_on_any_bilateral_joint():
    from crane_io.sim.plant_config import JointWallSpec

    cfg = load_config().with_operator_task("contact").with_bilateral_joints("all")
    arm = replace(default_arm(), bilateral_joints=cfg.bilateral)
    wall = JointWallSpec(joint="joint6", angle=0.4, side="above", stiffness=50.0, damping=0.5)
    op = SimulatedOperator(3, arm, 100.0, cfg, environment=[wall])
    op.start(np.array([cfg.operator.start.get(n, 0.0) for n in arm.joint_names]), 0.0)
    j6 = SEVEN.index("joint6")
    pressed, q_max_free = [], -np.inf
    for t in np.arange(0.0, 120.0, 0.01):
        q_ref, _ = op.reference(t)
        if op.pressing:
            pressed.append(q_ref[j6])
        elif op.phase == "free":
            q_max_free = max(q_max_free, q_ref[j6])
    assert pressed and min(pressed) > 0.4  # presses go past the wall on joint6
    assert q_max_free < 0.4  # free moves stay out of it
    held_cfg = load_config().with_operator_task("contact")  # joint6 held: the wall cannot be pressed
    with pytest.raises(ConfigError, match="joint6 sits on a joint this run holds"):
        SimulatedOperator(3, default_arm(), 100.0, held_cfg, environment=[wall])
