"""The selection step of `crane-train diagnose --discover` (train/diagnosis/discovery.py, step 2): on the rows
of some time blocks, which terms of the basis explain a target beyond a base. The terms and the target are
made orthogonal to the base, standardised, and the Lasso path is computed knot by knot (scikit-learn's
`lars_path`, method "lasso"); the expressions along it (none, one term, two, ...) are scored by
leave-one-block-out CV of their least-squares refits; the fewest terms within one standard error of the
best are kept, then pruned to coefficients at least twice their jackknife standard error."""

from __future__ import annotations

import math

import numpy as np

MAX_TERMS = 6
MIN_OWN_PART = 0.05  # a term's part orthogonal to the base, relative to its norm, below which it is dropped


def select(T: np.ndarray, y: np.ndarray, B: np.ndarray, rows: np.ndarray, fold: np.ndarray, train: list[int],
           max_terms: int = MAX_TERMS) -> list[int]:
    """Indices of the terms (columns of T) selected on the rows of the `train` blocks: Lasso path on the
    terms made orthogonal to the base B (N, p), leave-one-block-out CV of the least-squares refits of
    each path point, the sparsest point within one standard error of the best (module docstring)."""
    r = rows[np.isin(fold[rows], train)]
    if len(r) < 10 or T.shape[1] == 0:
        return []
    Z, e = _orthogonal(T[r], y[r], B[r])
    norm = np.linalg.norm(Z, axis=0)
    # a term the base nearly spans (gravity's sin(q2 + q4) against a rigid-body model) cannot be told
    # apart from the base's own parameters: it is not a candidate
    usable = np.flatnonzero(norm > MIN_OWN_PART * np.maximum(np.linalg.norm(T[r], axis=0), 1e-300))
    if len(usable) == 0:
        return []
    Z = Z[:, usable] / (norm[usable] / math.sqrt(len(r)))
    blocks = fold[r]
    sizes = range(max_terms + 1)
    mse = np.full((len(train), max_terms + 1), np.inf)  # per held-out block and number of terms
    for i, k in enumerate(train):
        tr, te = blocks != k, blocks == k
        supports = _supports(Z[tr], e[tr], max_terms)
        for n in sizes:  # a size the path skips scores as the largest expression it has below that size
            S = supports[max(m for m in supports if m <= n)]
            mse[i, n] = _refit_error(Z[tr][:, S], e[tr], Z[te][:, S], e[te]) if len(S) else float(
                np.mean(e[te] ** 2))
    mean = mse.mean(0)
    finite = np.isfinite(mean)
    best = int(np.argmin(np.where(finite, mean, np.inf)))
    se = float(mse[:, best].std(ddof=1) / math.sqrt(len(train))) if len(train) > 1 else 0.0
    chosen = next(n for n in sizes if finite[n] and mean[n] <= mean[best] + se)  # the simplest
    if chosen == 0:
        return []
    supports = _supports(Z, e, max_terms)
    n = max((m for m in supports if m <= chosen), default=0)
    S = _prune(Z, e, blocks, train, list(supports[n]))
    return sorted(int(usable[s]) for s in S)


def _supports(Z, e, max_terms: int) -> dict[int, np.ndarray]:
    """Number of terms -> the terms active at the first knot of the Lasso path (scikit-learn's
    `lars_path`, method "lasso") with that many, up to `max_terms` (0 -> none)."""
    import warnings

    from sklearn.exceptions import ConvergenceWarning
    from sklearn.linear_model import lars_path

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        coefs = lars_path(Z, e, method="lasso", max_iter=max_terms + 4, Gram=Z.T @ Z)[2]
    out: dict[int, np.ndarray] = {0: np.zeros(0, dtype=int)}
    for c in coefs.T:
        S = np.flatnonzero(c)
        if 0 < len(S) <= max_terms and len(S) not in out:
            out[len(S)] = S
    return out


def _prune(Z, e, blocks, train, S: list[int]) -> list[int]:
    """Drop, one at a time, the selected term whose least-squares coefficient is least certain until
    every coefficient is at least twice its delete-a-block jackknife standard error
    (train.diagnosis.cv.jackknife)."""
    from .cv import jackknife

    while S and len(train) > 1:
        full = np.linalg.lstsq(Z[:, S], e, rcond=None)[0]
        names = [str(i) for i in range(len(S))]
        spread = jackknife([dict(zip(names, np.linalg.lstsq(Z[blocks != k][:, S], e[blocks != k],
                                                            rcond=None)[0])) for k in train])
        se = np.array([spread[n][1] for n in names])
        z = np.abs(full) / np.maximum(se, 1e-300)
        worst = int(np.argmin(z))
        if z[worst] >= 2.0:
            break
        S = S[:worst] + S[worst + 1:]
    return S


def _orthogonal(T: np.ndarray, y: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """T and y minus their least-squares projection on the columns of B (the base's joint equation)."""
    B = B[:, np.linalg.norm(B, axis=0) > 0]
    if B.shape[1] == 0:
        return T.copy(), y.copy()
    from scipy.linalg import qr

    U, R, _ = qr(B / np.linalg.norm(B, axis=0), mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    U = U[:, d > 1e-8 * d[0]]  # the base's own rank deficiencies (columns the data barely excite)
    return T - U @ (U.T @ T), y - U @ (U.T @ y)


def _refit_error(Ztr, etr, Zte, ete) -> float:
    coef = np.linalg.lstsq(Ztr, etr, rcond=None)[0]
    return float(np.mean((ete - Zte @ coef) ** 2))
