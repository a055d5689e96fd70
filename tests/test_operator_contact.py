"""The simulated operator's contact task: free motion alternating with presses against the
follower plant's [[environment]] objects; config keys; determinism; the free task unchanged."""

from __future__ import annotations

import numpy as np
import pytest

from collect.config import load_config
from collect.operator import SimulatedOperator
from crane_io.errors import ConfigError
from crane_io.sim.arm_plant import ArmPlant
from crane_io.sim.plant_api import ActuatorCommand
from crane_io.sim.plant_config import load_plant_config

N = 8
BI = [0, 1, 3]
DT = 0.002


def contact_config(tmp_path, extra: str = ""):
    path = tmp_path / "op.toml"
    path.write_text('[operator]\ntask = "contact"\n' + extra)
    return load_config(path)


def command(current) -> ActuatorCommand:
    return ActuatorCommand(np.ones(N, bool), np.zeros(N, int), np.asarray(current, float), np.zeros(N),
                           np.tile([800, 0, 0], (N, 1)), np.full(N, 10.0))


def run(preset: str, config, seconds: float, seed: int = 1) -> dict:
    """One arm: gravity-compensated motors (like the bilateral controller), the operator's hand on it
    and the preset's objects in its world. Per cycle: pressing, contact torque (8,), hand torque (8,),
    the hand's reference (3,)."""
    plant = ArmPlant(preset)
    op = SimulatedOperator(seed=seed, config=config, environment=plant.environment)
    q0 = np.array([config.operator.start.get(n, 0.0) for n in plant.joint_names])
    plant.set_state(q=q0)
    op.start(q0, 0.0)
    out = {"pressing": [], "contact": [], "hand": [], "ref": [], "phase": []}
    for i in range(int(round(seconds / DT))):
        q, dq = plant.state()
        hand = op.torque(i * DT, q, dq)
        plant.set_external_torque(hand)
        cur = np.zeros(N)
        cur[BI] = plant.dyn.gravity_torque(plant.q) / plant.kt[BI]
        plant.step(command(cur), DT)
        out["pressing"].append(op.pressing)
        out["phase"].append(op.phase)
        out["contact"].append(plant.contact_torque())
        out["hand"].append(hand)
        out["ref"].append(op.reference(i * DT)[0])
    return {k: np.array(v) for k, v in out.items()}


# ---- configuration --------------------------------------------------------------------------------------

def test_the_task_keys_have_documented_defaults_and_are_checked(tmp_path):
    o = load_config().operator
    assert (o.task, o.press_fraction, o.press_torque_min, o.press_torque_max, o.press_min_s,
            o.press_max_s) == ("free", 0.3, 0.3, 1.5, 1.0, 4.0)
    assert load_config().with_operator_task("contact").operator.task == "contact"
    with pytest.raises(ConfigError, match="operator task"):
        load_config().with_operator_task("juggle")
    bad = (('task = "juggle"', "operator.task"), ("press_fraction = 1.0", "operator.press_fraction"),
           ("press_torque_min = 2.0", "operator.press_torque_min"),
           ("press_min_s = 5.0", "operator.press_min_s"), ("press_max_s = 0.0", "operator.press_max_s"))
    for extra, key in bad:
        path = tmp_path / "bad.toml"
        path.write_text(f"[operator]\n{extra}\n")
        with pytest.raises(ConfigError, match=key):
            load_config(path)


def test_the_contact_task_needs_objects():
    config = load_config().with_operator_task("contact")
    with pytest.raises(ConfigError, match="environment"):
        SimulatedOperator(config=config, environment=[])
    with pytest.raises(ConfigError, match="environment"):
        SimulatedOperator(config=config)


def test_the_free_task_ignores_the_environment_and_draws_the_same_numbers():
    env = load_plant_config("contact-wall").environment
    a = SimulatedOperator(seed=4)
    b = SimulatedOperator(seed=4, environment=env)
    q0 = np.radians([0.0, 15.0, 0.0, -90.0, 0.0, 0.0, 0.0, 0.0])
    a.start(q0)
    b.start(q0)
    for t in np.arange(0.0, 20.0, 0.01):
        ra, rb = a.reference(t), b.reference(t)
        assert np.array_equal(ra[0], rb[0]) and np.array_equal(ra[1], rb[1])
    assert not b.pressing


# ---- the task on the plant --------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def wall_run(tmp_path_factory):
    # short moves leave room for press_fraction with short presses (approach and withdrawal are free time)
    config = contact_config(tmp_path_factory.mktemp("op"), "press_min_s = 1.0\npress_max_s = 2.5\n"
                            "min_move_s = 0.4\nmax_move_s = 1.0\n")
    return config, run("contact-wall", config, 40.0)


def test_presses_against_the_walls_for_about_press_fraction_of_the_time(wall_run):
    _config, r = wall_run
    pressing = r["pressing"]
    touching = np.any(r["contact"] != 0.0, axis=1)
    assert 0.18 < pressing.mean() < 0.42  # press_fraction 0.3, over a few episodes
    assert 0.18 < touching.mean() < 0.45
    assert touching[pressing].mean() > 0.8  # pressing means touching
    assert touching[~pressing].mean() < 0.15  # free motion stays out (the approach may touch first)
    starts = np.flatnonzero(np.diff(pressing.astype(int)) == 1)
    assert len(starts) >= 4  # several episodes
    # the walls push out: joint2's (above 45 deg) negative, joint1's (below -60 deg) positive
    assert np.all(r["contact"][:, 1] <= 0.0) and np.all(r["contact"][:, 0] >= 0.0)
    assert (r["contact"][:, 1] < 0).any() and (r["contact"][:, 0] > 0).any()


def test_the_hand_presses_with_varied_torques_in_the_configured_range(wall_run):
    config, r = wall_run
    pressing = r["pressing"]
    ends = np.flatnonzero(np.diff(pressing.astype(int)) == -1)
    held = [np.linalg.norm(r["hand"][e - 5, BI]) for e in ends]  # the hand near the end of each hold
    assert len(held) >= 4
    assert np.ptp(held) > 0.2  # varied
    o = config.operator
    assert min(held) > 0.5 * o.press_torque_min and max(held) < 1.5 * o.press_torque_max
    contact = [np.linalg.norm(r["contact"][e - 5]) for e in ends]  # the wall holds the hand's push
    assert np.corrcoef(held, contact)[0, 1] > 0.9


def test_free_references_stay_clear_of_the_walls(wall_run):
    _config, r = wall_run
    free = r["phase"] == "free"
    assert set(r["phase"]) == {"free", "approach", "ramp", "hold", "withdraw"}
    assert np.array_equal(r["pressing"], np.isin(r["phase"], ["ramp", "hold"]))
    assert np.all(r["ref"][free, 1] <= np.radians(45.0) + 1e-9)
    assert np.all(r["ref"][free, 0] >= np.radians(-60.0) - 1e-9)


def test_the_table_task_presses_the_tool_onto_the_plane(tmp_path):
    config = contact_config(tmp_path, "press_min_s = 0.8\npress_max_s = 1.6\npress_fraction = 0.4\n")
    r = run("contact-table", config, 20.0, seed=2)
    pressing = r["pressing"]
    touching = np.any(r["contact"] != 0.0, axis=1)
    assert pressing.any() and touching[pressing].mean() > 0.7
    assert touching[~pressing].mean() < 0.15
    # the table pushes up: the hand bends the elbow (joint4 negative) to press, the table pushes it back
    assert np.median(r["contact"][pressing & touching, 3]) > 0.0


def test_the_contact_task_is_deterministic(tmp_path):
    config = contact_config(tmp_path, "press_min_s = 0.5\npress_max_s = 0.8\n")
    a, b = run("contact-wall", config, 4.0, seed=5), run("contact-wall", config, 4.0, seed=5)
    assert np.array_equal(a["hand"], b["hand"]) and np.array_equal(a["pressing"], b["pressing"])
