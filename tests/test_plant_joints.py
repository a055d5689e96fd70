"""The simulated arm integrates any set of joints: ArmPlant(joints=...) and the plant
configuration's `joints` key. With the default three joints the reference path's (`kernel=False`)
trajectories are pinned below (presets, backlash, user-defined effects, [[environment]] objects); where the
compiled kernel applies (the default) it gives the same bits (tests/test_plant_kernel.py)."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from crane_io.errors import ConfigError
from crane_io.physics.dynamics import ArmDynamics
from crane_io.physics.effects import load_effect_file
from crane_io.sim.arm_plant import ArmPlant
from crane_io.sim.plant_api import ActuatorCommand
from crane_io.sim.plant_config import ARM_JOINTS, BILATERAL_JOINTS, load_plant_config, presets

PERIOD = 0.002
GAINS = np.tile([800.0, 0.0, 0.0], (8, 1))
LIMIT = np.full(8, 3.0)
NO_NOISE = "[sensor]\nposition_noise_probability = 0.0\ncurrent_noise_lsb = 0.0\nvelocity_noise_lsb = 0.0\n"


def command(current=None, mode=None, position=None, enabled=None) -> ActuatorCommand:
    return ActuatorCommand(np.ones(8, bool) if enabled is None else enabled,
                           np.zeros(8, int) if mode is None else mode,
                           np.zeros(8) if current is None else current,
                           np.zeros(8) if position is None else position, GAINS, LIMIT)


def holding_current(plant: ArmPlant) -> np.ndarray:
    """Goal currents that cancel gravity on the integrated joints at the plant's present pose."""
    cur = np.zeros(8)
    idx = [plant.joint_names.index(n) for n in plant.joints]
    cur[idx] = plant.dyn.gravity_torque(plant.q) / plant.kt[idx]
    return cur


def write(tmp_path, name: str, text: str):
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return path


# ---- the default three joints: the same bits as before ------------------------------------------------

_USER_EFFECTS = '''
import numpy as np
from crane_io.physics.effects import Effect, Param
from crane_io.physics.effects.base import joint_columns

class QuadDrag(Effect):
    name = "joints-test-quad-drag"
    params = (Param("drag", "N m s^2/rad^2", 0.05, "quadratic drag"),)
    def _columns(self, q, dq, ddq, joint, shape):
        return joint_columns(len(q), q.shape[1], joint, dq[:, joint] * np.abs(dq[:, joint]))

class SoftFriction(Effect):
    name = "joints-test-soft-friction"
    params = (Param("level", "N m", 0.05, "friction"),)
    friction = True
    def _columns(self, q, dq, ddq, joint, shape):
        return joint_columns(len(q), q.shape[1], joint, np.tanh(dq[:, joint] / 0.02))
    def static_band(self, values):
        v = self.check_values(values)
        return (abs(v["level"]), abs(v["level"]))
'''

# (preset or extra TOML, sha256[:16] of every step's state, motor torque and reading) on x86_64 Linux; the
# first three are tests/test_plant_kernel.py's _KERNEL_REFERENCE: the two steppers compute the same bits
_REFERENCE = {
    "crane-x7": "23195b13a6e4133e",
    "baseline": "df694052eb0cb756",
    "hidden-cogging": "cbb1ef498f63615f",
    "contact-wall": "42a2e5ca9117d40e",
    "backlash+torque-constant-error": "950707d7f2817b12",
    "user friction effect+joint wall": "ff763403a5103d1a",
    "user effect+payload+asymmetric Coulomb+spring": "4ada303b220b6158",
}


def _reference_config(tmp_path, key: str):
    effects = tmp_path / "user_effects.py"
    effects.write_text(_USER_EFFECTS)
    load_effect_file(effects)  # a plant file never runs code: the user's effects are defined in code
    extra = {
        "backlash+torque-constant-error":
            'base = "baseline"\n[[effects]]\neffect = "torque-constant-error"\njoint = "joint4"\n'
            'scale_error = 0.1\n[hidden]\neffect = "backlash"\njoint = "joint2"\nwidth = 0.0044\n'
            'motor_inertia = 0.01\n',
        "user friction effect+joint wall":
            'base = "crane-x7"\n[hidden]\n'
            'effect = "joints-test-soft-friction"\njoint = "joint4"\nlevel = 0.04\n[[environment]]\n'
            'kind = "joint-wall"\njoint = "joint4"\nangle = -0.2\nside = "above"\n',
        "user effect+payload+asymmetric Coulomb+spring":
            'base = "hidden-spring"\n[[effects]]\n'
            'effect = "joints-test-quad-drag"\njoint = "joint1"\ndrag = 0.05\n[[effects]]\n'
            'effect = "payload"\nmass = 0.2\n[[effects]]\neffect = "coulomb-asym"\njoint = "joint2"\n'
            'coulomb_pos = 0.2\ncoulomb_neg = 0.1\n',
    }
    return load_plant_config(write(tmp_path, "ref", extra[key]) if key in extra else key)


def _trajectory_hash(plant: ArmPlant, steps: int = 200) -> str:
    """Current mode on joints 1, 2, 4 with an external torque, the others in position mode, then every
    servo in position mode; hashes state, motor torque and the noisy reading of every step."""
    h = hashlib.sha256()
    rng = np.random.default_rng(42)
    for k in range(steps):
        mode = np.array([0, 0, 3, 0, 3, 3, 3, 3]) if k < 150 else np.full(8, 3)
        current = np.zeros(8)
        current[[0, 1, 3]] = [0.2 * np.sin(0.05 * k), 0.8 + 0.3 * np.sin(0.03 * k),
                              -0.1 + 0.2 * np.cos(0.07 * k)]
        position = 0.2 * np.sin(0.02 * k + np.arange(8))
        ext = np.zeros(8)
        ext[[0, 1, 3]] = rng.normal(0, 0.2, 3)
        plant.set_external_torque(ext)
        plant.step(ActuatorCommand(np.ones(8, bool), mode, current, position, GAINS, np.full(8, 2.0)), PERIOD)
        r = plant.read()
        q, dq = plant.state()
        for a in (q, dq, plant.motor_torque, r.position, r.velocity, r.current):
            h.update(np.ascontiguousarray(a, dtype=float).tobytes())
    return h.hexdigest()[:16]


@pytest.mark.parametrize("key", list(_REFERENCE))
def test_the_default_three_joints_give_the_trajectory_of_the_three_joint_plant(tmp_path, monkeypatch, key):
    import crane_io.physics.effects as effects

    monkeypatch.setattr(effects, "_REGISTRY", dict(effects._REGISTRY))  # the test's effects go away after it
    config = _reference_config(tmp_path, key)
    assert config.joints == BILATERAL_JOINTS
    assert _trajectory_hash(ArmPlant(config, seed=3, kernel=False)) == _REFERENCE[key]


def test_the_joint_set_is_put_in_arm_order_and_given_joints_override_the_config():
    default = _trajectory_hash(ArmPlant("crane-x7", seed=3), steps=60)
    shuffled = ArmPlant("crane-x7", seed=3, joints=["joint4", "joint1", "joint2"])
    assert shuffled.joints == BILATERAL_JOINTS
    assert _trajectory_hash(shuffled, steps=60) == default
    seven = ArmPlant("crane-x7", seed=3, joints=ARM_JOINTS)  # a 3-joint preset integrated on all seven
    assert seven.joints == ARM_JOINTS and seven.q.shape == (7,)
    assert seven.truth()["joints"] == list(ARM_JOINTS)


# ---- seven joints -------------------------------------------------------------------------------------

def test_a_seven_joint_plant_falls_under_gravity_as_the_forward_dynamics_say(tmp_path):
    path = write(tmp_path, "bare7", f'joints = {list(ARM_JOINTS)!r}\n'.replace("'", '"') + NO_NOISE)
    plant = ArmPlant(path)
    q0 = np.array([0.3, 0.5, -0.4, -0.8, 0.6, 0.7, -0.2, 0.0])
    plant.set_state(q0, np.zeros(8))
    h = plant.config.substep_s
    plant.step(command(enabled=np.zeros(8, bool)), h)  # torque off: gravity only, one substep
    want = ArmDynamics(ARM_JOINTS).forward_dynamics(q0[:7], np.zeros(7), np.zeros(7))
    q, dq = plant.state()
    assert np.abs(want).max() > 1.0  # it really falls
    np.testing.assert_allclose(dq[:7] / h, want, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(q[:7], q0[:7] + h * dq[:7], rtol=0, atol=1e-15)
    assert q[7] == q0[7]  # the gripper (held, torque off) stays where it is


def test_the_held_servos_still_follow_their_goals():
    plant = ArmPlant("crane-x7", joints=("joint1", "joint2", "joint4", "joint6"))
    goal = np.array([0.0, 0.0, 0.4, -0.3, -0.5, 0.0, 0.6, 0.3])
    mode = np.array([0, 0, 3, 0, 3, 0, 3, 3])
    for _ in range(400):
        plant.step(command(holding_current(plant), mode, goal), PERIOD)
    q = plant.state()[0]
    np.testing.assert_allclose(q[[2, 4, 6, 7]], goal[[2, 4, 6, 7]], atol=1e-3)  # joint3, 5, 7, gripper
    seven = ArmPlant("crane-x7-7dof")
    for _ in range(300):
        seven.step(command(holding_current(seven), np.array([0] * 7 + [3]), goal), PERIOD)
    assert abs(seven.state()[0][7] - goal[7]) < 1e-3  # the gripper is the only held servo


def test_the_integrated_wrist_servos_follow_position_goals_with_their_pd():
    plant = ArmPlant("crane-x7-7dof")
    goal = np.array([0.2, 0.3, -0.3, -0.6, 0.4, 0.5, -0.4, 0.0])
    for _ in range(1500):
        plant.step(command(mode=np.full(8, 3), position=goal), PERIOD)
    q, dq = plant.state()
    assert np.abs(q[:7] - goal[:7]).max() < 0.1 and np.abs(dq).max() < 0.05


def test_coulomb_friction_on_joint6_holds_it_below_breakaway_and_lets_go_above():
    plant = ArmPlant("baseline-7dof")  # joint6: stiction, Coulomb 0.12, breakaway 0.17 N m
    ext = np.zeros(8)
    ext[5] = 0.15  # below breakaway (the wrist upright: no gravity on joint6)
    plant.set_external_torque(ext)
    q6 = plant.q[5]
    for _ in range(300):
        plant.step(command(holding_current(plant)), PERIOD)
    assert plant.q[5] == q6 and plant.dq[5] == 0.0  # exactly at rest
    ext[5] = 0.25
    plant.set_external_torque(ext)
    for _ in range(100):
        plant.step(command(holding_current(plant)), PERIOD)
    assert plant.q[5] > q6 + 0.01


def test_a_spring_on_joint5_pulls_it_to_its_rest_angle(tmp_path):
    effects = (("spring", "stiffness = 0.5\nrest_angle = 0.5"), ("viscous", "viscous = 0.05"),
               ("rotor-inertia", "inertia = 0.0055"))
    path = write(tmp_path, "spring5", 'base = "crane-x7"\njoints = ["joint1", "joint2", "joint3", "joint4", '
                 '"joint5", "joint6", "joint7"]\n'
                 + "".join(f'[[effects]]\neffect = "{e}"\njoint = "joint5"\n{v}\n' for e, v in effects))
    plant = ArmPlant(path)
    assert plant.q[4] == 0.0
    for _ in range(1500):
        plant.step(command(holding_current(plant)), PERIOD)
    assert abs(plant.q[4] - 0.5) < 0.02 and abs(plant.dq[4]) < 0.05


def test_a_joint_wall_on_joint6_stops_joint6(tmp_path):
    path = write(tmp_path, "wall6", 'base = "baseline-7dof"\n[[environment]]\nkind = "joint-wall"\n'
                 'joint = "joint6"\nangle = 0.3\nside = "above"\nstiffness = 50.0\n')
    plant = ArmPlant(path)
    ext = np.zeros(8)
    ext[5] = 0.8  # 0.63 N m beyond the breakaway
    plant.set_external_torque(ext)
    for _ in range(1000):
        plant.step(command(holding_current(plant)), PERIOD)
    assert 0.3 < plant.q[5] < 0.3 + 0.8 / 50.0 + 1e-3  # pressed in, no further than the wall allows
    assert plant.in_contact and plant.contact_torque()[5] < -0.5
    free = ArmPlant("baseline-7dof")
    free.set_external_torque(ext)
    for _ in range(300):
        free.step(command(holding_current(free)), PERIOD)
    assert free.q[5] > 0.5  # without the wall it goes on


def test_a_single_integrated_joint(tmp_path):
    plant = ArmPlant(write(tmp_path, "one", 'joints = ["joint2"]\n'))
    plant.set_state(np.array([0.0, 0.3, 0, -0.3, 0, 0, 0, 0]))
    for _ in range(100):
        plant.step(command(enabled=np.array([1, 0, 1, 1, 1, 1, 1, 1], bool), mode=np.full(8, 3)), PERIOD)
    q = plant.state()[0]
    assert q[1] > 0.4  # joint2 falls forward with its torque off
    assert q[3] == pytest.approx(0.0, abs=0.05)  # joint4 is a held servo going to its goal (0)


# ---- refusals -----------------------------------------------------------------------------------------

def test_an_effect_on_a_joint_the_plant_does_not_integrate_is_refused(tmp_path):
    with pytest.raises(ConfigError, match=r"joint3.*integrate joint3") as err:
        ArmPlant("crane-x7-7dof", joints=BILATERAL_JOINTS)
    assert "\n" not in str(err.value)
    bad = write(tmp_path, "bad", '[[effects]]\neffect = "coulomb"\njoint = "joint6"\n')
    with pytest.raises(ConfigError, match=r"needs joint.*add joint6 to the plant's joints"):
        load_plant_config(bad)
    bad = write(tmp_path, "bad2", 'joints = ["joint1", "joint5"]\n[[effects]]\n'
                'effect = "torque-constant-error"\njoint = "joint5"\n')
    with pytest.raises(ConfigError, match=r"joint5, which this plant holds as a servo.*integrate joint5"):
        ArmPlant(load_plant_config(bad), joints=["joint1"])


def test_a_joint_wall_on_a_joint_the_plant_does_not_integrate_is_refused(tmp_path):
    wall = '[[environment]]\nkind = "joint-wall"\njoint = "joint6"\nangle = 0.3\nside = "above"\n'
    with pytest.raises(ConfigError, match="joint6"):
        load_plant_config(write(tmp_path, "w3", wall))
    all_seven = f"joints = {list(ARM_JOINTS)!r}\n".replace("'", '"')
    config = load_plant_config(write(tmp_path, "w7", all_seven + wall))
    with pytest.raises(ConfigError, match=r"joint wall on joint6.*integrate joint6"):
        ArmPlant(config, joints=("joint1", "joint2", "joint3", "joint4", "joint5", "joint7"))


@pytest.mark.parametrize("joints, words", [
    (["gripper"], "'gripper'"), ([], "at least one"), (["joint1", "joint1"], "each once"),
    ("joint1", "list of joint names"), (["joint9"], "'joint9'"),
])
def test_a_bad_joint_set_is_refused(tmp_path, joints, words):
    with pytest.raises(ConfigError, match=words):
        ArmPlant("baseline", joints=joints)
    text = f"joints = {joints!r}\n".replace("'", '"')
    with pytest.raises(ConfigError, match=words):
        load_plant_config(write(tmp_path, "j", text))


# ---- presets ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name, hidden", [("crane-x7-7dof", None), ("baseline-7dof", None),
                                          ("hidden-wrist-coulomb", ("coulomb", "joint6")),
                                          ("hidden-wrist-spring", ("spring", "joint5"))])
def test_the_seven_joint_presets_load_and_run(name, hidden):
    assert name in presets()
    config = load_plant_config(name)
    assert config.joints == ARM_JOINTS and config.locked == {}
    known = {(e, j) for e, j, _ in config.known}
    assert {j for _, j in known} == set(ARM_JOINTS)
    if hidden is None:
        assert config.hidden is None
    else:
        assert (config.hidden.effect, config.hidden.joint) == hidden and hidden not in known
    plant = ArmPlant(config, seed=1)
    for _ in range(100):
        plant.step(command(holding_current(plant)), PERIOD)
    q, dq = plant.state()
    assert np.isfinite(q).all() and np.abs(dq).max() < 1.0


def test_the_wrist_presets_keep_the_baseline_friction_bands():
    """hidden-wrist-coulomb sticks joint6 at the baseline's breakaway: the hidden Coulomb part plus the
    remaining breakaway excess (as hidden-coulomb does for joint2)."""
    base, hidden = ArmPlant("baseline-7dof"), ArmPlant("hidden-wrist-coulomb")
    assert hidden.terms.band_pos[5] == pytest.approx(base.terms.band_pos[5])
    assert hidden.terms.coulomb_pos[5] == pytest.approx(base.terms.coulomb_pos[5])


def test_a_plane_pushes_every_integrated_joint_through_the_jacobian_of_the_seven_joint_model(tmp_path):
    """At rest, a plane's joint torque is minus the gradient of its spring energy k d^2 / 2 over all seven
    joints (forward kinematics and Jacobian of the integrated-joint model)."""
    q = np.array([0.3, 1.2, 0.4, -1.5, 0.6, 0.9, -0.5])
    probe = ArmPlant(write(tmp_path, "probe", f'base = "contact-table"\njoints = {list(ARM_JOINTS)!r}\n'
                           .replace("'", '"')))
    plane = probe._env.planes[0]
    height = float(plane.position(q)[2])
    path = write(tmp_path, "table7", f'joints = {list(ARM_JOINTS)!r}\n'.replace("'", '"')
                 + f'[[environment]]\nkind = "plane"\npoint = [0.0, 0.0, {height + 0.01}]\n'
                   'normal = [0.0, 0.0, 1.0]\nstiffness = 2000.0\n')
    plant = ArmPlant(path)
    env = plant._env
    torque = env.contact_torque(q, np.zeros(7))
    assert env.in_contact(q) and torque.shape == (7,)

    def energy(x):
        depth = -env.planes[0].distance(x)
        return 0.5 * 2000.0 * max(depth, 0.0) ** 2

    eps = 1e-6
    grad = np.array([(energy(q + eps * e) - energy(q - eps * e)) / (2 * eps) for e in np.eye(7)])
    np.testing.assert_allclose(torque, -grad, rtol=1e-5, atol=1e-7)
    assert np.count_nonzero(np.abs(torque) > 1e-3) >= 5  # the wrist joints feel it too
    full = q.tolist() + [0.0]
    plant.set_state(full, np.zeros(8))
    plant.step(command(enabled=np.zeros(8, bool)), plant.config.substep_s)
    assert plant.in_contact and plant.contact_torque()[:7] @ torque > 0


# ---- one implementation of each effect ---------------------------------------------------------------

@pytest.mark.parametrize("effect, values", [
    ("coulomb", {"coulomb": 0.2}), ("coulomb-asym", {"coulomb_pos": 0.2, "coulomb_neg": 0.1}),
    ("viscous", {"viscous": 0.04}), ("stribeck", {"stribeck": 0.1, "stribeck_velocity": 0.05}),
    ("stiction", {"coulomb": 0.12, "breakaway": 0.2, "stiction_velocity": 0.02}),
    ("offset", {"offset": -0.07}), ("spring", {"stiffness": 0.4, "rest_angle": 0.5}),
    ("cogging", {"amplitude": 0.08, "phase": 0.5, "cycles_per_rev": 12.0}),
    ("stribeck", {"stribeck": -0.05, "stribeck_velocity": 0.05}),  # a dip, not a bump
    ("stiction", {"coulomb": 0.2, "breakaway": 0.12, "stiction_velocity": 0.02}),
])
def test_the_plant_terms_of_an_effect_are_its_torque_on_any_joint(tmp_path, effect, values):
    """Each built-in's closed form in the plant (Effect.plant_terms) is the effect's own torque(), on a
    wrist joint of a 7-joint plant (moving joints: kinetic friction plus the other terms)."""
    from crane_io.physics.effects import get_effect

    body = "".join(f"{k} = {v}\n" for k, v in values.items())
    path = write(tmp_path, "one", f'joints = {list(ARM_JOINTS)!r}\n'.replace("'", '"')
                 + f'[[effects]]\neffect = "{effect}"\njoint = "joint6"\n{body}')
    plant = ArmPlant(path, kernel=False)
    rng = np.random.default_rng(0)
    q = rng.uniform(-1.0, 1.0, (50, 7))
    q[:, 3] = rng.uniform(-2.0, -0.1, 50)  # inside joint4's limits (no end stop)
    dq = rng.normal(0.0, 0.1, (50, 7))
    want = get_effect(effect).torque(q, dq, np.zeros_like(q), 5, values)
    for qi, dqi, w in zip(q, dq, want):
        got = np.array(plant._stepper.other_torques(qi.tolist(), dqi.tolist()))
        got += plant._stepper.kinetic_torques(dqi.tolist())
        np.testing.assert_allclose(got, w, rtol=1e-12, atol=1e-14)


def test_an_effect_without_a_closed_form_is_evaluated_from_its_torque(monkeypatch):
    """A subclass of a built-in that changes the torque is not compiled with the built-in's closed form."""
    import crane_io.physics.effects as effects
    from crane_io.physics.effects import PlantTerms
    from crane_io.physics.effects.base import joint_columns
    from crane_io.physics.effects.library import Viscous

    class Quadratic(Viscous):
        name = "joints-test-quadratic-viscous"

        def _columns(self, q, dq, ddq, joint, shape):
            return joint_columns(len(q), q.shape[1], joint, dq[:, joint] * np.abs(dq[:, joint]))

    class Renamed(Viscous):
        name = "joints-test-renamed-viscous"

    monkeypatch.setattr(effects, "_REGISTRY", dict(effects._REGISTRY))
    terms = PlantTerms(ARM_JOINTS, {})
    Quadratic().add_to_plant(terms, 4, {"viscous": 0.1})
    Renamed().add_to_plant(terms, 5, {"viscous": 0.2})
    assert terms.viscous == [0.0, 0.0, 0.0, 0.0, 0.0, 0.2, 0.0]
    assert [(type(e), k) for e, k, _ in terms.generic] == [(Quadratic, 4)]
