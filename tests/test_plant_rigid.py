"""The simulated arm's one rigid-body implementation (crane_io/sim/plant_rigid.py) against pinocchio, the
oracle: the mass matrix, the bias torque and the forward dynamics equal pinocchio's `crba`,
`nonLinearEffects` and `aba` to 1e-12 at random states, for 3 and 7 joints, with a payload and rotor
inertia (armature), compiled (as both steppers run it) and as its Python source; the compiled function
gives its source's bits."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from crane_io.physics.dynamics import ArmDynamics
from crane_io.sim import plant_kernel, plant_layout, plant_rigid
from crane_io.sim.arm_plant import ArmPlant
from crane_io.sim.plant_config import ARM_JOINTS

ARMATURE = 'base = "{base}"\n[[effects]]\neffect = "rotor-inertia"\njoint = "{joint}"\ninertia = 0.02\n'
# (base preset, a joint given rotor inertia): payload presets and other joints locked elsewhere
CASES = {"3 joints, payload, armature": ("hidden-payload", "joint2"),
         "7 joints, payload, armature": ("crane-x7-7dof", "joint6")}


@pytest.fixture(scope="module", params=list(CASES))
def plant(request, tmp_path_factory):
    base, joint = CASES[request.param]
    path = tmp_path_factory.mktemp("rigid") / "plant.toml"
    text = ARMATURE.format(base=base, joint=joint)
    if base == "crane-x7-7dof":
        text += '[[effects]]\neffect = "payload"\nmass = 0.3\n'
    path.write_text(text)
    p = ArmPlant(path, kernel=False)
    assert p.terms.payload > 0 and max(p.model.armature) >= 0.02  # the case is what it says
    return p


def _functions():
    fns = plant_kernel.compiled()
    compiled = [] if fns is None else [fns[2]]
    return [plant_rigid.mass_and_bias, *compiled]


def _states(n: int, count: int):
    rng = np.random.default_rng(5)
    for _ in range(count):
        yield rng.uniform(-3, 3, n), rng.uniform(-4, 4, n), rng.uniform(-5, 5, n)


@pytest.mark.parametrize("compiled", [False, True], ids=["python source", "compiled"])
def test_mass_matrix_bias_and_forward_dynamics_equal_pinocchios(plant, compiled):
    fns = _functions()
    if compiled and len(fns) < 2:
        pytest.skip("numba is not installed")
    mass_and_bias = fns[-1] if compiled else fns[0]
    model, data = plant.model, plant.model.createData()
    n = model.nv
    idx = np.arange(n)
    for q, dq, tau in _states(n, 40 if compiled else 8):
        out = mass_and_bias(plant.geo, model.armature, plant.scal, q, dq)
        mass, bias = out[:n], out[n]
        m = pin.crba(model, data, q)
        m = np.triu(m) + np.triu(m, 1).T
        np.testing.assert_allclose(mass, m, rtol=0, atol=1e-12 * np.abs(m).max())
        assert np.array_equal(mass, mass.T)
        b = pin.nonLinearEffects(model, data, q, dq)
        np.testing.assert_allclose(bias, b, rtol=0, atol=1e-12 * np.abs(b).max())
        ddq = np.empty(n)
        plant_rigid.solve(mass, idx, n, tau - bias, ddq, np.empty((n, n)))
        want = pin.aba(model, data, q, dq, tau)
        np.testing.assert_allclose(ddq, want, rtol=0, atol=1e-12 * np.abs(want).max())


def test_the_armature_and_gravity_are_the_models(plant):
    """M grows by the armature on its diagonal only; no gravity leaves C(q, dq) dq alone (zero at rest)."""
    model = plant.model
    n = model.nv
    q = np.linspace(-0.5, 0.7, n)
    with_arm = plant_rigid.mass_and_bias(plant.geo, model.armature, plant.scal, q, np.zeros(n))
    without = plant_rigid.mass_and_bias(plant.geo, np.zeros(n), plant.scal, q, np.zeros(n))
    np.testing.assert_allclose(with_arm[:n] - without[:n], np.diag(model.armature), rtol=0, atol=1e-15)
    weightless = plant.scal.copy()
    weightless[2:5] = 0.0
    at_rest = plant_rigid.mass_and_bias(plant.geo, model.armature, weightless, q, np.zeros(n))
    assert np.abs(at_rest[n]).max() == 0.0 and np.abs(with_arm[n]).max() > 0.1


def test_the_compiled_function_gives_its_sources_bits(plant):
    fns = _functions()
    if len(fns) < 2:
        pytest.skip("numba is not installed")
    source, compiled = fns
    n = plant.model.nv
    for q, dq, _tau in _states(n, 20):
        args = (plant.geo, plant.model.armature, plant.scal, q, dq)
        assert compiled(*args).tobytes() == source(*args).tobytes()


def test_every_arm_the_simulator_builds_is_a_revolute_chain():
    """The one rigid body covers every plant: ArmPlant's model is ArmDynamics' for its joints (any non-empty
    set of joint1..joint7, in arm order, the others locked), and every such model is a revolute chain."""
    for mask in range(1, 1 << len(ARM_JOINTS)):
        joints = [j for i, j in enumerate(ARM_JOINTS) if mask >> i & 1]
        locked = {j: 0.4 for j in ARM_JOINTS if j not in joints}
        assert plant_layout.revolute_chain(ArmDynamics(joints, locked=locked).model), joints
