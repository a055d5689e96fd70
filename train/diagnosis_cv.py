"""The cross-validation behind the diagnosis (train/diagnose.py, steps 2-4): contiguous time-block folds,
per-fold normal equations of the masked least-squares problem, the cross-validated fit of one candidate
over its shape grid, its held-out error reductions, and the jackknife uncertainty of its parameters."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .diagnosis_effects import named_values


def fold_ids(n: int, folds: int) -> np.ndarray:
    """(n,) fold index of each row: `folds` contiguous blocks of (nearly) equal size."""
    return np.minimum((np.arange(n) * folds) // max(n, 1), folds - 1)


def jackknife(per_fold: list[dict[str, float]]) -> dict[str, tuple[float, float]]:
    """name -> (mean over folds, delete-a-block jackknife standard error) of the per-fold values."""
    names = [n for n in per_fold[0] if all(n in v for v in per_fold)]
    k = len(per_fold)
    out = {}
    for name in names:
        v = np.array([f[name] for f in per_fold], dtype=float)
        out[name] = (float(v.mean()), float(math.sqrt((k - 1) / k * ((v - v.mean()) ** 2).sum())))
    return out


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
        self.XX = np.stack([np.einsum("nj,nja,njb->ab", m, self.Xs, self.Xs) for m in self.masks])
        self.Xy = np.stack([np.einsum("nj,nja,nj->a", m, self.Xs, y) for m in self.masks])
        self.yy = np.array([float((m * y * y).sum()) for m in self.masks])

    def extended(self, C: np.ndarray) -> Engine:
        """The same problem with the columns C (N, J, c) added to the basis."""
        return Engine(np.concatenate([self.X, C], axis=2), self.y, self.W, self.fold, self.K)

    def _scale(self, A):
        w = self.W[:, :, None]
        s = np.sqrt((w * A * A).sum(axis=(0, 1)) / max(w.sum(), 1.0))
        return np.where(s > 1e-12, s, 1.0)

    def _solve(self, G, b):
        n = len(b)
        if n == 0:
            return np.zeros(0)
        lam = self.RIDGE * max(float(np.trace(G)) / n, 1e-12)
        try:
            return np.linalg.solve(G + lam * np.eye(n), b)
        except np.linalg.LinAlgError:
            return np.linalg.lstsq(G, b, rcond=None)[0]

    def fit(self, C: np.ndarray | None, train: list[int]):
        """Least squares on the training folds; returns (theta_x, theta_c (unscaled), training SSE)."""
        XX, Xy, yy = self.XX[train].sum(0), self.Xy[train].sum(0), self.yy[train].sum()
        if C is None:
            th = self._solve(XX, Xy)
            sse = yy - 2 * th @ Xy + th @ XX @ th
            return th / self.sx, np.zeros(0), float(sse)
        sc = self._scale(C)
        Cs = C / sc
        mask = sum(self.masks[k] for k in train)
        XC = np.einsum("nj,nja,njb->ab", mask, self.Xs, Cs)
        CC = np.einsum("nj,nja,njb->ab", mask, Cs, Cs)
        Cy = np.einsum("nj,nja,nj->a", mask, Cs, self.y)
        G = np.block([[XX, XC], [XC.T, CC]])
        b = np.concatenate([Xy, Cy])
        th = self._solve(G, b)
        sse = yy - 2 * th @ b + th @ G @ th
        return th[:self.p] / self.sx, th[self.p:] / sc, float(sse)

    def heldout_sse(self, C, th_x, th_c, k: int) -> np.ndarray:
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
    shape_index: int = 0  # index into columns_by_shape of shape_all

    def reduction(self, joint: int) -> float:
        """Fraction of the held-out SSE on `joint` (all folds) the candidate removes."""
        before = self.sse_before[joint].sum()
        return 0.0 if before == 0 else float(1.0 - self.sse_after[joint].sum() / before)

    def fold_reductions(self, joint: int) -> list[float]:
        """The same, per fold."""
        return [float(1 - a / b) if b > 0 else 0.0
                for a, b in zip(self.sse_after[joint], self.sse_before[joint])]


def cross_validate(engine: Engine, effect, columns_by_shape, baseline) -> CVFit:
    """Fit the candidate (its columns per shape, see diagnosis_effects.candidate_columns) on every K-1
    folds, keeping the shape that fits the training folds best, and predict the held-out fold.
    baseline[k] = (J,) held-out SSE of the refit without candidate for fold k (Engine.baseline)."""
    K = engine.K
    J = engine.y.shape[1]
    sse_before = np.zeros((J, K))
    sse_after = np.zeros((J, K))
    fold_values = []
    for k in range(K):
        train = [i for i in range(K) if i != k]
        best = None
        for shape, C in columns_by_shape:
            th_x, th_c, sse = engine.fit(C, train)
            if best is None or sse < best[0]:
                best = (sse, shape, C, th_x, th_c)
        _, shape, C, th_x, th_c = best
        fold_values.append(named_values(effect, th_c, shape))
        sse_before[:, k] = baseline[k]
        sse_after[:, k] = engine.heldout_sse(C, th_x, th_c, k)
    count = engine.W.sum(axis=0)
    every = list(range(K))
    shape_all = min(((engine.fit(C, every)[2], i) for i, (_, C) in enumerate(columns_by_shape)))[1]
    return CVFit(sse_before, sse_after, count, fold_values, columns_by_shape[shape_all][0], shape_all)
