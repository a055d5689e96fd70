"""Standard errors that hold for serially correlated data: the delete-a-block jackknife over contiguous
time blocks.

Neighbouring samples of a recording are nearly copies of each other (low-pass filtering, a move lasts a
second or two, an unmodelled effect leaves a residual that changes slowly), so least squares' textbook
covariance s^2 (A^T A)^-1, which counts every row as an independent observation, understates the
uncertainty of a fitted parameter by roughly the square root of the number of rows per correlation time.
The block jackknife makes no assumption about the correlation inside a block: the data are cut into K
contiguous time blocks, the estimate is recomputed K times with one block left out (theta_(k)), and

    se = sqrt((K - 1) / K * sum_k (theta_(k) - mean_k theta_(k))^2).

Assumptions: the blocks are long compared with the correlation time of the residual (then the blocks
are nearly independent), the estimator is smooth in the data (least squares is linear), and there are
enough blocks for the spread to be estimated: the standard error is itself estimated from K values, so
a 95 % interval is +- t_{K-1, 0.975} x se (Student's t with K - 1 degrees of freedom, `t_factor`), not
+- 1.96 x se.

Repeated samples: a block method treats two blocks as independent evidence, so a copied stretch of
data placed in another block would shrink the standard error as if it were new data. `sample_blocks`
therefore gives every repeated sample (equal, to `DUPLICATE_DIGITS` significant digits of each column's
scale, to an earlier one) the block of its first occurrence: leaving that block out leaves out every
copy, and the copy adds no evidence.

`block_count` picks K from the data's duration: blocks of at least `MIN_BLOCK_S` seconds, at most
`MAX_BLOCKS` blocks and at least `MIN_BLOCKS` (shorter blocks then, on very short data).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MIN_BLOCK_S = 3.0  # s: blocks at least this long (several moves of an operator, many filter time constants)
MAX_BLOCKS = 20  # more blocks add little: the t factor at 19 degrees of freedom is 2.09 (1.96 at infinity)
MIN_BLOCKS = 5  # fewer leave the spread of the estimate too poorly known (t factor 2.78 at 4)
DUPLICATE_DIGITS = 7  # repeated samples: equal to this many significant digits of each column's RMS


@dataclass(frozen=True)
class BlockPlan:
    """How the rows were cut: `ids` (n,) block of each row (0..count-1), `count` blocks, `block_s` their
    mean length in seconds, `repeated` rows that repeat an earlier sample (given its block)."""
    ids: np.ndarray
    count: int
    block_s: float
    repeated: int = 0

    def describe(self) -> str:
        extra = f"; {self.repeated} repeated samples counted once" if self.repeated else ""
        return (f"delete-a-block jackknife over {self.count} contiguous time blocks of "
                f"{self.block_s:.3g} s{extra}")


def block_count(duration_s: float, min_block_s: float = MIN_BLOCK_S, max_blocks: int = MAX_BLOCKS,
                min_blocks: int = MIN_BLOCKS) -> int:
    """K for data lasting `duration_s` seconds: as many blocks of `min_block_s` as fit, within
    [min_blocks, max_blocks]."""
    fit = int(duration_s // min_block_s) if min_block_s > 0 and math.isfinite(duration_s) else 0
    return int(min(max_blocks, max(min_blocks, fit)))


def contiguous_ids(n: int, count: int) -> np.ndarray:
    """(n,) block of each of n rows in time order: `count` contiguous blocks of (nearly) equal size."""
    count = max(int(count), 1)
    return np.minimum((np.arange(n) * count) // max(n, 1), count - 1)


def repeated_rows(values: np.ndarray) -> np.ndarray:
    """(n,) index of each row's first occurrence among the rows of `values` (n, m) (itself when it is
    new), rows compared to DUPLICATE_DIGITS significant digits of each column's RMS."""
    v = np.asarray(values, dtype=float).reshape(len(values), -1)
    if len(v) == 0:
        return np.zeros(0, dtype=int)
    scale = np.sqrt((v ** 2).mean(axis=0))
    scale = np.where(scale > 0, scale, 1.0)
    key = np.round(v / scale, DUPLICATE_DIGITS)
    key = np.ascontiguousarray(np.where(key == 0, 0.0, key))  # -0.0 and 0.0 alike
    _, first, inverse = np.unique(key.view(np.dtype((np.void, key.dtype.itemsize * key.shape[1]))),
                                  return_index=True, return_inverse=True)
    return first[inverse.reshape(-1)]


def sample_blocks(order_key: np.ndarray, rate_hz: float, values: np.ndarray | None = None,
                  count: int | None = None) -> BlockPlan:
    """Contiguous time blocks of n samples. `order_key` (n,) sorts the samples into time order (e.g.
    segment x big + time; rows may come shuffled); `rate_hz` gives the duration (n / rate_hz) and so
    the block count (unless `count` is given); `values` (n, m), when given, finds repeated samples, which
    join their first occurrence's block."""
    order_key = np.asarray(order_key, dtype=float)
    n = len(order_key)
    first = repeated_rows(values) if values is not None else np.arange(n)
    new = first == np.arange(n)
    n_new = int(new.sum())
    duration = n_new / rate_hz if rate_hz > 0 else 0.0
    k = block_count(duration) if count is None else int(count)
    k = max(1, min(k, n_new))
    ids = np.empty(n, dtype=int)
    new_rows = np.flatnonzero(new)
    ranked = new_rows[np.argsort(order_key[new_rows], kind="stable")]
    ids[ranked] = contiguous_ids(n_new, k)
    ids[~new] = ids[first[~new]]
    return BlockPlan(ids, k, duration / k if k else 0.0, n - n_new)


def jackknife_se(replicates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(mean, standard error) over axis 0 of the K leave-one-block-out replicates (K, ...):
    se = sqrt((K-1)/K sum_k (theta_(k) - mean)^2)."""
    r = np.asarray(replicates, dtype=float)
    k = r.shape[0]
    mean = r.mean(axis=0)
    if k < 2:
        return mean, np.full_like(mean, np.nan)
    return mean, np.sqrt((k - 1) / k * ((r - mean) ** 2).sum(axis=0))


def jackknife_values(per_block: list[dict[str, float]]) -> dict[str, tuple[float, float]]:
    """name -> (mean, delete-a-block jackknife standard error) of named values, one dict per left-out
    block (the names every dict holds)."""
    names = [n for n in per_block[0] if all(n in v for v in per_block)]
    out = {}
    for name in names:
        mean, se = jackknife_se(np.array([v[name] for v in per_block], dtype=float))
        out[name] = (float(mean), float(se))
    return out


def t_factor(blocks: int, level: float = 0.95) -> float:
    """The half-width of a `level` interval in standard errors for a jackknife over `blocks` blocks
    (Student's t with blocks - 1 degrees of freedom)."""
    from scipy.stats import t

    return float(t.ppf(0.5 + level / 2, max(int(blocks) - 1, 1)))


def block_normal_equations(A: np.ndarray, b: np.ndarray, ids: np.ndarray,
                           count: int) -> tuple[np.ndarray, np.ndarray]:
    """Per block, A_k^T A_k (K, p, p) and A_k^T b_k (K, p) of the rows A (m, p), b (m,) with block ids."""
    p = A.shape[1]
    G, c = np.zeros((count, p, p)), np.zeros((count, p))
    order = np.argsort(ids, kind="stable")
    edges = np.searchsorted(ids[order], np.arange(count + 1))
    for k in range(count):
        rows = order[edges[k]:edges[k + 1]]
        Ak = A[rows]
        G[k] = Ak.T @ Ak
        c[k] = Ak.T @ b[rows]
    return G, c


def least_squares_jackknife(A: np.ndarray, b: np.ndarray, ids: np.ndarray, count: int,
                            ridge: float = 0.0) -> np.ndarray:
    """Delete-a-block jackknife standard errors (p,) of the least-squares estimate
    argmin |A theta - b|^2 + ridge |theta|^2, rows A (m, p), b (m,) in blocks `ids` (0..count-1):
    each replicate solves the normal equations without one block's."""
    return jackknife_se(least_squares_replicates(A, b, ids, count, ridge))[1]


def least_squares_covariance(A: np.ndarray, b: np.ndarray, ids: np.ndarray, count: int,
                             ridge: float = 0.0) -> np.ndarray:
    """The delete-a-block jackknife covariance (p, p) of the same estimate: (K-1)/K sum_k d_k d_k^T with
    d_k the k-th replicate's deviation from the replicates' mean (its diagonal is the square of
    least_squares_jackknife)."""
    reps = least_squares_replicates(A, b, ids, count, ridge)
    k = reps.shape[0]
    if k < 2:
        return np.full((reps.shape[1], reps.shape[1]), np.nan)
    dev = reps - reps.mean(axis=0)
    return (k - 1) / k * dev.T @ dev


def least_squares_replicates(A: np.ndarray, b: np.ndarray, ids: np.ndarray, count: int,
                             ridge: float = 0.0) -> np.ndarray:
    """(K, p) the least-squares estimates with each of the K blocks left out in turn."""
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    G, c = block_normal_equations(A, b, ids, count)
    Gt, ct = G.sum(axis=0), c.sum(axis=0)
    reg = ridge * np.eye(A.shape[1])
    reps = np.empty((count, A.shape[1]))
    for k in range(count):
        M = Gt - G[k] + reg
        try:
            reps[k] = np.linalg.solve(M, ct - c[k])
        except np.linalg.LinAlgError:
            reps[k] = np.linalg.lstsq(M, ct - c[k], rcond=None)[0]
    return reps
