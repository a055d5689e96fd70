"""Planted effects on the wrist joints: the diagnosis names them first and adding them halves the error.

Seven joints: what tests/test_diagnose.py checks for the three paper joints, on a 7-joint
arm. For the presets `hidden-wrist-coulomb` (joint6's 0.12 N m Coulomb friction hidden) and
`hidden-wrist-spring` (a 0.3 N m/rad spring on joint5, relaxed at 0.5 rad, hidden): a simulated session
with all seven joints driven (tests/planted.py, joints="all", 90 simulated seconds, seeded), a baseline
rigid-body model over all seven joints fitted the way `crane-train fit --joints all` does with the
preset's [known] effects (per-joint evaluation sets, train/data/splits.py), then:

- the diagnosis ranks the hidden effect first on its joint, significant, removing most of the remaining
  error, with its estimate near the truth: Coulomb within 0.015 N m of 0.12; the spring's stiffness
  within 0.03 N m/rad of 0.3 and its rest angle within 0.05 rad of 0.5; no other joint blames anything.
  Measured (90 s, seeds 0 / 1 / 2): Coulomb on joint6 rank 1, 99.7 / 99.6 / 99.5 % removed, 0.1187 +-
  0.0002 / 0.1193 +- 0.0004 / 0.1183 +- 0.0004 N m; spring on joint5 rank 1, 99.9 % removed (all three),
  stiffness 0.2991 +- 0.0020 / 0.2981 +- 0.0014 / 0.2991 +- 0.0013 N m/rad, rest angle 0.511 +- 0.003 /
  0.509 +- 0.008 / 0.501 +- 0.004 rad;
- refitting with the effect added (`--effect NAME:joint=JOINT`, the fit choosing shape parameters such
  as the spring's rest angle itself) at least halves that joint's held-out MSE, where the joint moves
  (`crane-train compare`), and on the fit's test set (per-joint: the test rows where that joint moves).

The fit at seven joints solves each joint's torque equation where that joint moves (train.models.
rigid_body, rows "auto" -> "per-joint"): on the paper's all-moving rows (1-4 % of a session, 44-90 rows of
a 90 s one for 63 parameters) the spring's rest angle was picked on a handful of validation rows, at
-0.5 rad with seed 0, and joint5's error did not fall.

`baseline-7dof` (nothing hidden): the diagnosis does not invent the wrist presets' effects (no significant
Coulomb friction or spring on joints 5 and 6). It is not silent there, though: with seeds 0-2 the best
candidate on joints 5 and 6 is always gear backlash with a negative reversal inertia (-0.0027 to -0.0052
kg m^2, the order of those joints' rotor inertia, 0.0055-0.006), removing 5-20 % of the remaining error;
with seed 0 it is significant on both joints (16 %), with seeds 1 and 2 on neither. So the test bounds
what any significant candidate there explains (below 30 %) rather than asserting none.

CRANE_PLANTED_SEED=N runs the file with another seed.
"""

from __future__ import annotations

import os

import pytest

from crane_io.sim.plant_config import load_plant_config
from tests.fitting import fit_model
from tests.planted import simulate_session
from train.data.preprocess import preprocess
from train.data.session import read_sessions
from train.diagnosis.diagnose import diagnose
from train.evaluation.compare import compare_models
from train.evaluation.heldout import model_settings
from train.models.registry import load_model

DURATION_S = 90.0
SEED = int(os.environ.get("CRANE_PLANTED_SEED", "0"))
# the hidden effect's main parameters: truth and tolerance of the diagnosis' estimate
TOLERANCE = {"hidden-wrist-coulomb": {"coulomb": 0.015},
             "hidden-wrist-spring": {"stiffness": 0.03, "rest_angle": 0.05}}


@pytest.fixture(scope="module")
def wrist_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("planted-wrist")


def _fit(session, out, effects):
    return fit_model([str(session)], "rigid-body", out, seed=SEED, effects=effects, scale_to_data=True,
                     progress=False, joints="all")


@pytest.fixture(scope="module")
def case(wrist_dir):
    """preset -> (session, baseline fit doc, diagnosis, known); computed once per preset."""
    cache = {}

    def get(preset):
        if preset not in cache:
            session = wrist_dir / f"{preset}.h5"
            simulate_session(session, preset, DURATION_S, seed=SEED, joints="all")
            known = list(load_plant_config(preset).known)
            base = wrist_dir / f"{preset}-baseline"
            doc = _fit(session, base, known)
            model = load_model(base)
            ds = preprocess(read_sessions([session]), model_settings(model, base)[0])
            assert tuple(ds.joint_names) == tuple(f"joint{k}" for k in range(1, 8))
            cache[preset] = (session, doc, diagnose(model, ds), known)
        return cache[preset]

    return get


@pytest.mark.parametrize("preset", ["hidden-wrist-coulomb", "hidden-wrist-spring"])
def test_a_hidden_wrist_effect_is_named_first_and_adding_it_halves_the_error(preset, case, wrist_dir):
    session, before, result, known = case(preset)
    assert before["eval_set"] == "per-joint"
    hidden = load_plant_config(preset).hidden
    joint = hidden.joint
    best = result.best(joint)
    assert best is not None and best.effect == hidden.effect, result.summary[joint]
    assert best.rank == 1 and best.significant and best.error_reduction > 0.9, result.summary[joint]
    assert best.sentence.startswith(f"{joint}: ")
    for name, tol in TOLERANCE[preset].items():
        est = best.parameters[name]
        assert abs(est["value"] - hidden.values[name]) <= tol, (name, est, hidden.values)
        assert est["std"] >= 0
    for other in result.joints:
        if other != joint:
            assert not any(c.significant for c in result.for_joint(other)), result.summary[other]
    # add it as a user would (--effect NAME:joint=JOINT): the fit picks shape parameters itself
    fixed = wrist_dir / f"{preset}-fixed"
    after = _fit(session, fixed, known + [(hidden.effect, joint, None)])
    fitted = [e["values"] for e in load_model(fixed).effect_values()
              if e["effect"] == hidden.effect and e["joint"] == joint]
    assert len(fitted) == 1
    for name, tol in TOLERANCE[preset].items():  # the fit's own values (a spring's rest angle from its grid)
        assert abs(fitted[0][name] - hidden.values[name]) <= tol, (name, fitted, hidden.values)
    scores = compare_models([wrist_dir / f"{preset}-baseline", fixed], [session])
    moving = [m.moving_mse[joint] for m in scores.models]
    assert moving[1] <= 0.5 * moving[0], moving
    assert after["test"]["mse"][joint] <= 0.5 * before["test"]["mse"][joint], (before["test"], after["test"])


def test_nothing_hidden_on_the_wrist_is_not_blamed_on_coulomb_or_a_spring(case):
    _, _, result, _ = case("baseline-7dof")
    for joint in ("joint5", "joint6"):
        found = [c for c in result.for_joint(joint) if c.significant]
        assert not [c for c in found if c.effect in ("coulomb", "spring")], result.summary[joint]
        assert all(c.error_reduction < 0.3 for c in found), result.summary[joint]
