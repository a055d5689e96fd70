"""The physical-effects library: torque == columns x coefficients, round trips through the fitted
coefficients, the registry, and a user's effect file."""

import textwrap
from pathlib import Path

import numpy as np
import pytest

from crane_io.errors import ConfigError
from crane_io.physics.dynamics import ArmDynamics
from crane_io.physics.effects import (
    Effect,
    effect_names,
    get_effect,
    in_rigid_body_span,
    list_effects,
    load_effect_file,
    register_effect,
)

BUILTINS = ["coulomb", "coulomb-asym", "viscous", "stribeck", "stiction", "offset", "spring", "payload",
            "rotor-inertia", "cogging", "backlash", "torque-constant-error"]


@pytest.fixture(scope="module")
def states():
    rng = np.random.default_rng(3)
    n = 150
    q = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-1.4, 1.4, n), rng.uniform(-2.5, 0, n)])
    dq = rng.normal(0, 0.5, (n, 3))
    dq[::10] = 0.0  # some samples at rest
    return q, dq, rng.normal(0, 5, (n, 3))


def _random_values(eff, rng):
    values = {}
    for p in eff.params:
        if p.linear:
            values[p.name] = float(rng.uniform(0.05, 0.5)) * (1 if p.default >= 0 else -1)
        elif p.name in eff.shape_grid:
            values[p.name] = float(rng.choice(eff.shape_grid[p.name]))
    return values


def test_every_builtin_is_registered_with_complete_metadata():
    assert set(BUILTINS) <= set(effect_names())
    for eff in list_effects():
        assert eff.name and eff.title and eff.description and eff.signature
        assert eff.scope in ("joint", "arm")
        assert "{joint}" in eff.signature or eff.scope == "arm"
        assert eff.describe_signature("joint2")
        for p in eff.params:
            assert p.unit and p.description
        for p in eff.shape_params:
            assert len(eff.shape_grid[p.name]) >= 2


@pytest.mark.parametrize("name", BUILTINS)
def test_torque_equals_columns_times_coefficients_and_round_trips(name, states):
    q, dq, ddq = states
    rng = np.random.default_rng(hash(name) % 2**32)
    eff = get_effect(name)
    for joint in (0, 1, 2):
        values = _random_values(eff, rng)
        shape = {p.name: values[p.name] for p in eff.shape_params}
        tau = eff.torque(q, dq, ddq, joint, values)
        cols = eff.columns(q, dq, ddq, joint, shape)
        assert cols.shape == (len(q), 3, eff.n_columns())
        coefs = eff.coefficients(values)
        assert np.allclose(cols @ coefs, tau, atol=1e-12)
        assert np.abs(tau).max() > 0
        if eff.scope == "joint":
            others = [j for j in range(3) if j != joint]
            assert np.all(tau[:, others] == 0) and np.all(cols[:, others] == 0)
        back = eff.values_from_coefficients(coefs, shape)
        for p in eff.params:
            if p.model:
                assert back[p.name] == pytest.approx(values[p.name], abs=1e-12)
        assert len(eff.column_names("joint2", shape)) == eff.n_columns()


def test_friction_effects_oppose_motion_and_report_a_static_band(states):
    q, dq, ddq = states
    dq = dq * 0.05  # slow enough that the Stribeck bump is visible
    for name in ("coulomb", "coulomb-asym", "stribeck", "stiction"):
        eff = get_effect(name)
        tau = eff.torque(q, dq, ddq, 1, eff.default_values())[:, 1]
        moving = dq[:, 1] != 0
        # the motor must push harder in the direction of motion (Stribeck fades to ~0 at speed)
        assert np.all(tau[moving] * dq[moving, 1] >= 0) and np.abs(tau[moving]).max() > 0.05
        assert np.all(tau[~moving] == 0)
        lo, hi = eff.static_band(eff.default_values())
        assert lo > 0 and hi > 0
    assert get_effect("stiction").static_band({"coulomb": 0.2, "breakaway": 0.3}) == (0.3, 0.3)


def test_rigid_body_span_tells_which_effects_a_fitted_model_absorbs():
    dyn = ArmDynamics()
    rotor = get_effect("rotor-inertia")
    assert in_rigid_body_span(rotor, 0, dyn)  # joint1: merges with the link's axis inertia
    assert in_rigid_body_span(rotor, 1, dyn)  # joint2 too
    assert not in_rigid_body_span(rotor, 2, dyn)  # joint4: identifiable
    assert in_rigid_body_span(get_effect("payload", dynamics=dyn), None, dyn)
    for name, joint in (("coulomb", 1), ("viscous", 0), ("offset", 0), ("spring", 1), ("cogging", 2),
                        ("torque-constant-error", 2)):
        assert not in_rigid_body_span(get_effect(name), joint, dyn), name


def test_unknown_effect_and_bad_arguments_raise_config_errors(states):
    q, dq, ddq = states
    with pytest.raises(ConfigError, match="unknown effect 'magic'.*coulomb"):
        get_effect("magic")
    with pytest.raises(ConfigError, match="no parameter"):
        get_effect("coulomb").torque(q, dq, ddq, 0, {"colomb": 1.0})
    with pytest.raises(ConfigError, match="one joint"):
        get_effect("viscous").columns(q, dq, ddq, None)
    with pytest.raises(ConfigError, match="out of range"):
        get_effect("viscous").columns(q, dq, ddq, 3)
    with pytest.raises(ConfigError, match="bound to dynamics"):
        get_effect("payload").columns(q[:, :2], dq[:, :2], ddq[:, :2], None)


EXAMPLE_EFFECT_FILE = Path(__file__).parents[1] / "docs" / "examples" / "cable_drag.py"


def test_a_user_effect_file_registers_without_editing_the_package(tmp_path, states):
    path = tmp_path / "my_effects.py"
    path.write_text(EXAMPLE_EFFECT_FILE.read_text())
    assert load_effect_file(path) == ["cable-drag"]
    eff = get_effect("cable-drag")
    q, dq, ddq = states
    tau = eff.torque(q, dq, ddq, 2, {"drag": 0.3})
    assert np.allclose(tau[:, 2], 0.3 * q[:, 2] * np.abs(q[:, 2]))
    assert "cable-drag" in [e.name for e in list_effects()]


def test_broken_effect_files_raise_one_sentence_config_errors(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_effect_file(tmp_path / "missing.py")
    bad = tmp_path / "bad.py"
    bad.write_text("this is not python(\n")
    with pytest.raises(ConfigError, match="failed to load: SyntaxError"):
        load_effect_file(bad)
    empty = tmp_path / "empty.py"
    empty.write_text("x = 1\n")
    with pytest.raises(ConfigError, match="defines no Effect"):
        load_effect_file(empty)
    broken = tmp_path / "broken.py"
    broken.write_text(textwrap.dedent('''
        from crane_io.physics.effects import Effect, Param
        class Broken(Effect):
            name = "broken-effect"
            title = "broken"; description = "d"; signature = "s {joint}"
            params = (Param("a", "N m", 1.0, "a"),)
            def _columns(self, q, dq, ddq, joint, shape):
                raise RuntimeError("oops")
    '''))
    with pytest.raises(ConfigError, match="does not work"):
        load_effect_file(broken)
    assert "broken-effect" not in effect_names()


def test_register_effect_refuses_a_taken_name_and_non_effects():
    class Another(Effect):
        name = "coulomb"

    with pytest.raises(ConfigError, match="already exists"):
        register_effect(Another)
    with pytest.raises(ConfigError, match="not an Effect"):
        register_effect(int)
