"""The `Effect` base class: one named physical effect with parameters, its torque, its model-side
regressor columns and the residual signature it leaves when a model lacks it.

Conventions (all arrays SI, (N, J) in the dynamics' joint order):
- A one-joint effect whose torque has a closed form defines it once, in `formula(q, dq, ddq, c, shape, ops)`:
  the torque on its joint from that joint's angle, velocity and acceleration (floats, or (N,) arrays), its
  coefficients c and shape values, with the elementwise functions of `ops` (`ARRAY_OPS` for arrays,
  `SCALAR_OPS` for floats; `smooth_sign_ops(v0)` replaces sign(dq) by tanh(dq / v0)), the built-in
  shapes (crane_io.physics.effect_shapes: `ops.stribeck`, `ops.spring`, `ops.ripple`) included. Its regressor
  columns are the formula at each unit coefficient vector (`_columns`), and the control loop evaluates the
  same formula on floats (crane_io.physics.loop_model): one definition, the same IEEE operations in both.
- `torque(q, dq, ddq, joint, values)` is what the effect ADDS to the torque the motor must supply
  (inverse-dynamics sense): tau = tau_rigid + sum of effects.
- `columns(q, dq, ddq, joint, shape)` -> (N, J, k) are linear in the effect's coefficients for the
  given shape values: `torque == columns @ coefficients(values)` for every effect whose torque is
  exactly linear in its coefficients (all built-ins except where documented as approximations).
- Joint-scope effects act on one joint (`joint` = its column index) and their columns are zero in
  every other row; arm-scope effects (payload) act on all joints and ignore `joint`.
- Parameters: `linear=True` ones are recovered from the fitted coefficients
  (`values_from_coefficients`); `linear=False` ones are shape parameters chosen from `shape_grid`;
  `model=False` ones exist only in the simulated plant (they are not estimated from data).
- The simulated plant (crane_io.sim.arm_plant.ArmPlant) compiles every configured effect with
  `add_to_plant(terms, k, values)`: the effect adds its own contribution to a `PlantTerms` (per
  integrated joint k: Coulomb levels, Stribeck terms, viscous, offset, spring, cogging, armature, ...).
  The base class's contribution is the generic one: the plant evaluates `torque` every substep (as
  friction when `friction` is True). Built-in effects override `plant_terms` with their closed form, so
  each effect's physics lives in one class.
"""

from __future__ import annotations

import math
import types
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np

from crane_io.errors import ConfigError
from crane_io.physics import effect_shapes


def _sign(x: float) -> float:
    return 1.0 if x > 0 else (-1.0 if x < 0 else 0.0)  # as np.sign: 0 at 0


def _positive(x: float) -> float:
    return 1.0 if x > 0 else 0.0


def on_arrays(shape):
    """A shape of crane_io.physics.effect_shapes (written on floats with math's exp, sin, cos) as the same
    code on arrays: its `math` is numpy."""
    return types.FunctionType(shape.__code__, {**shape.__globals__, "math": np}, shape.__name__,
                              shape.__defaults__)


# the elementwise functions an effect's formula uses: on (N,) arrays, and on floats (the same values); the
# built-in effects' shapes (crane_io.physics.effect_shapes) among them
ARRAY_OPS = SimpleNamespace(sign=np.sign, positive=lambda x: (x > 0).astype(float), exp=np.exp,
                            sin=np.sin, cos=np.cos, stribeck=on_arrays(effect_shapes.stribeck),
                            spring=effect_shapes.spring, ripple=on_arrays(effect_shapes.ripple))
SCALAR_OPS = SimpleNamespace(sign=_sign, positive=_positive, exp=math.exp, sin=math.sin, cos=math.cos,
                             stribeck=effect_shapes.stribeck, spring=effect_shapes.spring,
                             ripple=effect_shapes.ripple)


def smooth_sign_ops(v0: float) -> SimpleNamespace:
    """SCALAR_OPS with sign(v) replaced by tanh(v / v0) (v0 > 0 rad/s): friction without its jump at rest."""
    return SimpleNamespace(**{**vars(SCALAR_OPS), "sign": lambda v: math.tanh(v / v0)})


@dataclass(frozen=True)
class Param:
    name: str
    unit: str
    default: float
    description: str
    linear: bool = True  # fitted through the linear coefficients; False = shape parameter (grid)
    model: bool = True  # False: only the simulated plant uses it; never estimated


@dataclass
class PlantTerms:
    """What the configured effects contribute to the simulated plant, per integrated joint: index k =
    0..n-1 of `joints` (the joints the plant integrates, arm order). Lists hold n floats (N m, N m s/rad,
    N m/rad, kg m^2); every effect adds its part with `Effect.add_to_plant`, in configuration order."""

    joints: tuple[str, ...]
    torque_constant: dict[str, float]  # TRUE N m/A of every joint by name (torque-constant-error divides it)
    coulomb_pos: list[float] = field(default_factory=list)  # kinetic friction while moving positive
    coulomb_neg: list[float] = field(default_factory=list)  # (magnitude) while moving negative
    stribeck: list[list[tuple[float, float]]] = field(default_factory=list)  # per joint: (amplitude, vs)
    viscous: list[float] = field(default_factory=list)
    offset: list[float] = field(default_factory=list)
    springs: list[list[tuple[float, float]]] = field(default_factory=list)  # per joint: (stiffness, rest)
    cogging: list[tuple[int, float, float, float]] = field(default_factory=list)  # (k, sin, cos, cycles)
    armature: list[float] = field(default_factory=list)  # rotor inertia (the dynamics' armature)
    payload: float = 0.0  # kg at the tool
    backlash: dict[int, tuple[float, float]] = field(default_factory=dict)  # k -> (gap width, motor inertia)
    generic: list[tuple] = field(default_factory=list)  # (effect, k or None, values): torque() per substep
    band_pos: list[float] = field(default_factory=list)  # static friction band (against + motion)
    band_neg: list[float] = field(default_factory=list)  # (against - motion)

    def __post_init__(self):
        n = len(self.joints)
        for name in ("coulomb_pos", "coulomb_neg", "viscous", "offset", "armature", "band_pos", "band_neg"):
            if not getattr(self, name):
                setattr(self, name, [0.0] * n)
        for name in ("stribeck", "springs"):
            if not getattr(self, name):
                setattr(self, name, [[] for _ in range(n)])


class Effect:
    """Base class of every physical effect. Subclass, set the class attributes, implement `formula` (a
    one-joint closed form) or `_columns` (and override `coefficients`/`values_from_coefficients` when the
    coefficients are not simply the linear parameters in order)."""

    name: str = ""  # library key, e.g. "coulomb"
    version: int = 1  # of the effect's definition: a saved model records it (crane_io.physics.effects.spec)
    title: str = ""  # e.g. "Coulomb friction"
    description: str = ""  # what it models, one or two sentences
    signature: str = ""  # residual signature when missing; may contain {joint}
    params: tuple[Param, ...] = ()
    shape_grid: dict[str, list] = {}
    # shape parameters that only take whole numbers (ripple periods per revolution): a fit refines them
    # over the integers between grid points, never to a fraction
    integer_shapes: tuple[str, ...] = ()
    scope: str = "joint"  # "joint" or "arm"
    friction: bool = False  # the plant treats it as friction: it can hold a joint at rest
    # formula(q, dq, ddq, c, shape, ops) -> the torque on the effect's joint (see the module docstring);
    # None: the effect defines `_columns` instead
    formula = None

    # ---- parameter helpers ------------------------------------------------------------------------------
    @property
    def linear_params(self) -> tuple[Param, ...]:
        return tuple(p for p in self.params if p.linear and p.model)

    @property
    def shape_params(self) -> tuple[Param, ...]:
        return tuple(p for p in self.params if not p.linear and p.model)

    @property
    def units(self) -> dict[str, str]:
        return {p.name: p.unit for p in self.params}

    def default_values(self) -> dict[str, float]:
        return {p.name: float(p.default) for p in self.params}

    def default_shape(self) -> dict[str, float]:
        return {p.name: float(p.default) for p in self.shape_params}

    def shape_options(self) -> list[dict[str, float]]:
        """Every combination of the shape grid ([{}] when the effect has no shape parameter)."""
        combos: list[dict[str, float]] = [{}]
        for p in self.shape_params:
            grid = self.shape_grid.get(p.name, [p.default])
            combos = [{**c, p.name: float(v)} for c in combos for v in grid]
        return combos

    def check_values(self, values: dict | None) -> dict[str, float]:
        """Defaults filled in; unknown names -> ConfigError."""
        values = dict(values or {})
        known = {p.name for p in self.params}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ConfigError(f"effect {self.name!r} has no parameter(s) {', '.join(unknown)} "
                              f"(parameters: {', '.join(sorted(known)) or 'none'})")
        out = self.default_values()
        for k, v in values.items():
            try:
                out[k] = float(v)
            except (TypeError, ValueError):
                raise ConfigError(f"parameter {k} of effect {self.name!r} must be a number, "
                                  f"got {v!r}") from None
            if not np.isfinite(out[k]):
                raise ConfigError(f"parameter {k} of effect {self.name!r} must be finite, got {v!r}")
        return out

    def _shape(self, shape: dict | None) -> dict[str, float]:
        s = self.default_shape()
        for k, v in (shape or {}).items():
            if k in s:
                s[k] = float(v)
            elif k not in self.units:
                raise ConfigError(f"effect {self.name!r} has no shape parameter {k!r}")
        return s

    def n_columns(self) -> int:
        return len(self.linear_params)

    # ---- the three views ------------------------------------------------------------------------------
    def columns(self, q, dq, ddq, joint: int | None, shape: dict | None = None) -> np.ndarray:
        """(N, J, k) regressor columns for the given shape values (defaults when None)."""
        q, dq, ddq = _batch(q, dq, ddq)
        j = self._check_joint(joint, q.shape[1])
        return self._columns(q, dq, ddq, j, self._shape(shape))

    def coefficients(self, values: dict) -> np.ndarray:
        """(k,) coefficients that multiply the columns, from named parameter values."""
        v = self.check_values(values)
        return np.array([v[p.name] for p in self.linear_params])

    def values_from_coefficients(self, coefs, shape: dict | None = None) -> dict[str, float]:
        """Named parameter values (units in `units`) from fitted coefficients plus the shape used."""
        coefs = np.asarray(coefs, dtype=float).ravel()
        out = {p.name: float(c) for p, c in zip(self.linear_params, coefs)}
        out.update(self._shape(shape))
        return out

    def torque(self, q, dq, ddq, joint: int | None, values: dict | None = None) -> np.ndarray:
        """(N, J) torque the effect adds to what the motor must supply."""
        v = self.check_values(values)
        shape = {p.name: v[p.name] for p in self.shape_params}
        return self.columns(q, dq, ddq, joint, shape) @ self.coefficients(v)

    def column_names(self, joint: int | str | None, shape: dict | None = None) -> list[str]:
        where = "" if self.scope == "arm" or joint is None else (
            f"@{joint}" if isinstance(joint, str) else f"@joint#{joint}")
        return [f"{self.name}.{p.name}{where}" for p in self.linear_params]

    def static_band(self, values: dict) -> tuple[float, float]:
        """Friction the effect can supply at rest: (against negative motion, against positive motion),
        both >= 0 N m. Only meaningful when `friction` is True."""
        return (0.0, 0.0)

    # ---- the simulated plant ------------------------------------------------------------------------------
    def add_to_plant(self, terms: PlantTerms, k: int | None, values: dict) -> None:
        """Add this effect (on integrated joint k, None for arm-scope effects; `values` checked and
        complete) to the plant's terms: `plant_terms`, plus the static friction band of a friction
        effect."""
        self.plant_terms(terms, k, values)
        if self.friction and k is not None:
            lo, hi = self.static_band(values)
            terms.band_neg[k] += lo
            terms.band_pos[k] += hi

    def plant_terms(self, terms: PlantTerms, k: int | None, values: dict) -> None:
        """This effect's contribution to the plant. Default: the plant evaluates `torque` every substep
        (friction when `friction` is True). Built-ins override it with their closed form."""
        terms.generic.append((self, k, values))

    def _same_physics(self, cls: type) -> bool:
        """True when this effect's torque is `cls`'s (a subclass that changes it is evaluated
        generically instead of with cls's closed form)."""
        t = type(self)
        return (t._columns is cls._columns and t.torque is cls.torque and t.coefficients is cls.coefficients
                and t.formula is cls.formula)

    def describe_signature(self, joint_name: str = "the joint") -> str:
        return self.signature.format(joint=joint_name)

    def describe(self) -> dict:
        """Plain-data summary (for listings and JSON)."""
        return {
            "name": self.name, "title": self.title, "description": self.description,
            "signature": self.signature, "scope": self.scope,
            "params": [{"name": p.name, "unit": p.unit, "default": p.default, "description": p.description,
                        "linear": p.linear, "model": p.model} for p in self.params],
            "shape_grid": {k: list(v) for k, v in self.shape_grid.items()},
        }

    @property
    def has_scalar_form(self) -> bool:
        """The effect's columns are its `formula` (so a per-sample path may evaluate the formula instead)."""
        return self.formula is not None and type(self)._columns is Effect._columns

    # ---- for subclasses ----------------------------------------------------------------------------------
    def _columns(self, q, dq, ddq, joint: int | None, shape: dict) -> np.ndarray:
        """The formula's columns: the formula at each unit coefficient vector."""
        if self.formula is None:
            raise NotImplementedError
        k = self.n_columns()
        qj, dqj, ddqj = q[:, joint], dq[:, joint], ddq[:, joint]
        cols = [self.formula(qj, dqj, ddqj, [1.0 if a == b else 0.0 for b in range(k)], shape, ARRAY_OPS)
                for a in range(k)]
        return joint_columns(len(q), q.shape[1], joint, *cols)

    def _check_joint(self, joint, n_joints: int) -> int | None:
        if self.scope == "arm":
            return None
        if joint is None or isinstance(joint, bool) or not isinstance(joint, (int, np.integer)):
            raise ConfigError(f"effect {self.name!r} acts on one joint; give the joint's column index, "
                              f"got {joint!r}")
        if not 0 <= int(joint) < n_joints:
            raise ConfigError(f"joint index {joint} is out of range for {n_joints} joints")
        return int(joint)

    def __repr__(self) -> str:
        return f"<Effect {self.name}>"


def _batch(q, dq, ddq):
    arrays = []
    for a, what in ((q, "q"), (dq, "dq"), (ddq, "ddq")):
        a = np.asarray(a, dtype=float)
        if a.ndim == 1:
            a = a[None, :]
        if a.ndim != 2:
            raise ConfigError(f"{what} must be an (N, J) array, got shape {a.shape}")
        arrays.append(a)
    if len({a.shape for a in arrays}) != 1:
        raise ConfigError(f"q, dq and ddq must have the same shape, got {[a.shape for a in arrays]}")
    return arrays


def joint_columns(n: int, n_joints: int, joint: int, *cols: np.ndarray) -> np.ndarray:
    """(N, J, k) with the k given (N,) columns in row `joint` and zeros elsewhere."""
    out = np.zeros((n, n_joints, len(cols)))
    for i, c in enumerate(cols):
        out[:, joint, i] = c
    return out
