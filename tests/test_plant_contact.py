"""Contact in the simulated arm: [[environment]] joint walls and planes in the plant TOML,
their physics (crane_io.sim.environment) and the plant's contact API (crane_io.sim.arm_plant)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from crane_io.errors import ConfigError
from crane_io.sim.arm_plant import ArmPlant
from crane_io.sim.environment import Environment
from crane_io.sim.plant_api import ActuatorCommand
from crane_io.sim.plant_config import JointWallSpec, PlaneSpec, load_plant_config, presets

N = 8
BI = [0, 1, 3]  # joint1, joint2, joint4 in the servo order
START = np.radians([0.0, 15.0, 0.0, -90.0, 0.0, 0.0, 0.0, 0.0])  # the operator's start pose


def command(current) -> ActuatorCommand:
    """Current mode on every servo, goal current `current` (8,) A."""
    return ActuatorCommand(np.ones(N, bool), np.zeros(N, int), np.asarray(current, float), np.zeros(N),
                           np.tile([800, 0, 0], (N, 1)), np.full(N, 10.0))


def push(plant: ArmPlant, torque_bi, seconds: float) -> None:
    """Gravity-compensated motors plus a constant external torque (N m) on joint1, joint2, joint4."""
    ext = np.zeros(N)
    ext[BI] = torque_bi
    plant.set_external_torque(ext)
    for _ in range(int(round(seconds / 0.002))):
        cur = np.zeros(N)
        cur[BI] = plant.dyn.gravity_torque(plant.q) / plant.kt[BI]
        plant.step(command(cur), 0.002)


def plant_with(tmp_path, entries: str, name: str = "p.toml") -> ArmPlant:
    path = tmp_path / name
    path.write_text('base = "crane-x7"\n' + entries)
    plant = ArmPlant(load_plant_config(path))
    plant.set_state(q=START)
    return plant


WALL = """
[[environment]]
kind = "joint-wall"
joint = "joint2"
angle = 0.6
side = "above"
stiffness = 40.0
damping = 0.8
"""


# ---- joint walls --------------------------------------------------------------------------------------

def test_a_joint_wall_stops_the_joint_with_stiffness_times_penetration_plus_damping(tmp_path):
    plant = plant_with(tmp_path, WALL)
    push(plant, (0.0, 1.2, 0.0), 1.5)
    q, dq = plant.state()
    penetration = q[1] - 0.6
    assert 0.0 < penetration < 0.05  # stopped just inside the wall
    expected = -(40.0 * penetration + 0.8 * dq[1])
    assert plant.contact_torque()[1] == pytest.approx(expected, rel=1e-12, abs=1e-15)
    assert plant.contact_torque()[1] == pytest.approx(-1.2, abs=0.3)  # it holds the push (+ friction)
    assert plant.in_contact
    assert np.all(plant.contact_torque()[[0, 2, 3, 4, 5, 6, 7]] == 0.0)


def test_the_joint_is_free_on_the_other_side_of_a_wall(tmp_path):
    below = WALL.replace('side = "above"', 'side = "below"').replace("angle = 0.6", "angle = -0.5")
    plant = plant_with(tmp_path, below)
    free = ArmPlant("crane-x7", kernel=False)  # the reference path, as a plant with objects integrates
    free.set_state(q=START)
    for p in (plant, free):
        push(p, (0.3, 1.0, -0.4), 0.6)
    assert not plant.in_contact
    assert np.all(plant.contact_torque() == 0.0)
    # a wall never touched changes nothing, to the bit
    assert np.array_equal(plant.state()[0], free.state()[0])
    assert np.array_equal(plant.state()[1], free.state()[1])


def test_a_wall_pushes_but_never_pulls():
    env = Environment([JointWallSpec("joint4", -1.0, "below", stiffness=50.0, damping=0.5)])
    inside = [0.0, 0.0, -1.02]  # 0.02 rad below the wall
    assert env.contact_torque(inside, [0.0, 0.0, 0.0])[2] == pytest.approx(1.0)
    assert env.contact_torque(inside, [0.0, 0.0, -1.0])[2] == pytest.approx(1.5)  # moving in: + damping
    assert env.contact_torque(inside, [0.0, 0.0, 5.0])[2] == 0.0  # leaving fast: zero, not a pull
    assert env.contact_torque([0.0, 0.0, -0.9], [0.0, 0.0, -1.0])[2] == 0.0
    assert env.in_contact(inside) and not env.in_contact([0.0, 0.0, -0.99])


# ---- planes -------------------------------------------------------------------------------------------

def _pose_below(plane, depth: float) -> np.ndarray:
    """A pose whose tool is `depth` m inside `plane` (found from the plane's own surface pose)."""
    q_s, direction, _ = plane.surface(np.radians([10.0, 15.0, -90.0]))
    q = q_s.copy()
    for _ in range(50):  # walk into the plane along the direction until the depth is reached
        q = q + direction * 0.001
        if -plane.distance(q) >= depth:
            return q
    raise AssertionError("could not reach the depth")


def _numeric_jacobian(plane, q, h=1e-7) -> np.ndarray:
    cols = []
    for i in range(3):
        dq = np.zeros(3)
        dq[i] = h
        cols.append((plane.position(q + dq).copy() - plane.position(q - dq).copy()) / (2 * h))
    return np.array(cols).T


def test_a_plane_gives_j_transpose_f_of_its_spring_damper():
    spec = PlaneSpec(point=(0.0, 0.0, 0.25), normal=(0.0, 0.0, 1.0), stiffness=2000.0, damping=20.0,
                     friction=0.0)
    env = Environment([spec])
    plane = env.planes[0]
    q = _pose_below(plane, 0.01)
    depth = -plane.distance(q)
    jac = _numeric_jacobian(plane, q)
    dq = np.array([0.0, 0.2, -0.1])
    v_n = (jac @ dq)[2]
    force = np.array([0.0, 0.0, 2000.0 * depth - 20.0 * v_n])
    assert env.contact_torque(q, dq) == pytest.approx(jac.T @ force, rel=1e-6, abs=1e-9)
    assert env.in_contact(q)
    # leaving fast (damping x velocity out > spring): no pull
    _, direction, _ = plane.surface(q)
    leaving = -direction * 5.0
    assert (jac @ leaving)[2] * 20.0 > 2000.0 * depth
    assert np.all(env.contact_torque(q, leaving) == 0.0)


def test_plane_friction_opposes_sliding_and_is_bounded():
    mu = 0.4
    base = PlaneSpec(point=(0.0, 0.0, 0.25), normal=(0.0, 0.0, 1.0), friction=0.0, damping=0.0)
    rough = PlaneSpec(point=(0.0, 0.0, 0.25), normal=(0.0, 0.0, 1.0), friction=mu, damping=0.0)
    smooth_env, rough_env = Environment([base]), Environment([rough])
    plane = rough_env.planes[0]
    q = _pose_below(plane, 0.005)
    jac = pin.computeFrameJacobian(plane.model, plane.data, q, plane.frame, pin.LOCAL_WORLD_ALIGNED)[:3]
    dq = np.array([0.5, 0.0, 0.0])  # joint1 turns: the tool slides sideways over the plane
    v = jac @ dq
    assert abs(v[2]) < 1e-9 and np.linalg.norm(v[:2]) > 0.05
    friction_torque = rough_env.contact_torque(q, dq) - smooth_env.contact_torque(q, dq)
    assert friction_torque @ dq < 0  # it takes energy out: opposes the sliding
    f_t = plane.force(v, -plane.distance(q)) - Environment([base]).planes[0].force(v, -plane.distance(q))
    f_n = 2000.0 * -plane.distance(q)
    assert np.dot(f_t, v) < 0
    assert np.linalg.norm(f_t) <= mu * f_n * (1 + 1e-12)
    assert np.linalg.norm(f_t) == pytest.approx(mu * f_n, rel=1e-6)  # 0.05 m/s >> 0.01 m/s: saturated


def test_the_arm_pressed_down_rests_on_the_table_preset():
    plant = ArmPlant("contact-table")
    plant.set_state(q=START)
    push(plant, (0.0, 0.0, -1.5), 2.0)  # bend the elbow: the tool goes down onto the table
    plane = plant._env.planes[0]
    depth = -plane.distance(plant.q)
    assert plant.in_contact and 0.0 < depth < 0.01
    q, dq = plant.state()
    expected = Environment(plant.environment).contact_torque(q[BI], dq[BI])
    assert plant.contact_torque()[BI] == pytest.approx(expected, rel=1e-9, abs=1e-12)
    assert plant.contact_torque()[3] > 0.5  # the table pushes joint4 back up


# ---- configuration ------------------------------------------------------------------------------------

def test_the_contact_presets_load_and_start_free():
    assert {"contact-wall", "contact-table"} <= set(presets())
    wall = load_plant_config("contact-wall")
    assert [(s.kind, s.joint, s.side) for s in wall.environment] == [("joint-wall", "joint2", "above"),
                                                                    ("joint-wall", "joint1", "below")]
    table = load_plant_config("contact-table")
    assert [s.kind for s in table.environment] == ["plane"] and table.environment[0].frame == "tool"
    for name in ("contact-wall", "contact-table"):
        plant = ArmPlant(name)
        assert plant.environment == load_plant_config(name).environment
        assert "environment" in plant.truth()
        plant.set_state(q=START)
        push(plant, (0.0, 0.0, 0.0), 0.01)
        assert not plant.in_contact
    plane = Environment(table.environment).planes[0]
    assert plane.surface(START[BI]) is not None  # the table is in reach from the start pose
    assert load_plant_config("contact-wall").without_environment().environment == []


def test_a_plant_without_environment_reports_no_contact_and_the_hand():
    plant = ArmPlant("crane-x7")
    assert plant.environment == [] and "environment" not in plant.truth()
    hand = np.arange(N, dtype=float) * 0.1
    plant.set_external_torque(hand)
    push_cmd = command(np.zeros(N))
    plant.step(push_cmd, 0.002)
    assert np.array_equal(plant.external_torque(), hand)
    assert np.all(plant.contact_torque() == 0.0) and plant.in_contact is False


@pytest.mark.parametrize("entry, words", [
    ('kind = "box"', ["kind", "'box'"]),
    ('joint = "joint2"\nangle = 0.5\nside = "above"', ["kind"]),
    ('kind = "joint-wall"\njoint = "joint3"\nangle = 0.5\nside = "above"', ["joint", "'joint3'"]),
    ('kind = "joint-wall"\njoint = "joint2"\nangle = 0.5\nside = "left"', ["side", "'left'"]),
    ('kind = "joint-wall"\njoint = "joint2"\nside = "above"', ["angle"]),
    ('kind = "joint-wall"\njoint = "joint2"\nangle = 0.5\nside = "above"\nstiffness = -1.0', ["stiffness"]),
    ('kind = "joint-wall"\njoint = "joint2"\nangle = "x"\nside = "above"', ["angle"]),
    ('kind = "plane"\npoint = [0.0, 0.0]\nnormal = [0.0, 0.0, 1.0]', ["point"]),
    ('kind = "plane"\npoint = [0.0, 0.0, 0.2]\nnormal = [0.0, 0.0, 0.0]', ["normal"]),
    ('kind = "plane"\npoint = [0.0, 0.0, 0.2]', ["normal"]),
    ('kind = "plane"\npoint = [0.0, 0.0, 0.2]\nnormal = [0, 0, 1]\nfriction = -0.1', ["friction"]),
    ('kind = "plane"\npoint = [0.0, 0.0, 0.2]\nnormal = [0, 0, 1]\nframe = "nose"', ["frame", "'nose'"]),
    ('kind = "plane"\npoint = [0.0, 0.0, 0.2]\nnormal = [0, 0, 1]\ncolour = "red"', ["colour"]),
])
def test_a_bad_environment_entry_is_one_sentence_naming_file_and_key(tmp_path, entry, words):
    path = tmp_path / "bad.toml"
    path.write_text(f'base = "crane-x7"\n[[environment]]\n{entry}\n')
    with pytest.raises(ConfigError) as err:
        load_plant_config(path)
    msg = str(err.value)
    assert str(path) in msg and "[[environment]] entry 1" in msg
    for w in words:
        assert w in msg
    assert "\n" not in msg and msg.count(". ") == 0


def test_environment_must_be_a_list_of_tables(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('environment = 3\n')
    with pytest.raises(ConfigError, match="environment must be a list"):
        load_plant_config(path)
