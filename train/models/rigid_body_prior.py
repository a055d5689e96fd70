"""A rigid-body fit that starts from an identified arm model (crane_io.physics.identified_model).

"Start from" means: the recursive least-squares filter of train.models.rigid_body starts at the
identified parameters instead of at zero, with a finite initial covariance, so the estimate is least
squares regularised towards them,

    theta = argmin |y - Phi theta|^2 + sum_k w (s_k (theta_k - theta0_k))^2,

where s_k scales column k to unit RMS on the training data and w = `weight` (option `start_weight`)
is the number of torque equations the identified parameters count as: each identified parameter is
held as firmly as `weight` rows of data would hold it. theta0 holds the identified model's base
parameters (its bodies through the fit's own base map) and, for the effect columns `viscous.*@JOINT` and
`coulomb.*@JOINT`, the model's identified viscous and Coulomb friction of that joint. Columns the arm
model says nothing about (other effects) keep the plain fit's start: zero, with no pull towards it.
"""

from __future__ import annotations

import numpy as np

from crane_io.errors import ConfigError

FRICTION_EFFECTS = ("viscous", "coulomb")


def arm_model_table(path) -> dict:
    """The [identified] table of the arm model TOML `path`, checked (ConfigError in one sentence); the
    model records this table, so it holds what it started from without the file."""
    from crane_io.physics.identified_model import IdentifiedArm

    arm = IdentifiedArm.from_toml(path)
    return {"source": str(path), "free": list(arm.free), "locked": dict(arm.locked),
            "payload_mass": arm.payload_mass,
            "bodies": {k: {"parameters": [float(x) for x in v]} for k, v in arm.bodies.items()},
            "friction": {j: dict(f) for j, f in arm.friction.items()}}


def start_point(table: dict, dynamics, joint_names, context_joints, locked: dict, names) -> tuple:
    """(theta0, has_prior) for the parameters `names` of a rigid-body model whose dynamics are
    `dynamics` (learning joints then context joints, the rest at `locked`): the identified base
    parameters and friction, and which entries the arm model gives. ConfigError when the arm model was
    identified for another configuration of the arm."""
    from crane_io.physics.identified_model import IdentifiedArm

    arm = IdentifiedArm.from_dict({"format_version": 1, **{k: table[k] for k in
                                                           ("free", "locked", "payload_mass", "bodies",
                                                            "friction")}},
                                  f"the arm model {table.get('source', '')}".strip())
    free = tuple(joint_names) + tuple(context_joints)
    try:
        arm.check_configuration(free, locked or {})
    except ConfigError as exc:
        raise ConfigError(f"{str(exc).split('; ')[0]}, so the rigid-body fit cannot start from it; fit "
                          f"on data recorded in that configuration") from None
    phi = np.concatenate([arm.bodies[name] for name in dynamics.body_names()])
    base = dynamics.base_map_rows(tuple(joint_names)) @ phi
    theta0 = np.zeros(len(names))
    given = np.zeros(len(names), dtype=bool)
    theta0[:len(base)], given[:len(base)] = base, True
    for k in range(len(base), len(names)):
        column, _, joint = names[k].partition("@")
        effect = column.split(".")[0]
        value = arm.friction.get(joint, {}).get(effect)
        if effect in FRICTION_EFFECTS and value is not None:
            theta0[k], given[k] = value, True
    return theta0, given
