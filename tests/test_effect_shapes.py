"""The built-in effects' torque shapes are written once (crane_io/physics/effect_shapes.py): the effects'
formulas (floats and arrays) and the simulated plant's effect functions (crane_io/sim/plant_layout.py, both
steppers) call them and state no exp, sin or cos of their own; the plant's Stribeck, spring and cogging
torques are the formula's on floats, bit for bit."""

from __future__ import annotations

import ast
import inspect
import math

import numpy as np
import pytest

from crane_io.physics import effect_shapes
from crane_io.physics.effects import PlantTerms, library
from crane_io.physics.effects.base import ARRAY_OPS, SCALAR_OPS
from crane_io.physics.effects.library import Cogging, Spring, Stribeck
from crane_io.sim import plant_layout

_TRANSCENDENTAL = {"exp", "sin", "cos"}


def _calls(tree) -> set[str]:
    """The attribute or plain names called anywhere in the tree (`ops.exp(...)` -> "exp")."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            out.add(f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", ""))
    return out


def test_no_formula_of_the_library_states_a_shape_of_its_own():
    tree = ast.parse(inspect.getsource(library))
    formulas = [f for f in ast.walk(tree) if isinstance(f, ast.FunctionDef) and f.name == "formula"]
    assert len(formulas) >= 10
    assert set().union(*map(_calls, formulas)) & _TRANSCENDENTAL == set()
    assert {"stribeck", "spring", "ripple"} <= set().union(*map(_calls, formulas))


def test_the_plants_effect_functions_state_no_shape_of_their_own():
    for fn in (plant_layout.kinetic, plant_layout.cogging_torque, plant_layout.other_torque):
        assert _calls(ast.parse(inspect.getsource(fn))) & _TRANSCENDENTAL == set(), fn.__name__
    assert plant_layout.stribeck is effect_shapes.stribeck and plant_layout.ripple is effect_shapes.ripple
    assert plant_layout.spring is effect_shapes.spring


@pytest.mark.parametrize("name", ["stribeck", "spring", "ripple"])
def test_the_array_shape_is_the_float_shapes_code_on_arrays(name):
    scalar, array = getattr(SCALAR_OPS, name), getattr(ARRAY_OPS, name)
    assert scalar is getattr(effect_shapes, name) and array.__code__ is scalar.__code__  # (spring: itself)
    rng = np.random.default_rng(4)
    x = rng.uniform(-2, 2, 200)
    args = {"stribeck": (0.05,), "spring": (0.4, 0.3), "ripple": (0.3, -0.2, 12.0)}[name]
    got = array(x, *args)
    assert isinstance(got, np.ndarray) and got.shape == x.shape
    np.testing.assert_allclose(got, [scalar(v, *args) for v in x.tolist()], rtol=1e-15, atol=1e-17)


def test_the_plants_springs_are_the_formula_on_floats_bit_for_bit():
    """Two springs on one joint: each is the formula's k (q - q0), added in configuration order."""
    springs = [{"stiffness": 0.4, "rest_angle": 0.5}, {"stiffness": 0.25, "rest_angle": -0.3}]
    terms = PlantTerms(("joint1",), {"joint1": 1.0})
    for values in springs:
        Spring().add_to_plant(terms, 0, values)
    row = plant_layout.effect_rows(terms, [-9.0], [9.0], [1.0], [0])[0].tolist()
    for q in np.random.default_rng(7).uniform(-2, 2, 300).tolist():
        want = 0.0
        for v in springs:
            want += Spring().formula(q, 0.0, 0.0, [v["stiffness"]], {"rest_angle": v["rest_angle"]},
                                     SCALAR_OPS)
        assert plant_layout.other_torque(row, q, 0.0, 0.0, 0.0) == want


def test_the_plants_stribeck_friction_and_cogging_are_the_formula_on_floats_bit_for_bit():
    vs, amp = 0.05, 0.1
    row = [0.0] * plant_layout.P_STRIB + [amp, vs]
    row[plant_layout.P_NSTRIB] = 1
    cog = Cogging()
    c = cog.coefficients({"amplitude": 0.08, "phase": 0.5, "cycles_per_rev": 12.0}).tolist()
    for v in np.random.default_rng(6).uniform(-0.3, 0.3, 300).tolist():
        want = Stribeck().formula(0.0, v, 0.0, [amp], {"stribeck_velocity": vs}, SCALAR_OPS)
        assert plant_layout.kinetic(row, v) == want
        want = cog.formula(v, 0.0, 0.0, c, {"cycles_per_rev": 12.0}, SCALAR_OPS)
        assert plant_layout.cogging_torque([0, *c, 12.0], v) == want
    assert effect_shapes.stribeck(vs, vs) == math.exp(-1.0) and effect_shapes.stribeck(0.0, vs) == 1.0
