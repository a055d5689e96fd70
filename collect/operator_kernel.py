"""The simulated operator's hand (collect/operator.py) per joint, defined once and run two ways.

`min_jerk` (the normalised minimum-jerk profile) and `hand_torque` (one joint's impedance torque on its
move) are plain Python: the operator's numpy profile calls `min_jerk` on arrays, its reference backend
(collect/operator.py `PythonHand`) calls `hand_torque` on Python floats, and the compiled backend
`CompiledHand` here runs them compiled with numba through crane_io.jit (`hand`: no `fastmath`, the same
IEEE operations, so the same bits; tests/test_collect_scalar_paths.py). Both implement
collect/operator_layout.Hand; the compiled one takes the moves' rows as a (k, 5) array.

This module imports numpy, crane_io.jit (numba, when compiling) and its layout only.
"""

from __future__ import annotations

import numpy as np

from .operator_layout import MOVE_FIELDS, Hand


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
    """hand_torque of every move's joint into out (moves: (k, 5) rows (index, t0, T, a, d))."""
    for j in range(moves.shape[0]):
        i = int(moves[j, 0])
        out[i] = hand_torque(t, moves[j, 1], moves[j, 2], moves[j, 3], moves[j, 4], q[i], dq[i], k_p, k_d,
                             top)


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


_F64 = np.dtype(np.float64)


def _f64(x, n: int) -> np.ndarray:
    """x as `hand` takes it: (n,) float64, C-contiguous and writeable (x itself when it is one already)."""
    if not (type(x) is np.ndarray and x.dtype is _F64 and x.flags.carray):
        x = np.array(x, dtype=float)
    if x.shape != (n,):  # the compiled code does not check its indices
        raise ValueError(f"the hand takes the arm's {n} joint angles and velocities, not {x.shape}")
    return x


class CompiledHand(Hand):
    """The compiled backend: `fn`, compiled()'s `hand`; the moves a (k, 5) array."""

    compiled = True

    def __init__(self, fn, n: int, stiffness: float, damping: float, max_torque: float):
        super().__init__(n, stiffness, damping, max_torque)
        self._fn = fn

    def moves(self, rows: list) -> np.ndarray:
        return np.array(rows, dtype=float).reshape(len(rows), len(MOVE_FIELDS))

    def torque(self, t: float, moves: np.ndarray, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        out = np.zeros(self.n)
        n = self.n
        self._fn(float(t), moves, _f64(q, n), _f64(dq, n), *self._gains, out)
        return out
