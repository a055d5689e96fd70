"""An exciting trajectory for identification: a finite Fourier series per joint (Swevers et al.), its
file, and the condition number of the identification regressor over any motion.

Per joint j, with the fundamental angular frequency w_f and L harmonics:

    q_j(t)   = q0_j + sum_l [ a_jl / (w_f l) sin(w_f l t) - b_jl / (w_f l) cos(w_f l t) ]
    dq_j(t)  = sum_l [ a_jl cos(w_f l t) + b_jl sin(w_f l t) ]
    ddq_j(t) = sum_l [ -a_jl w_f l sin(w_f l t) + b_jl w_f l cos(w_f l t) ]

The series is periodic with period 2 pi / w_f. `FourierTrajectory.at_rest()` says whether it starts
(and so ends each period) at rest, dq = ddq = 0: sum_l a_jl = 0 and sum_l l b_jl = 0 for every joint
(crane_io/physics/excitation_design.py builds only such trajectories).

A run plays `periods` periods one after another, period k at the speed scale s = speeds[k % len(speeds)]
(0 < s <= 1): the same path in 1/s times the time, q(s t), s dq(s t), s^2 ddq(s t) (`play`). Every
period starts and ends at rest at the same pose, so the periods join smoothly whatever their speeds, and
a slower period stays within every limit the full-speed one keeps. Different speeds put the same path
through other velocities (low speeds and slow reversals, where friction shows) and other accelerations,
so an error locked to one period's phase differs from period to period.

The identification regressor (`identification_regressor`) is the base-parameter regressor of
crane_io.physics.dynamics (`ArmDynamics.base_regressor`) with two friction columns per joint: viscous
dq_j and Coulomb tanh(dq_j / COULOMB_SMOOTHING) (the smooth sign of crane_io/physics/effects), each
in its joint's row only. `regressor_condition` is the 2-norm condition number of it stacked over
the samples.

The file is JSON (`save`, `load`): data only, checked on loading, never code. Keys: format, version,
joints, w_f (rad/s), q0 (J,) rad, a and b (J, L) rad/s, periods, speeds (the speed cycle, each in
(0, 1]), condition_number. A version-1 file has no `speeds` (every period at full speed).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from crane_io.errors import ConfigError

FORMAT = "crane-excitation-trajectory"
VERSION = 2
VERSIONS = (1, 2)  # the versions read: 1 has no `speeds`
COULOMB_SMOOTHING = 0.05  # rad/s: the Coulomb column is tanh(dq / this)
_KEYS = ("format", "version", "joints", "w_f", "q0", "a", "b", "periods", "speeds", "condition_number")
_MAX_HARMONICS = 50


@dataclass(frozen=True, eq=False)
class FourierTrajectory:
    """The series of the module docstring over `joints` (names, in the order of the rows of a, b). Two are
    equal when they describe the same motion (joints, w_f, q0, a, b, periods; not the condition number)."""

    joints: tuple[str, ...]
    w_f: float  # rad/s, the fundamental angular frequency
    q0: np.ndarray  # (J,) rad
    a: np.ndarray  # (J, L) rad/s
    b: np.ndarray  # (J, L) rad/s
    periods: int = 1  # how many periods a run plays
    condition_number: float = field(default=float("nan"), compare=False)
    speeds: tuple[float, ...] = (1.0,)  # the speed scale of period k is speeds[k % len(speeds)]

    def __eq__(self, other) -> bool:
        if not isinstance(other, FourierTrajectory):
            return NotImplemented
        return (self.joints == other.joints and self.w_f == other.w_f and self.periods == other.periods
                and tuple(self.speeds) == tuple(other.speeds)
                and all(np.array_equal(x, y) for x, y in ((self.q0, other.q0), (self.a, other.a),
                                                          (self.b, other.b))))

    __hash__ = None

    @property
    def period(self) -> float:
        """s: one period of the series."""
        return 2.0 * math.pi / self.w_f

    @property
    def duration(self) -> float:
        """s: the periods a run plays, each at its speed."""
        return float(self.period_starts()[-1])

    def period_speeds(self) -> np.ndarray:
        """(periods,) the speed scale of each period a run plays."""
        return np.array([self.speeds[k % len(self.speeds)] for k in range(self.periods)], dtype=float)

    def period_starts(self) -> np.ndarray:
        """(periods + 1,) s: the run time each period starts at, and the end of the run."""
        return np.concatenate([[0.0], np.cumsum(self.period / self.period_speeds())])

    def periods_within(self, duration: float) -> int:
        """The number of periods (at least 1) of the speed cycle whose run time is closest to `duration`."""
        lengths = self.period / np.array([self.speeds[k % len(self.speeds)]
                                          for k in range(max(1, int(duration / self.period) + 1))])
        ends = np.cumsum(lengths)
        return int(np.argmin(np.abs(ends - duration))) + 1

    def play(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, dq, ddq) at run time t (s) of the periods at their speeds (the module docstring); shapes as
        `evaluate`. Past the end: the pose the last period ends at, at rest."""
        t_arr = np.asarray(t, dtype=float)
        tt = np.atleast_1d(t_arr)
        starts = self.period_starts()
        k = np.clip(np.searchsorted(starts, tt, side="right") - 1, 0, self.periods - 1)
        s = self.period_speeds()[k]
        local = np.clip((tt - starts[k]) * s, 0.0, self.period)
        q, dq, ddq = self.evaluate(local)
        dq, ddq = dq * s[:, None], ddq * (s * s)[:, None]
        if t_arr.ndim == 0:
            return q[0], dq[0], ddq[0]
        return q, dq, ddq

    @property
    def harmonics(self) -> int:
        return int(self.a.shape[1])

    def at_rest(self, tol: float = 1e-9) -> bool:
        """Whether dq = ddq = 0 at t = 0 (and so at every whole period)."""
        l_ = np.arange(1, self.harmonics + 1)
        return bool(np.all(np.abs(self.a.sum(axis=1)) <= tol) and np.all(np.abs(self.b @ l_) <= tol))

    def evaluate(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, dq, ddq) at times t (s): (N, J) each for (N,) times, (J,) for one time."""
        t_arr = np.asarray(t, dtype=float)
        single = t_arr.ndim == 0
        tt = np.atleast_1d(t_arr)
        wl = self.w_f * np.arange(1, self.harmonics + 1)  # (L,)
        s, c = np.sin(np.outer(tt, wl)), np.cos(np.outer(tt, wl))  # (N, L)
        a, b = self.a, self.b
        q = self.q0 + s @ (a / wl).T - c @ (b / wl).T
        dq = c @ a.T + s @ b.T
        ddq = -s @ (a * wl).T + c @ (b * wl).T
        if single:
            return q[0], dq[0], ddq[0]
        return q, dq, ddq

    def start(self) -> np.ndarray:
        """(J,) rad: the pose at t = 0."""
        return self.evaluate(0.0)[0]

    def with_condition(self, cond: float) -> FourierTrajectory:
        return FourierTrajectory(self.joints, self.w_f, self.q0, self.a, self.b, self.periods, float(cond),
                                 self.speeds)

    def with_periods(self, periods: int, speeds: tuple[float, ...] | None = None) -> FourierTrajectory:
        """The same series played `periods` times (cycling through `speeds`, default its own)."""
        speeds = self.speeds if speeds is None else _speeds(list(speeds), "the trajectory")
        return FourierTrajectory(self.joints, self.w_f, self.q0, self.a, self.b, int(periods),
                                 self.condition_number, tuple(speeds))

    # -- the file ---------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {"format": FORMAT, "version": VERSION, "joints": list(self.joints), "w_f": float(self.w_f),
                "q0": [float(x) for x in self.q0], "a": np.asarray(self.a, float).tolist(),
                "b": np.asarray(self.b, float).tolist(), "periods": int(self.periods),
                "speeds": [float(x) for x in self.speeds], "condition_number": float(self.condition_number)}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1) + "\n"


def from_dict(d, where: str = "the trajectory") -> FourierTrajectory:
    """The trajectory a file's content describes; ConfigError (one sentence naming `where`) otherwise."""
    if not isinstance(d, dict) or d.get("format") != FORMAT:
        raise ConfigError(f"{where} is not an excitation trajectory (its format is not {FORMAT!r})")
    if d.get("version") not in VERSIONS:
        raise ConfigError(f"{where} has version {d.get('version')!r}; this toolkit reads versions "
                          f"{' and '.join(str(v) for v in VERSIONS)}")
    keys = _KEYS if d["version"] == VERSION else tuple(k for k in _KEYS if k != "speeds")
    unknown = sorted(set(d) - set(keys))
    missing = [k for k in keys if k not in d]
    if unknown or missing:
        what = f"unknown key {unknown[0]!r}" if unknown else f"no {missing[0]!r}"
        raise ConfigError(f"{where} has {what}")
    joints = d["joints"]
    if not (isinstance(joints, list) and joints and all(isinstance(j, str) for j in joints)
            and len(set(joints)) == len(joints)):
        raise ConfigError(f"{where} needs `joints` as a list of different joint names")
    n = len(joints)
    w_f = _number(d["w_f"], where, "w_f")
    if not w_f > 0:
        raise ConfigError(f"{where} needs a positive `w_f` (rad/s), got {w_f}")
    q0 = _array(d["q0"], (n,), where, "q0")
    a = _array(d["a"], None, where, "a")
    b = _array(d["b"], a.shape, where, "b")
    if a.ndim != 2 or a.shape[0] != n or not 1 <= a.shape[1] <= _MAX_HARMONICS:
        raise ConfigError(f"{where} needs `a` and `b` as {n} rows of 1 to {_MAX_HARMONICS} harmonics")
    periods = d["periods"]
    if not (isinstance(periods, int) and not isinstance(periods, bool) and periods >= 1):
        raise ConfigError(f"{where} needs `periods` as a whole number of at least 1, got {periods!r}")
    cond = d["condition_number"]
    cond = float("nan") if cond is None else _number(cond, where, "condition_number", finite=False)
    speeds = _speeds(d.get("speeds", [1.0]), where)
    return FourierTrajectory(tuple(joints), w_f, q0, a, b, periods, cond, speeds)


def _speeds(x, where: str) -> tuple[float, ...]:
    ok = isinstance(x, list) and 1 <= len(x) <= _MAX_HARMONICS and all(
        not isinstance(v, bool) and isinstance(v, (int, float)) and 0.0 < v <= 1.0 for v in x)
    if not ok:
        raise ConfigError(f"{where} needs `speeds` as a list of 1 to {_MAX_HARMONICS} speed scales, each "
                          f"above 0 and at most 1")
    return tuple(float(v) for v in x)


def _number(x, where: str, key: str, finite: bool = True) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)) or (finite and not math.isfinite(x)):
        raise ConfigError(f"{where} needs `{key}` as a finite number, got {x!r}")
    return float(x)


def _array(x, shape, where: str, key: str) -> np.ndarray:
    try:
        arr = np.array(x, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"{where} needs `{key}` as numbers") from None
    if (shape is not None and arr.shape != tuple(shape)) or not np.all(np.isfinite(arr)):
        want = f"{shape[0]} finite numbers" if shape is not None and len(shape) == 1 else "finite numbers"
        raise ConfigError(f"{where} needs `{key}` as {want} of the right shape")
    return arr


def save(traj: FourierTrajectory, path) -> Path:
    """Write the trajectory's JSON file atomically."""
    from crane_io.output_files import write_text_atomic

    return write_text_atomic(path, traj.to_json(), what="trajectory file")


def load(path) -> FourierTrajectory:
    """Read and check a trajectory file (ConfigError in one sentence when it is not one)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"trajectory file {p} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"trajectory file {p} cannot be read ({getattr(exc, 'strerror', None) or exc})"
                          ) from None
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"trajectory file {p} is not JSON (line {exc.lineno}: {exc.msg})") from None
    return from_dict(d, f"trajectory file {p}")


# -- the identification regressor -----------------------------------------------------------------------
def friction_columns(dq: np.ndarray) -> np.ndarray:
    """(N, J, 2J): viscous dq_j and Coulomb tanh(dq_j / COULOMB_SMOOTHING) in joint j's row."""
    dq = np.atleast_2d(np.asarray(dq, dtype=float))
    n, j = dq.shape
    out = np.zeros((n, j, 2 * j))
    idx = np.arange(j)
    out[:, idx, idx] = dq
    out[:, idx, j + idx] = np.tanh(dq / COULOMB_SMOOTHING)
    return out


def identification_regressor(dynamics, q, dq, ddq) -> np.ndarray:
    """(N J, B + 2J): base regressor plus friction columns, stacked over the samples."""
    w = np.concatenate([dynamics.base_regressor(q, dq, ddq), friction_columns(dq)], axis=2)
    return w.reshape(-1, w.shape[2])


def regressor_condition(dynamics, q, dq, ddq, normalised: bool = False) -> float:
    """The 2-norm condition number of `identification_regressor` (inf when it is rank-deficient);
    `normalised`: of the regressor with every column scaled to unit norm (free of the parameters' units)."""
    w = identification_regressor(dynamics, q, dq, ddq)
    if normalised:
        norms = np.linalg.norm(w, axis=0)
        w = w / np.where(norms > 0, norms, 1.0)
    s = np.linalg.svd(w, compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")


def recording_condition(dynamics, q, rate_hz: float, every: int = 10, window_s: float = 0.1,
                        normalised: bool = False) -> float:
    """`regressor_condition` over a recording of angles q (N, J) sampled at `rate_hz`: dq and ddq from a
    Savitzky-Golay filter (cubic, `window_s` long) of q, then every `every`-th sample."""
    from scipy.signal import savgol_filter

    q = np.asarray(q, dtype=float)
    dt = 1.0 / rate_hz
    window = max(5, int(round(window_s * rate_hz)) | 1)
    if len(q) < window:
        raise ConfigError(f"a recording of {len(q)} samples is shorter than the {window}-sample filter")
    dq = savgol_filter(q, window, 3, deriv=1, delta=dt, axis=0)
    ddq = savgol_filter(q, window, 3, deriv=2, delta=dt, axis=0)
    return regressor_condition(dynamics, q[::every], dq[::every], ddq[::every], normalised)
