"""The one library of named physical effects, shared by the simulated plant (the truth), the physics
model (columns to fit) and the diagnosis (candidates).

    from crane_io.physics.effects import get_effect, list_effects, load_effect_file
    eff = get_effect("coulomb")                  # a fresh instance
    cols = eff.columns(q, dq, ddq, joint=1)      # (N, J, 1)
    eff.values_from_coefficients(coefs)          # {"coulomb": 0.21}, units in eff.units

A user adds an effect without editing the package: write a Python file with `Effect` subclasses (see
docs/arm-model.md), or an effect-spec file (effects as data over the basis grammar of
crane_io/physics/effects/terms.py), and call `load_effect_file(path)` (or pass `--effect-file` on the
command lines). A saved model or plant stores its effects as data (crane_io/physics/effects/spec.py):
loading one never runs code.
"""

from __future__ import annotations

import inspect

import numpy as np

from crane_io.errors import ConfigError
from crane_io.physics.effects.base import Effect, Param, PlantTerms
from crane_io.physics.effects.library import BUILTIN_EFFECTS

__all__ = ["Effect", "Param", "PlantTerms", "list_effects", "get_effect", "register_effect",
           "load_effect_file",
           "effect_names", "in_rigid_body_span"]

_REGISTRY: dict[str, type[Effect]] = {}


def register_effect(cls: type[Effect], replace: bool = False) -> type[Effect]:
    """Add an Effect subclass to the library (usable as a decorator). A name already taken by a
    different class -> ConfigError unless replace=True."""
    if not (inspect.isclass(cls) and issubclass(cls, Effect)):
        raise ConfigError(f"{cls!r} is not an Effect subclass")
    name = getattr(cls, "name", "")
    if not isinstance(name, str) or not name:
        raise ConfigError(f"effect class {cls.__name__} has no name")
    if cls.scope not in ("joint", "arm"):
        raise ConfigError(f"effect {name!r} has scope {cls.scope!r}; it must be 'joint' or 'arm'")
    for p in cls.params:
        if p.model and not p.linear and p.name not in cls.shape_grid:
            raise ConfigError(f"effect {name!r}: shape parameter {p.name!r} needs a shape_grid entry")
    old = _REGISTRY.get(name)
    if old is not None and old is not cls and not replace and old.__qualname__ != cls.__qualname__:
        raise ConfigError(f"an effect named {name!r} already exists ({old.__name__})")
    _REGISTRY[name] = cls
    return cls


for _cls in BUILTIN_EFFECTS:
    register_effect(_cls)


def effect_names() -> list[str]:
    return list(_REGISTRY)


def list_effects() -> list[Effect]:
    """A fresh instance of every registered effect, built-ins first, in registration order."""
    return [cls() for cls in _REGISTRY.values()]


def get_effect(name: str, **kwargs) -> Effect:
    """A fresh instance of the named effect (kwargs go to its constructor, e.g. dynamics=... for
    payload and torque-constant-error). Unknown name -> ConfigError listing the names."""
    cls = _REGISTRY.get(name)
    if cls is None:
        raise ConfigError(f"unknown effect {name!r}; known effects: {', '.join(_REGISTRY)}")
    try:
        return cls(**kwargs)
    except TypeError as exc:
        raise ConfigError(f"effect {name!r} cannot be built with {sorted(kwargs)}: {exc}") from None


def load_effect_file(path) -> list[str]:
    """Register the effects of a file the user named (`--effect-file`); returns their names.

    An effect-spec file (`.json`, crane_io.physics.effects.spec: effects as data, e.g. written by
    `crane-train diagnose --write-effect-file`) is read, never run. A Python file (`.py`) is run: the one
    way a user's code enters the toolkit, and only for a file named explicitly. A missing or broken file,
    or one with no effect, -> ConfigError."""
    from crane_io.physics.effects import spec as specs

    path, raw, sha = specs.read_effect_file(path)
    if path.suffix == ".json":
        found = [specs.terms_effect_class(s) for s in specs.read_spec_file(path, raw)]
    elif path.suffix == ".py":
        found = specs.run_python_effects(path, raw, sha)
    else:
        raise ConfigError(f"effect file {path} must be an effect-spec file (.json) or a Python file (.py)")
    for cls in found:
        old = _REGISTRY.get(cls.name)
        register_effect(cls, replace=True)
        try:
            inst = cls()
            n, j = 4, getattr(cls, "_n_joints", 0) or 3
            cols = inst.columns(np.zeros((n, j)), np.ones((n, j)), np.zeros((n, j)),
                                None if inst.scope == "arm" else 0, None)
            if np.shape(cols)[:2] != (n, j):
                raise ValueError(f"columns() returned shape {np.shape(cols)}, expected (N, J, k)")
        except ConfigError:
            raise
        except Exception as exc:
            if old is None:
                _REGISTRY.pop(cls.name, None)
            else:
                _REGISTRY[cls.name] = old
            raise ConfigError(f"effect {cls.name!r} in {path} does not work: "
                              f"{type(exc).__name__}: {exc}") from None
    return [cls.name for cls in found]


def in_rigid_body_span(effect: Effect, joint: int | None, dynamics=None, shape: dict | None = None,
                       samples: int = 300, seed: int = 0) -> bool:
    """True when the effect's columns lie in the span of the rigid-body base regressor, i.e. a
    rigid-body model that fits its own base parameters absorbs the effect (e.g. rotor inertia on
    joint1, a payload). Checked numerically on random states."""
    if dynamics is None:
        from crane_io.physics.dynamics import ArmDynamics

        dynamics = ArmDynamics()
    rng = np.random.default_rng(seed)
    j = dynamics.n_joints
    q = rng.uniform(-1.2, 0.0, (samples, j)) + rng.uniform(0, 1.2, (samples, j))
    dq = rng.normal(0, 1, (samples, j))
    ddq = rng.normal(0, 5, (samples, j))
    yb = dynamics.base_regressor(q, dq, ddq).reshape(samples * j, -1)
    c = effect.columns(q, dq, ddq, joint, shape).reshape(samples * j, -1)
    coef, *_ = np.linalg.lstsq(yb, c, rcond=None)
    resid = np.linalg.norm(c - yb @ coef) / max(np.linalg.norm(c), 1e-300)
    return bool(resid < 1e-6)
