"""An effect's torque written once (Effect.formula): its regressor columns, the control loop's per-sample
torque and the plant's handling of a changed formula all follow that one definition."""

from __future__ import annotations

import numpy as np
import pytest

from crane_io.physics.dynamics import ArmDynamics
from crane_io.physics.effects import PlantTerms
from crane_io.physics.effects.base import SCALAR_OPS, smooth_sign_ops
from crane_io.physics.effects.library import BUILTIN_EFFECTS, Coulomb, Viscous
from crane_io.physics.loop_model import RigidPath

FORMULA_EFFECTS = [cls for cls in BUILTIN_EFFECTS if cls.formula is not None]


def _samples(n=300, seed=0):
    rng = np.random.default_rng(seed)
    q, dq, ddq = rng.uniform(-2, 2, (n, 3)), rng.normal(0, 0.1, (n, 3)), rng.normal(0, 1, (n, 3))
    dq[::5] = 0.0  # at rest: sign(0) = 0
    return q, dq, ddq


def test_every_closed_form_builtin_defines_its_torque_in_its_formula():
    names = {cls.name for cls in FORMULA_EFFECTS}
    assert names == {"coulomb", "coulomb-asym", "viscous", "stribeck", "stiction", "offset", "spring",
                     "rotor-inertia", "cogging", "backlash"}
    assert all(cls().has_scalar_form for cls in FORMULA_EFFECTS)


@pytest.mark.parametrize("cls", FORMULA_EFFECTS, ids=lambda c: c.name)
def test_the_columns_are_the_formula_on_arrays_and_the_formula_on_floats_gives_the_same_torque(cls):
    effect = cls()
    q, dq, ddq = _samples()
    rng = np.random.default_rng(1)
    for shape in effect.shape_options()[:3]:
        coefs = rng.normal(0, 1, effect.n_columns())
        cols = effect.columns(q, dq, ddq, 1, shape)
        assert not cols[:, [0, 2]].any()  # one joint's effect
        want = cols[:, 1] @ coefs
        got = [effect.formula(a, b, c, coefs.tolist(), effect._shape(shape), SCALAR_OPS)
               for a, b, c in zip(q[:, 1].tolist(), dq[:, 1].tolist(), ddq[:, 1].tolist())]
        np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-15)


def test_a_changed_formula_changes_the_columns_the_loop_and_the_plant_together():
    class Cubic(Viscous):
        name = "formula-test-cubic-drag"

        def formula(self, q, dq, ddq, c, shape, ops):
            return c[0] * dq * dq * dq

    effect = Cubic()
    q, dq, ddq = _samples(50)
    np.testing.assert_allclose(effect.columns(q, dq, ddq, 2, None)[:, 2, 0], dq[:, 2] ** 3, rtol=1e-14)
    dyn = ArmDynamics()
    path = RigidPath(dyn.joint_names, np.zeros(10 * dyn.nbodies), [(effect, 2, None, [0.4])], dynamics=dyn)
    assert path.scalar_terms and not path.generic_terms  # the loop evaluates the formula itself
    for a, b, c in zip(q, dq, ddq):
        out = path(a, b, c, np.zeros(3))
        assert out[2] == pytest.approx(0.4 * b[2] ** 3, rel=1e-12, abs=1e-15)
    terms = PlantTerms(("joint1", "joint2", "joint4"), {})
    effect.add_to_plant(terms, 2, {"viscous": 0.4})
    assert terms.viscous == [0.0, 0.0, 0.0]  # not Viscous's closed form: the plant evaluates its torque
    assert [(type(e), k) for e, k, _ in terms.generic] == [(Cubic, 2)]


def test_the_smooth_sign_replaces_sign_in_every_formula_that_uses_it():
    ops = smooth_sign_ops(0.2)
    assert Coulomb().formula(0.0, 0.05, 0.0, [0.3], {}, ops) == 0.3 * np.tanh(0.05 / 0.2)
    assert Coulomb().formula(0.0, 0.05, 0.0, [0.3], {}, SCALAR_OPS) == 0.3
    assert Viscous().formula(0.0, 0.05, 0.0, [0.3], {}, ops) == 0.3 * 0.05  # no sign: unchanged
