"""The cross-validation behind the diagnosis (train/diagnosis/diagnose.py, steps 2-4): contiguous time-block
folds, per-fold normal equations of the masked least-squares problem, the cross-validated fit of one candidate
over its shape grid, its held-out error reductions, and the jackknife uncertainty of its parameters."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..evaluation.block_uncertainty import jackknife_values, t_factor
from .effects import named_values

if TYPE_CHECKING:
    from collections.abc import Callable, Container, Sequence
    from typing import Any


def fold_ids(n: int, folds: int) -> np.ndarray:
    """(n,) fold index of each row: `folds` contiguous blocks of (nearly) equal size."""
    return np.minimum((np.arange(n) * folds) // max(n, 1), folds - 1)


def sparse_joint(moving: np.ndarray, fold: np.ndarray, folds: int, joint_names: Sequence[str],
                 min_samples: int = 50) -> str | None:
    """The first joint whose moving samples are too few (fewer than max(min_samples, 5 folds)) or missing
    from a fold, as the sentence's middle ("joint2 moves in only 40 samples (or not in every part of the
    recording)" and what is needed), or None when every joint has enough in every fold."""
    need = max(min_samples, 5 * folds)
    for j, name in enumerate(joint_names):
        per_fold = np.bincount(fold[moving[:, j]], minlength=folds)
        if per_fold.sum() < need or per_fold.min() == 0:
            return (f"{name} moves in only {int(per_fold.sum())} samples (or not in every part of the "
                    f"recording); {{what}} needs at least {need} spread over the whole recording")
    return None


def jackknife(per_fold: list[dict[str, float]]) -> dict[str, tuple[float, float]]:
    """name -> (mean over folds, delete-a-block jackknife standard error) of the per-fold values (each
    fold's fit leaves one contiguous time block out; train.evaluation.block_uncertainty)."""
    return jackknife_values(per_fold)


def interval_factor(folds: int) -> float:
    """The half-width of a 95 % interval in jackknife standard errors over `folds` blocks (Student's t
    with folds - 1 degrees of freedom: 2.78 at 5 folds)."""
    return t_factor(folds) if folds >= 2 else float("nan")


def interval(value: float, std: float, factor: float) -> list[float]:
    """[low, high] of value +- factor x std."""
    return [float(value - factor * std), float(value + factor * std)]


class Engine:
    """Per-fold normal equations of the masked least-squares problem, so that a candidate's fit on the
    training folds is a small linear solve.

    basis X (N, J, p) (may have p = 0), target y (N, J), weights W (N, J) (the moving masks), fold (N,).
    Columns are scaled to unit RMS over the weighted rows; a tiny ridge keeps rank-deficient problems
    solvable (base parameters the data barely excite).
    """

    RIDGE = 1e-8

    def __init__(self, X: np.ndarray, y: np.ndarray, W: np.ndarray, fold: np.ndarray, folds: int):
        self.X, self.y, self.W, self.fold, self.K = X, y, W.astype(float), fold, folds
        self.p = X.shape[2]
        self.sx = self._scale(X)
        self.Xs = X / self.sx
        self.masks = [self.W * (fold == k)[:, None] for k in range(folds)]  # (N, J) per fold
        n, j = y.shape
        if len(fold) and np.all(np.diff(fold) >= 0):  # contiguous blocks (fold_ids): slices of the rows
            edges = np.searchsorted(fold, np.arange(folds + 1))
            self._slices = [slice(int(edges[k]) * j, int(edges[k + 1]) * j) for k in range(folds)]
        else:
            self._slices = None
        wf = self.W.reshape(n * j)
        self._wk = np.stack(self.masks).reshape(folds, n * j)  # (K, NJ) weights of each fold
        self._xf = self.Xs.reshape(n * j, self.p)
        self._yf = y.reshape(n * j)
        self._wxf = wf[:, None] * self._xf  # (NJ, p) weighted basis
        self._wyf = wf * self._yf
        self.XX = np.stack([self._part(self._wxf, k).T @ self._part(self._xf, k) for k in range(folds)])
        self.Xy = np.stack([self._part(self._wxf, k).T @ self._part(self._yf, k) for k in range(folds)])
        self.yy = np.array([float(self._part(self._wyf, k) @ self._part(self._yf, k)) for k in range(folds)])
        self._cache: dict[int, tuple] = {}  # id(C) -> (C, scale, per-fold XC, CC, Cy)
        # per joint, its rows alone (contiguous copies): most candidates act on one joint, and their
        # cross products then need only that joint's rows (the others add exact zeros)
        if self._slices is not None:
            wx3 = self._wxf.reshape(n, j, self.p)
            self._by_joint = [(np.ascontiguousarray(wx3[:, i]), self.W[:, i].copy(),
                               np.ascontiguousarray(self._wyf.reshape(n, j)[:, i])) for i in range(j)]
            self._row_edges = [(int(edges[k]), int(edges[k + 1])) for k in range(folds)]

    def extended(self, C: np.ndarray) -> Engine:
        """The same problem with the columns C (N, J, c) added to the basis."""
        return Engine(np.concatenate([self.X, C], axis=2), self.y, self.W, self.fold, self.K)

    def _scale(self, A, squares=None):
        """Per column of A (N, J, c), its weighted RMS (1 where it is ~0). `squares`: _squares(A)."""
        sq = self._squares(A) if squares is None else squares
        s = np.sqrt(sq.sum(axis=0) / max(self.W.sum(), 1.0))
        return np.where(s > 1e-12, s, 1.0)

    def _squares(self, A):
        """(J, c): the weighted sum of squares of each column of A (N, J, c) on each joint's rows."""
        return np.einsum("nj,njc,njc->jc", self.W, A, A)

    def _solve(self, G, b):
        n = len(b)
        if n == 0:
            return np.zeros(0)
        lam = self.RIDGE * max(float(np.trace(G)) / n, 1e-12)
        try:
            return np.linalg.solve(G + lam * np.eye(n), b)
        except np.linalg.LinAlgError:
            return np.linalg.lstsq(G, b, rcond=None)[0]

    def fit(self, C: np.ndarray | None, train: list[int]) -> tuple[np.ndarray, np.ndarray, float]:
        """Least squares on the training folds; returns (theta_x, theta_c (unscaled), training SSE)."""
        XX, Xy, yy = self.XX[train].sum(0), self.Xy[train].sum(0), self.yy[train].sum()
        if C is None:
            th = self._solve(XX, Xy)
            sse = yy - 2 * th @ Xy + th @ XX @ th
            return th / self.sx, np.zeros(0), float(sse)
        sc, XCk, CCk, Cyk = self._stats(C)
        XC, CC, Cy = XCk[train].sum(0), CCk[train].sum(0), Cyk[train].sum(0)
        G = np.block([[XX, XC], [XC.T, CC]])
        b = np.concatenate([Xy, Cy])
        th = self._solve(G, b)
        sse = yy - 2 * th @ b + th @ G @ th
        return th[:self.p] / self.sx, th[self.p:] / sc, float(sse)

    def _part(self, a: np.ndarray, k: int) -> np.ndarray:
        """The rows of fold k of a flattened (NJ, ...) array (zero-weighted outside it when the folds are
        not contiguous)."""
        if self._slices is not None:
            return a[self._slices[k]]
        w = self._wk[k] > 0
        return a[w]

    def _stats(self, C: np.ndarray):
        """Per-fold cross products of the columns C with the basis, themselves and the target (cached
        for the last few C: a candidate's columns are fitted once per fold)."""
        hit = self._cache.get(id(C))
        if hit is not None and hit[0] is C:
            return hit[1:]
        squares = self._squares(C)
        sc = self._scale(C, squares)
        used = np.flatnonzero(squares.any(axis=1))  # the joints on whose weighted rows C is not zero
        if self._slices is not None and len(used) < C.shape[1]:
            stats = (sc, *self._stats_by_joint(C / sc, used))
        else:
            cf = (C / sc).reshape(-1, C.shape[2])
            parts = [self._part(cf, k) for k in range(self.K)]
            stats = (sc, np.stack([self._part(self._wxf, k).T @ c for k, c in enumerate(parts)]),
                     np.stack([(self._part(self._wk[k], k)[:, None] * c).T @ c for k, c in enumerate(parts)]),
                     np.stack([c.T @ self._part(self._wyf, k) for k, c in enumerate(parts)]))
        if len(self._cache) > 64:
            self._cache.clear()
        self._cache[id(C)] = (C, *stats)
        return stats

    def _stats_by_joint(self, Cs: np.ndarray, used: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """_stats' per-fold cross products of the scaled columns Cs from the rows of the joints `used`
        only (Cs is zero on every other joint's rows; contiguous folds)."""
        c = Cs.shape[2]
        XC, CC, Cy = np.zeros((self.K, self.p, c)), np.zeros((self.K, c, c)), np.zeros((self.K, c))
        for i in used:
            wx, w, wy = self._by_joint[i]
            ci = np.ascontiguousarray(Cs[:, i])
            for k, (a, b) in enumerate(self._row_edges):
                part = ci[a:b]
                XC[k] += wx[a:b].T @ part
                CC[k] += (w[a:b, None] * part).T @ part
                Cy[k] += part.T @ wy[a:b]
        return XC, CC, Cy

    def heldout_sse(self, C: np.ndarray | None, th_x: np.ndarray, th_c: np.ndarray | None,
                    k: int) -> np.ndarray:
        """(J,) SSE of the held-out fold k per joint (weighted rows only)."""
        pred = self.X @ th_x if self.p else np.zeros_like(self.y)
        if C is not None:
            pred = pred + C @ th_c
        return ((self.y - pred) ** 2 * self.masks[k]).sum(axis=0)

    def baseline(self) -> list[np.ndarray]:
        """Per fold k, the (J,) held-out SSE of the basis alone refitted on the other folds."""
        out = []
        for k in range(self.K):
            th_x, _, _ = self.fit(None, [i for i in range(self.K) if i != k])
            out.append(self.heldout_sse(None, th_x, None, k))
        return out


@dataclass
class CVFit:
    sse_before: np.ndarray  # (J, K) held-out SSE without the candidate, per joint and fold
    sse_after: np.ndarray  # (J, K) with the candidate
    count: np.ndarray  # (J,) held-out rows per joint
    fold_values: list[dict[str, float]]
    shape_all: dict | None
    shape_index: int = 0  # index into columns_by_shape of the grid point nearest shape_all
    columns_all: np.ndarray | None = None  # (N, J, c) the candidate's columns at shape_all (refined)
    identifiable: bool = True  # False: its columns lie in the span of the basis (see identifiability)
    collinear: tuple[str, ...] = ()  # linear coefficients that cannot be told apart from the others
    fold_shapes: list = field(default_factory=list)  # the shape each fold's fit used (refined)

    def reduction(self, joint: int) -> float:
        """Fraction of the held-out SSE on `joint` (all folds) the candidate removes."""
        before = self.sse_before[joint].sum()
        return 0.0 if before == 0 else float(1.0 - self.sse_after[joint].sum() / before)

    def fold_reductions(self, joint: int) -> list[float]:
        """The same, per fold."""
        return [float(1 - a / b) if b > 0 else 0.0
                for a, b in zip(self.sse_after[joint], self.sse_before[joint])]


REFINE_TOL = 5e-3  # relative tolerance (of the bracket) of the shape refinement


def _bracket(grid: list[float], value: float) -> tuple[float, float]:
    """Half-way to the neighbouring grid points on each side of `value` (half a step beyond the ends):
    the grid does the coarse search, the refinement never jumps to another grid point's basin."""
    g = sorted(set(float(x) for x in grid))
    if len(g) < 2:
        d = max(abs(value) * 0.5, 1e-3)
        return value - d, value + d
    i = int(np.argmin([abs(x - value) for x in g]))
    lo = g[i] - (g[i] - g[i - 1]) / 2 if i > 0 else g[0] - (g[1] - g[0]) / 2
    hi = g[i] + (g[i + 1] - g[i]) / 2 if i < len(g) - 1 else g[-1] + (g[-1] - g[-2]) / 2
    return lo, hi


def _shape_objective(engine: Engine, columns_at, base: dict, name: str, train: list[int]):
    """Training SSE as a function of one shape parameter (the others at `base`)."""
    def objective(v):
        C = columns_at({**base, name: float(v)})
        return np.inf if C is None else engine.fit(C, train)[2]

    return objective


def refine_shape(engine: Engine, columns_at: Callable[[dict], np.ndarray | None] | None,
                 grid: dict[str, list],
                 shape: dict | None, train: list[int], sse: float, integers: Container[str] = ()
                 ) -> tuple[dict | None, np.ndarray | None, float]:
    """Refine the shape parameters picked from the grid (bounded scalar search per parameter, scipy's
    minimize_scalar, within half a grid step of the pick; over the whole numbers there for the names in
    `integers`) on the training folds `train`; returns
    (shape, columns, training SSE), the grid pick itself when nothing better is found.
    `columns_at(shape)` -> (N, J, c) columns or None when the shape gives unusable columns."""
    if not shape or columns_at is None:
        return shape, None, sse
    from scipy.optimize import minimize_scalar

    best_shape, best_cols, best_sse = dict(shape), None, sse
    for name in list(shape):
        if name not in grid:
            continue
        lo, hi = _bracket(list(grid[name]), float(best_shape[name]))
        if not hi > lo:
            continue
        if name in integers:  # whole numbers only: try each one in the bracket
            objective = _shape_objective(engine, columns_at, dict(best_shape), name, train)
            for v in range(math.ceil(lo), math.floor(hi) + 1):
                f = objective(float(v))
                if np.isfinite(f) and f < best_sse:
                    best_shape, best_sse = {**best_shape, name: float(v)}, float(f)
                    best_cols = columns_at(best_shape)
            continue

        objective = _shape_objective(engine, columns_at, dict(best_shape), name, train)
        res = minimize_scalar(objective, bounds=(lo, hi), method="bounded",
                              options={"xatol": REFINE_TOL * (hi - lo)})
        if np.isfinite(res.fun) and res.fun < best_sse:
            best_shape = {**best_shape, name: float(res.x)}
            best_sse = float(res.fun)
            best_cols = columns_at(best_shape)
    return best_shape, best_cols, best_sse


def cross_validate(engine: Engine, effect: Any,
                   columns_by_shape: Sequence[tuple[dict | None, np.ndarray]],
                   baseline: Sequence[np.ndarray],
                   columns_at: Callable[[dict], np.ndarray | None] | None = None) -> CVFit:
    """Fit the candidate (its columns per shape, see train.diagnosis.effects.candidate_columns) on every K-1
    folds, keeping the grid shape that fits the training folds best and refining it there
    (`refine_shape`, when `columns_at` is given), and predict the held-out fold.
    baseline[k] = (J,) held-out SSE of the refit without candidate for fold k (Engine.baseline).
    The per-fold values (refined shapes included) feed the jackknife, so a shape parameter's
    uncertainty includes its refinement."""
    K = engine.K
    J = engine.y.shape[1]
    grid = dict(getattr(effect, "shape_grid", None) or {})
    integers = tuple(getattr(effect, "integer_shapes", ()) or ())
    sse_before = np.zeros((J, K))
    sse_after = np.zeros((J, K))
    fold_values, fold_shapes = [], []

    def best_fit(train):
        best = None
        for i, (shape, C) in enumerate(columns_by_shape):
            th_x, th_c, sse = engine.fit(C, train)
            if best is None or sse < best[0]:
                best = (sse, i, shape, C)
        sse, i, shape, C = best
        shape2, C2, _ = refine_shape(engine, columns_at, grid, shape, train, sse, integers)
        if C2 is not None:
            shape, C = shape2, C2
        return i, shape, C

    for k in range(K):
        train = [i for i in range(K) if i != k]
        _, shape, C = best_fit(train)
        th_x, th_c, _ = engine.fit(C, train)
        fold_values.append(named_values(effect, th_c, shape))
        fold_shapes.append(shape)
        sse_before[:, k] = baseline[k]
        sse_after[:, k] = engine.heldout_sse(C, th_x, th_c, k)
    count = engine.W.sum(axis=0)
    index, shape_all, C_all = best_fit(list(range(K)))
    identifiable, collinear = identifiability(engine, C_all, effect)
    return CVFit(sse_before, sse_after, count, fold_values, shape_all, index, C_all,
                 identifiable=identifiable, collinear=collinear, fold_shapes=fold_shapes)


IDENTIFIABLE_TOL = 1e-3  # a column whose part outside the span is below 0.1 % of its size: absorbed


def _outside_share(G: np.ndarray, col: int, others: list[int]) -> float:
    """Relative size (squared) of column `col`'s part outside the span of `others`, from the Gram
    matrix G of the weighted rows."""
    if G[col, col] <= 0:
        return 0.0
    if not others:
        return 1.0
    Goo, goc = G[np.ix_(others, others)], G[others, col]
    coef = np.linalg.lstsq(Goo, goc, rcond=1e-12)[0]
    return float((G[col, col] - 2 * coef @ goc + coef @ Goo @ coef) / G[col, col])


def identifiability(engine: Engine, C: np.ndarray, effect: Any = None) -> tuple[bool, tuple[str, ...]]:
    """(identifiable, names of the linear coefficients that cannot be told apart) for candidate columns
    C on the judged rows. Not identifiable at all when every column lies in the span of the basis: the
    model's own parameters absorb the candidate (a payload against a fitted rigid-body model), any value
    fits as well and the error cannot fall. A single coefficient cannot be told apart when its column
    lies in the span of the basis and the candidate's other columns (asymmetric Coulomb on a model that
    has Coulomb: only the asymmetry is new)."""
    if C is None or C.shape[2] == 0:
        return True, ()
    W = engine.W
    A = np.concatenate([engine.Xs, C / engine._scale(C)], axis=2)
    flat = A.reshape(-1, A.shape[2])
    G = (W.reshape(-1, 1) * flat).T @ flat  # sum_nj W A_a A_b (a matrix product: ~8x faster than einsum)
    p, c = engine.p, C.shape[2]
    names = [q.name for q in getattr(effect, "linear_params", ())] if effect is not None else []
    tol = IDENTIFIABLE_TOL ** 2
    absorbed = all(_outside_share(G, p + i, list(range(p))) < tol for i in range(c))
    loose = [names[i] if i < len(names) else f"column {i}" for i in range(c)
             if _outside_share(G, p + i, [a for a in range(p + c) if a != p + i]) < tol]
    return not absorbed, tuple(loose)


def cv_columns(engine: Engine, C: np.ndarray, baseline: Sequence[np.ndarray]
               ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], np.ndarray]:
    """Cross-validate plain columns C (N, J, c) against the basis: (sse_before (J, K), sse_after (J, K),
    per-fold coefficients of C, coefficients of C on all folds)."""
    K, J = engine.K, engine.y.shape[1]
    before, after, coefs = np.zeros((J, K)), np.zeros((J, K)), []
    for k in range(K):
        train = [i for i in range(K) if i != k]
        th_x, th_c, _ = engine.fit(C, train)
        coefs.append(th_c)
        before[:, k] = baseline[k]
        after[:, k] = engine.heldout_sse(C, th_x, th_c, k)
    return before, after, coefs, engine.fit(C, list(range(K)))[1]
