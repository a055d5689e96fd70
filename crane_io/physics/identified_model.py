"""An identified arm model: the rigid-body parameters `crane-train identify` found, as a TOML file the
dynamics, the controller's nominal model and the simulated plant read (data only: loading it never runs
code).

    [identified]
    format_version = 1
    free = ["joint1", "joint2", "joint4"]      # the joints the parameters were identified for
    payload_mass = 0.0                          # kg at the tool, as identified
    [identified.locked]                         # every other arm joint and the angle it was held at, rad
    joint3 = 0.0
    ...
    [identified.bodies.joint2]                  # the body that joint moves (locked links merged in)
    parameters = [m, m c_x, m c_y, m c_z, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz]   # kg, kg m, kg m^2
    [identified.friction.joint2]                # optional: N m s/rad, N m
    viscous = 0.05
    coulomb = 0.24

Body parameters are pinocchio's dynamic parameters about the joint's own frame (the order of
crane_io.physics.dynamics.PARAMETER_NAMES). A body merges every locked link after its joint, so the
parameters hold only for the same free joints locked at the same angles (within LOCK_TOLERANCE): a model
asked for another set is refused in one sentence. Every body must be physically consistent (its
pseudo-inertia positive semidefinite, crane_io tolerance CONSISTENCY_TOLERANCE).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from crane_io.errors import ConfigError
from crane_io.toml_config import check_keys, dump_toml, is_number, read_toml

FORMAT_VERSION = 1
LOCK_TOLERANCE = 0.02  # rad: a held joint sags a little under its position controller
CONSISTENCY_TOLERANCE = 1e-9  # smallest pseudo-inertia eigenvalue allowed, in the body's own units
WHAT = "identified arm model"


def pseudo_inertia(v: np.ndarray) -> np.ndarray:
    """The 4 x 4 pseudo-inertia of one body's ten standard parameters."""
    m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = v
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    out = np.zeros((4, 4))
    out[:3, :3] = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    out[:3, 3] = out[3, :3] = (hx, hy, hz)
    out[3, 3] = m
    return out


def into_consistent(v: np.ndarray, margin: float = 10 * CONSISTENCY_TOLERANCE,
                    reach: float = 1e-5) -> np.ndarray:
    """The body's ten standard parameters, its pseudo-inertia J raised to at least `margin` by J + d 1
    (d added to the mass and 2 d to each of I_xx, I_yy, I_zz) when a solver left it just outside the
    consistent set: short of it by at most `reach` times its largest eigenvalue. Anything further out is
    returned as it is (the loader then refuses it)."""
    v = np.asarray(v, dtype=float).copy()
    eig = np.linalg.eigvalsh(pseudo_inertia(v))
    deficit = margin - eig.min()
    if 0 < deficit <= reach * max(eig.max(), 1.0):
        v[0] += deficit
        v[[4, 6, 9]] += 2 * deficit
    return v


@dataclass
class IdentifiedArm:
    free: tuple[str, ...]
    locked: dict[str, float]
    bodies: dict[str, np.ndarray]  # free joint -> (10,) standard parameters
    payload_mass: float = 0.0
    friction: dict[str, dict[str, float]] = field(default_factory=dict)
    source: str = "identified arm model"

    def check_configuration(self, joints, locked: dict[str, float]) -> None:
        """ConfigError unless `joints` free with the others at `locked` (default 0 rad) is the identified
        configuration."""
        from crane_io.physics.arm_model import JOINT_NAMES

        if sorted(joints) != sorted(self.free):
            raise ConfigError(f"{self.source} was identified for the free joints {', '.join(self.free)}, "
                              f"not {', '.join(joints)}; identify the arm for this joint set")
        for name in JOINT_NAMES:
            if name in self.free:
                continue
            want, given = self.locked.get(name, 0.0), float(locked.get(name, 0.0))
            if abs(given - want) > LOCK_TOLERANCE:
                raise ConfigError(f"{self.source} was identified with {name} held at {want:.4g} rad, not "
                                  f"{given:.4g} rad; hold it there or identify the arm again")

    def to_toml(self) -> str:
        doc = {"identified": {"format_version": FORMAT_VERSION, "free": list(self.free),
                              "payload_mass": float(self.payload_mass),
                              "locked": {k: float(v) for k, v in self.locked.items()},
                              "bodies": {k: {"parameters": [float(x) for x in v]}
                                         for k, v in self.bodies.items()},
                              **({"friction": {j: {k: float(x) for k, x in f.items()}
                                               for j, f in self.friction.items()}} if self.friction else {})}}
        return "# An identified CRANE-X7 model (crane-train identify); data only.\n" + dump_toml(doc)

    @classmethod
    def from_toml(cls, path: str | Path) -> IdentifiedArm:
        where = str(path)
        data = read_toml(path, what=WHAT)
        check_keys(data, ("identified",), where)
        table = data.get("identified")
        if not isinstance(table, dict):
            raise ConfigError(f"{WHAT} {where} has no [identified] table")
        return cls.from_dict(table, f"{WHAT} {where}")

    @classmethod
    def from_dict(cls, t: dict, where: str) -> IdentifiedArm:
        from crane_io.physics.arm_model import JOINT_NAMES

        check_keys(t, ("format_version", "free", "locked", "bodies", "payload_mass", "friction"), where)
        if t.get("format_version") != FORMAT_VERSION:
            raise ConfigError(f"{where} has format_version {t.get('format_version')!r}; this toolkit reads "
                              f"{FORMAT_VERSION}")
        free = t.get("free")
        if (not isinstance(free, list) or not free or len(set(free)) != len(free)
                or not all(isinstance(n, str) and n in JOINT_NAMES for n in free)):
            raise ConfigError(f"{where}: `free` must be a list of distinct joint names "
                              f"({', '.join(JOINT_NAMES)})")
        locked = t.get("locked", {})
        if not isinstance(locked, dict) or not all(k in JOINT_NAMES and k not in free and is_number(v)
                                                    for k, v in locked.items()):
            raise ConfigError(f"{where}: `locked` must map joints that are not free to finite angles in rad")
        payload = t.get("payload_mass", 0.0)
        if not is_number(payload) or payload < 0:
            raise ConfigError(f"{where}: `payload_mass` must be a non-negative number of kg, got {payload!r}")
        bodies_t = t.get("bodies")
        if not isinstance(bodies_t, dict) or sorted(bodies_t) != sorted(free):
            raise ConfigError(f"{where}: `bodies` must hold one table per free joint ({', '.join(free)})")
        bodies = {name: _body(bodies_t[name], f"{where}, body {name}") for name in free}
        friction = _friction(t.get("friction", {}), free, where)
        return cls(tuple(free), {k: float(v) for k, v in locked.items()}, bodies, float(payload), friction,
                   where)


def _body(table, where: str) -> np.ndarray:
    if not isinstance(table, dict):
        raise ConfigError(f"{where} must be a table with `parameters`")
    check_keys(table, ("parameters",), where)
    v = table.get("parameters")
    if not isinstance(v, list) or len(v) != 10 or not all(is_number(x) for x in v):
        raise ConfigError(f"{where}: `parameters` must be ten finite numbers (m, m c, I about the joint)")
    v = np.array(v, dtype=float)
    if v[0] <= 0 or np.linalg.eigvalsh(pseudo_inertia(v)).min() < -CONSISTENCY_TOLERANCE:
        raise ConfigError(f"{where} is not physically consistent (a mass that is not positive, or an inertia "
                          f"no rigid body has); identify the arm again")
    return v


def _friction(table, free, where: str) -> dict[str, dict[str, float]]:
    if not isinstance(table, dict) or not all(k in free for k in table):
        raise ConfigError(f"{where}: `friction` must hold tables of free joints")
    out = {}
    for joint, f in table.items():
        if not isinstance(f, dict):
            raise ConfigError(f"{where}: friction of {joint} must be a table")
        check_keys(f, ("viscous", "coulomb"), f"{where}, friction of {joint}")
        if not all(is_number(x) and x >= 0 for x in f.values()):
            raise ConfigError(f"{where}: friction of {joint} must be non-negative numbers")
        out[joint] = {k: float(x) for k, x in f.items()}
    return out
