"""The `Effect` base class: one named physical effect with parameters, its torque, its model-side
regressor columns and the residual signature it leaves when a model lacks it.

Conventions (all arrays SI, (N, J) in the dynamics' joint order):
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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError


@dataclass(frozen=True)
class Param:
    name: str
    unit: str
    default: float
    description: str
    linear: bool = True  # fitted through the linear coefficients; False = shape parameter (grid)
    model: bool = True  # False: only the simulated plant uses it; never estimated


class Effect:
    """Base class of every physical effect. Subclass, set the class attributes, implement
    `_columns` (and override `coefficients`/`values_from_coefficients` when the coefficients are not
    simply the linear parameters in order)."""

    name: str = ""  # library key, e.g. "coulomb"
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

    # ---- for subclasses ----------------------------------------------------------------------------------
    def _columns(self, q, dq, ddq, joint: int | None, shape: dict) -> np.ndarray:
        raise NotImplementedError

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
