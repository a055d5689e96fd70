"""The simulated operator's hand (collect/operator.py) per joint, defined once and run two ways.

`min_jerk` (the normalised minimum-jerk profile) and `hand_torque` (one joint's impedance torque on its
move) are plain Python: the operator's numpy profile calls `min_jerk` on arrays, the reference backend
`PythonHand` calls `hand_torque` on Python floats, and the compiled backend `CompiledHand` runs them
compiled with numba through crane_io.jit (`hand`: no `fastmath`, the same IEEE operations, so the same
bits; tests/test_collect_scalar_paths.py). Both backends take the moves as `torque` is given them:
rows (index, t0, T, a, b - a), one per bilateral joint (the columns `M_*`; no T is 0), in the form their
`moves` makes.
"""

from __future__ import annotations

import numpy as np

# the columns of a move's row: the joint's index in the arm, the move's start (s) and duration T (s), its
# start angle a and its length b - a (rad)
M_INDEX, M_T0, M_T, M_A, M_D = range(5)
N_MOVE = 5


def min_jerk(x):
    """(s, ds/dx) of the normalised minimum-jerk profile at x in [0, 1] (floats or arrays)."""
    x2 = x * x
    return x2 * x * (10.0 - 15.0 * x + 6.0 * x2), 30.0 * x2 * (1.0 - 2.0 * x + x2)


def hand_torque(t, t0, T, a, d, q, dq, k_p, k_d, top):
    """The hand's torque on one joint at time t: its reference on the move (t0, T, a, d) against its angle q
    and velocity dq, stiffness k_p, damping k_d, limited to +-top (the clamps keep a NaN, as np.clip)."""
    x = (t - t0) / T
    if 0.0 > x:
        x = 0.0
    if 1.0 < x:
        x = 1.0
    s, ds = min_jerk(x)
    tau = k_p * (a + d * s - q) + k_d * (d * ds / T - dq)
    if -top > tau:
        tau = -top
    if top < tau:
        tau = top
    return tau


def hand(t, moves, q, dq, k_p, k_d, top, out):
    """hand_torque of every move's joint into out (moves: (k, N_MOVE) rows)."""
    for j in range(moves.shape[0]):
        i = int(moves[j, M_INDEX])
        out[i] = hand_torque(t, moves[j, M_T0], moves[j, M_T], moves[j, M_A], moves[j, M_D], q[i], dq[i],
                             k_p, k_d, top)


_F = "float64[::1]"
SIGNATURES = {"hand": (f"void(float64, float64[:, ::1], {_F}, {_F}, float64, float64, float64, {_F})",)}
_COMPILED = None


def compiled():
    """`hand` compiled (or loaded from numba's cache) by crane_io.jit and closed to other argument types;
    None without numba."""
    global _COMPILED
    if _COMPILED is None:
        from crane_io.jit import compile_functions

        fns = compile_functions(globals(), ("min_jerk", "hand_torque", "hand"), SIGNATURES,
                                qualname_prefix="operator_kernel.")
        if fns is None:
            _COMPILED = False
        else:
            fns["hand"].disable_compile()
            _COMPILED = fns["hand"]
    return _COMPILED or None


class Hand:
    """The interface of the hand's backends: `moves(rows)` the moves (a list of rows (index, t0, T, a,
    b - a)) in the form `torque(t, moves, q, dq)` reads them, which gives the hand's torque (n,): on the
    moves' joints hand_torque of the arm's angles q (n,) and velocities dq (n,), 0 elsewhere."""

    compiled: bool

    def __init__(self, n: int, stiffness: float, damping: float, max_torque: float):
        self.n = n
        self._gains = (float(stiffness), float(damping), float(max_torque))

    def moves(self, rows: list):
        raise NotImplementedError

    def torque(self, t: float, moves, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        raise NotImplementedError


class PythonHand(Hand):
    """The reference backend: hand_torque in Python floats, joint by joint."""

    compiled = False

    def moves(self, rows: list) -> list:
        return rows

    def torque(self, t: float, moves: list, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        k_p, k_d, top = self._gains
        q, dq = q.tolist(), dq.tolist()
        out = [0.0] * self.n
        for i, t0, T, a, d in moves:
            out[i] = hand_torque(t, t0, T, a, d, q[i], dq[i], k_p, k_d, top)
        return np.array(out)


_F64 = np.dtype(np.float64)


def _f64(x, n: int) -> np.ndarray:
    """x as `hand` takes it: (n,) float64, C-contiguous and writeable (x itself when it is one already)."""
    if not (type(x) is np.ndarray and x.dtype is _F64 and x.flags.carray):
        x = np.array(x, dtype=float)
    if x.shape != (n,):  # the compiled code does not check its indices
        raise ValueError(f"the hand takes the arm's {n} joint angles and velocities, not {x.shape}")
    return x


class CompiledHand(Hand):
    """The compiled backend: `fn`, compiled()'s `hand`; the moves a (k, N_MOVE) array."""

    compiled = True

    def __init__(self, fn, n: int, stiffness: float, damping: float, max_torque: float):
        super().__init__(n, stiffness, damping, max_torque)
        self._fn = fn

    def moves(self, rows: list) -> np.ndarray:
        return np.array(rows, dtype=float).reshape(len(rows), N_MOVE)

    def torque(self, t: float, moves: np.ndarray, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        out = np.zeros(self.n)
        n = self.n
        self._fn(float(t), moves, _f64(q, n), _f64(dq, n), *self._gains, out)
        return out
