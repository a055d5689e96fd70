"""InertiaModel.write (collect/controller.py, the compiled controller's inertia update) gives the bits of
InertiaModel.__call__ and g times them, refuses what it refuses (NaN, infinite angles), for every inertia
model and joint set."""

from __future__ import annotations

import numpy as np
import pytest

from collect.config import _build, load_config
from collect.controller import BilateralController
from collect.runner import run_arm
from crane_io.errors import ConfigError


def _controller(joints, **controller):
    cfg = load_config()
    if joints is not None:
        cfg = cfg.with_bilateral_joints(joints)
    values = cfg.values
    values["controller"].update(controller)
    cfg = _build(values, "the test")
    return BilateralController(cfg, run_arm(cfg), compiled=False)


@pytest.mark.parametrize("joints", [None, "all", "joint4,joint2", "joint1,joint2,joint3,joint4,joint6"])
@pytest.mark.parametrize("kind", ["dynamics", "constant"])
def test_write_gives_the_inertia_and_g_times_it_bit_for_bit(joints, kind):
    ctl = _controller(joints, inertia_model=kind)
    inertia = ctl.inertia
    assert (inertia._crba is not None) == (kind == "dynamics" and inertia._dyn._identity)
    rng = np.random.default_rng(2)
    J_row, gJ_row = ctl.J.copy(), np.zeros(ctl.n)
    for k in range(300):
        q = rng.uniform(-2.5, 2.5, ctl.n)
        if k % 10 == 0:
            q[rng.integers(ctl.n)] = -0.0
        inertia.write(q, ctl.g, J_row, gJ_row)
        want = inertia(q)
        assert J_row.tobytes() == want.tobytes(), k
        assert gJ_row.tobytes() == (ctl.g * want).tobytes(), k


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_write_refuses_what_the_dynamics_refuse_and_changes_nothing(bad):
    ctl = _controller(None)
    J_row, gJ_row = ctl.J.copy(), np.zeros(ctl.n)
    q = np.array([0.0, 0.3, 0.0, -1.0, 0.0, 0.2, 0.0, 0.0])
    ctl.inertia.write(q, ctl.g, J_row, gJ_row)
    before = J_row.tobytes(), gJ_row.tobytes()
    q[ctl.inertia._idx[1]] = bad
    with pytest.raises(ConfigError, match="NaN or infinite"):
        ctl.inertia(q)
    with pytest.raises(ConfigError, match="NaN or infinite"):
        ctl.inertia.write(q, ctl.g, J_row, gJ_row)
    assert (J_row.tobytes(), gJ_row.tobytes()) == before
