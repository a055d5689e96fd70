"""The design of an exciting trajectory: the Fourier coefficients that minimise the condition number of
the identification regressor (crane_io/physics/excitation_trajectory.py) within the joints' limits and
clear of the table and the arm's own links (crane_io/physics/arm_clearance.py).

    space = DesignSpace(joints, lower, upper, vmax, amax, period=10.0, harmonics=5)
    result = optimise(space, dynamics, clearance, seed=0, evaluations=400, seconds=None, progress=print)
    result.trajectory.condition_number

The optimiser's variables are, per joint, q0 and the harmonics l = 2..L of a and b; the first
harmonic is a_j1 = -sum_{l>1} a_jl, b_j1 = -sum_{l>1} l b_jl, so every trajectory starts and ends each
period at rest (dq = ddq = 0). Every vector of variables maps to a trajectory within the limits
(`trajectory`): on a grid of GRID samples per period each joint's harmonics are scaled down until its
peak speed and acceleration on the grid fill at most GRID_FILL of vmax, amax and its swing at most
GRID_FILL of [lower, upper], then q0 is clipped so the swing lies inside with the rest of the range
shared out on both sides (the grid's peaks are within a
fraction of a percent of the true ones for up to 20 harmonics, so the true peaks stay within the limits).

The cost is log10 of the regressor's condition number over SAMPLES samples of one period, plus a
penalty of 100 per metre that the clearance falls short of `min_clearance` at any of them. The condition
number is the plain one (`normalised=False`, the default) or that of the regressor with every column
scaled to unit norm (`normalised=True`): the plain one has a floor set by the columns' physical scales
(a Coulomb column is at most 1, a gravity column several N m), the normalised one measures only how well
the samples separate the parameters, as the identification's own condition number does. The trajectory's
stored `condition_number` is the plain one either way; `DesignResult.criterion` is the optimised value.
The start is seeded: q0 at the middle of each range (or `start`), the harmonics drawn at random; when it is
not clear, its harmonics halved until they are give a first clear trajectory to fall back on.
scipy.optimize.minimize (Powell: derivative-free, the clip and scale make the cost only piecewise
smooth) runs from the start until `evaluations` cost evaluations or `seconds` have passed; the best
trajectory whose clearance held is the result. `progress` gets a line every `progress_every` evaluations.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from crane_io.errors import ConfigError
from crane_io.physics.excitation_trajectory import FourierTrajectory, regressor_condition

GRID = 256  # samples per period for the limits
SAMPLES = 60  # samples per period for the condition number
PENALTY = 100.0  # cost per metre of missing clearance
_SHRINK_STEPS = 8  # halvings of the starting harmonics until the start is clear
GRID_FILL = 0.99  # the grid's peaks fill this fraction of each limit (the true peaks lie between samples)


@dataclass(frozen=True)
class DesignSpace:
    """Joints, their limits (rad, rad/s, rad/s^2; each (J,)) and the series' period (s) and harmonics."""

    joints: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    vmax: np.ndarray
    amax: np.ndarray
    period: float = 10.0
    harmonics: int = 5
    min_clearance: float = 0.02  # m

    def __post_init__(self):
        n = len(self.joints)
        for name in ("lower", "upper", "vmax", "amax"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (n,) or not np.all(np.isfinite(v)):
                raise ConfigError(f"`{name}` needs {n} finite numbers, one per joint")
        if not np.all(np.asarray(self.upper) > np.asarray(self.lower)):
            raise ConfigError("every joint's `upper` limit must lie above its `lower` one")
        if not (np.all(np.asarray(self.vmax) > 0) and np.all(np.asarray(self.amax) > 0)):
            raise ConfigError("`vmax` and `amax` must be positive")
        if not (math.isfinite(self.period) and self.period > 0):
            raise ConfigError(f"`period` must be a positive number of seconds, got {self.period}")
        if not (isinstance(self.harmonics, int) and 2 <= self.harmonics <= 20):
            raise ConfigError(f"`harmonics` must be a whole number from 2 to 20, got {self.harmonics}")

    @property
    def w_f(self) -> float:
        return 2.0 * math.pi / self.period

    @property
    def size(self) -> int:
        """The number of variables."""
        return len(self.joints) * (1 + 2 * (self.harmonics - 1))


def _coefficients(x: np.ndarray, space: DesignSpace) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q0 (J,), a (J, L), b (J, L)) of the variables, the first harmonic from the rest (at rest)."""
    n, L = len(space.joints), space.harmonics
    x = np.asarray(x, dtype=float).reshape(n, 1 + 2 * (L - 1))
    q0 = x[:, 0].copy()
    a = np.zeros((n, L))
    b = np.zeros((n, L))
    a[:, 1:], b[:, 1:] = x[:, 1:L], x[:, L:]
    a[:, 0] = -a[:, 1:].sum(axis=1)
    b[:, 0] = -(b[:, 1:] @ np.arange(2, L + 1))
    return q0, a, b


def trajectory(x: np.ndarray, space: DesignSpace, periods: int = 1) -> FourierTrajectory:
    """The trajectory of the variables x, brought within the limits (the module docstring)."""
    q0, a, b = _coefficients(x, space)
    base = FourierTrajectory(space.joints, space.w_f, np.zeros_like(q0), a, b)
    t = np.linspace(0.0, space.period, GRID, endpoint=False)
    p, dq, ddq = base.evaluate(t)
    swing = p.max(axis=0) - p.min(axis=0)
    span = space.upper - space.lower
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = GRID_FILL * np.stack([space.vmax / np.abs(dq).max(axis=0),
                                       space.amax / np.abs(ddq).max(axis=0), span / swing])
    scale = np.minimum(1.0, np.nan_to_num(ratios, nan=1.0, posinf=1.0).min(axis=0))
    room = 0.5 * (1.0 - GRID_FILL) * span  # what the swing leaves free on each side, for the true peaks
    lo = space.lower + room - scale * p.min(axis=0)
    hi = space.upper - room - scale * p.max(axis=0)
    q0 = np.clip(q0, lo, np.maximum(lo, hi))
    return FourierTrajectory(space.joints, space.w_f, q0, a * scale[:, None], b * scale[:, None], periods)


def initial(space: DesignSpace, seed: int, start: np.ndarray | None = None) -> np.ndarray:
    """Seeded starting variables: q0 at `start` (default the middle of each range), small harmonics."""
    rng = np.random.default_rng(seed)
    n, L = len(space.joints), space.harmonics
    x = rng.normal(0.0, 0.3, size=(n, 1 + 2 * (L - 1)))
    x[:, 0] = 0.5 * (space.lower + space.upper) if start is None else np.asarray(start, dtype=float)
    return x.ravel()


def variables(traj: FourierTrajectory) -> np.ndarray:
    """The variables of a trajectory that starts at rest (the inverse of `trajectory` within limits)."""
    return np.concatenate([traj.q0[:, None], traj.a[:, 1:], traj.b[:, 1:]], axis=1).ravel()


@dataclass
class DesignResult:
    trajectory: FourierTrajectory  # the best one found, its condition number set
    initial_condition: float  # the starting trajectory's condition number
    evaluations: int
    seconds: float
    clearance: float  # m: the smallest clearance over the samples
    criterion: float  # the optimised condition number (plain or normalised) of the result


class _Budget(Exception):
    """The optimiser's budget ran out."""


class _Cost:
    """The cost of the module docstring, keeping the best trajectory whose clearance held."""

    def __init__(self, space, dynamics, clearance, evaluations, seconds, progress, progress_every,
                 normalised=False):
        self.space, self.dynamics, self.clear = space, dynamics, clearance
        self.normalised = normalised
        self.t = np.linspace(0.0, space.period, SAMPLES, endpoint=False)
        self.max_evaluations, self.seconds = evaluations, seconds
        self.progress, self.every = progress, progress_every
        self.count = 0
        self.t0 = time.perf_counter()
        self.best: tuple[float, FourierTrajectory, float] | None = None  # (cond, trajectory, clearance)
        self.best_cost = math.inf

    def measure(self, traj: FourierTrajectory, normalised: bool | None = None) -> tuple[float, float]:
        """(condition number, smallest clearance) over the samples; the condition number of the cost's
        definition unless `normalised` is given."""
        q, dq, ddq = traj.evaluate(self.t)
        norm = self.normalised if normalised is None else normalised
        return regressor_condition(self.dynamics, q, dq, ddq, norm), float(np.min(self.clear.clearance(q)))

    def __call__(self, x: np.ndarray) -> float:
        if self.count >= self.max_evaluations or (
                self.seconds is not None and time.perf_counter() - self.t0 > self.seconds):
            raise _Budget
        self.count += 1
        traj = trajectory(x, self.space)
        cond, margin = self.measure(traj)
        short = max(0.0, self.space.min_clearance - margin)
        cost = math.log10(cond) + PENALTY * short if math.isfinite(cond) else 1e6
        if short == 0.0 and (self.best is None or cond < self.best[0]):
            self.best = (cond, traj, margin)
        self.best_cost = min(self.best_cost, cost)
        if self.progress is not None and self.count % self.every == 0:
            best = f"{self.best[0]:.1f}" if self.best is not None else "none clear yet"
            self.progress(f"evaluation {self.count}: best condition number {best} "
                          f"({time.perf_counter() - self.t0:.0f} s)")
        return cost


def optimise(space: DesignSpace, dynamics, clearance, *, seed: int = 0, evaluations: int = 400,
             seconds: float | None = None, start: np.ndarray | None = None,
             progress: Callable[[str], None] | None = None, progress_every: int = 50,
             normalised: bool = False) -> DesignResult:
    """The best trajectory found within the budget (the module docstring). `dynamics`: an ArmDynamics
    over `space.joints`; `clearance`: an ArmClearance over them; `normalised`: minimise the condition
    number of the unit-column-norm regressor. ConfigError when no trajectory clear of the table and the
    arm's links was found."""
    if evaluations < 1:
        raise ConfigError(f"the optimiser's budget must be at least 1 evaluation, got {evaluations}")
    cost = _Cost(space, dynamics, clearance, evaluations, seconds, progress, max(1, progress_every),
                 normalised)
    x0 = initial(space, seed, start)
    first_cond = cost.measure(trajectory(x0, space), normalised=False)[0]
    margin = cost.measure(trajectory(x0, space))[1]
    try:
        if margin < space.min_clearance:  # a fallback clear of the table and the links: smaller swings
            fallback = x0.reshape(len(space.joints), -1).copy()
            for _ in range(_SHRINK_STEPS):
                fallback[:, 1:] *= 0.5
                if cost.measure(trajectory(fallback.ravel(), space))[1] >= space.min_clearance:
                    cost(fallback.ravel())
                    break
        minimize(cost, x0, method="Powell", options={"maxfev": evaluations, "xtol": 1e-4, "ftol": 1e-6})
    except _Budget:
        pass
    if cost.best is None:
        raise ConfigError("no trajectory clear of the table and the arm's own links was found within the "
                          "optimiser's budget; give a larger `budget`, another `seed` or other joints")
    cond, traj, margin = cost.best
    plain = cost.measure(traj, normalised=False)[0] if normalised else cond
    return DesignResult(traj.with_condition(plain), first_cond, cost.count, time.perf_counter() - cost.t0,
                        margin, cond)
