"""The effect interface as the diagnosis reads it (train/diagnosis/diagnose.py): an effect's shape grid, the
parameters it estimates and their units, its named values from fitted coefficients, its regressor
columns on a session, and binding effects computed from rigid-body dynamics to the data's joints."""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING

import numpy as np

from crane_io.errors import CraneError

from ..data.angle_columns import columns_on
from ..data.dataset import Dataset
from .result import DiagnosisError

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from typing import Any


def shape_options(effect: Any) -> list[dict | None]:
    """Every shape the effect can take (one dict per point of its grid), [None] if it has no shape."""
    if hasattr(effect, "shape_options"):
        return [o or None for o in effect.shape_options()]
    grid = dict(getattr(effect, "shape_grid", None) or {})
    if not grid:
        return [None]
    names = list(grid)
    return [dict(zip(names, values)) for values in itertools.product(*(list(grid[n]) for n in names))]


def model_params(effect: Any) -> list:
    """The parameters a model estimates (not the plant-only ones)."""
    return [p for p in getattr(effect, "params", ()) if getattr(p, "model", True)]


def param_units(effect: Any) -> dict[str, str]:
    return {p.name: getattr(p, "unit", "") for p in model_params(effect)}


def complexity(effect: Any) -> int:
    """Number of estimated parameters (linear coefficients + shape parameters chosen from a grid)."""
    return max(len(model_params(effect)), 1)


def effect_name(effect: Any) -> str:
    return getattr(effect, "name", type(effect).__name__)


def named_values(effect: Any, coefs: np.ndarray, shape: dict | None) -> dict[str, float]:
    """The effect's estimated parameters by name, from its fitted column coefficients and shape."""
    values = effect.values_from_coefficients(np.asarray(coefs, dtype=float), shape)
    keep = {p.name for p in model_params(effect)} or set(values)
    out = {}
    for name, value in dict(values).items():
        if name not in keep:
            continue
        try:
            out[name] = float(value)
        except (TypeError, ValueError):
            continue
    if shape:
        for name, value in shape.items():
            if name in keep:
                out.setdefault(name, float(value))
    return out


def _effect_columns(effect: Any, joint: int | None, shape: dict | None) -> Callable[[Dataset], np.ndarray]:
    """Dataset -> the effect's columns on it (for train.data.angle_columns.columns_on: on zero-phase
    signals the columns' angle-only part is filtered as the torque is)."""
    return lambda d: effect.columns(d.q, d.dq, d.ddq, joint, shape)


def candidate_columns(effect: Any, ds: Dataset, joint: int | None) -> list[tuple[dict | None, np.ndarray]]:
    """[(shape, columns (N, J, c))] for every shape whose columns are finite and act on some moving
    sample; empty if there is none (the candidate cannot be tried on these data)."""
    out = []
    for shape in shape_options(effect):
        C = np.asarray(columns_on(ds, _effect_columns(effect, joint, shape)), dtype=float)
        if C.ndim == 2:
            C = C[:, :, None]
        usable = C.shape[:2] == ds.tau.shape and np.isfinite(C).all()
        if not usable or not np.any(C * ds.moving[:, :, None]):
            continue
        out.append((shape, C))
    return out


def bind(effect: Any, joint_names: Sequence[str]) -> Any:
    """Effects computed from the rigid-body dynamics get dynamics of the data's joints."""
    absent = object()
    dyn = getattr(effect, "_dynamics", absent)
    if dyn is absent or not hasattr(effect, "bind"):
        return effect
    if dyn is not None and tuple(getattr(dyn, "joint_names", ())) == tuple(joint_names):
        return effect
    try:
        from crane_io.physics.dynamics import ArmDynamics

        return effect.bind(ArmDynamics(joints=tuple(joint_names)))
    except CraneError as exc:
        raise DiagnosisError(f"effect {getattr(effect, 'name', effect)!r} needs the arm's dynamics for "
                             f"joints {', '.join(joint_names)}: {exc}") from None


def library_effects() -> list[Any]:
    """An instance of every effect in the library (crane_io.physics.effects)."""
    from crane_io.physics.effects import list_effects

    out = []
    for e in list_effects():
        out.append(e() if isinstance(e, type) else e)
    return out


def columns_at(effect: Any, ds: Dataset, joint: int | None) -> Callable[[dict], np.ndarray | None]:
    """shape -> the effect's (N, J, c) columns on the session at that shape, or None when they are not
    finite (for refining a shape between grid points)."""
    def at(shape: dict) -> np.ndarray | None:
        try:
            C = np.asarray(columns_on(ds, _effect_columns(effect, joint, shape)), dtype=float)
        except (CraneError, ValueError, ZeroDivisionError, FloatingPointError):
            return None
        if C.ndim == 2:
            C = C[:, :, None]
        return C if C.shape[:2] == ds.tau.shape and np.isfinite(C).all() else None

    return at
