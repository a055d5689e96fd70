"""The hybrid's network share: per joint, the weight w in [0, 1] of the network in physics + w x network,
chosen by cross-validation over contiguous time blocks of the training data and shrunk when the data
are few.

The network's output on its own training rows says nothing about how it does elsewhere, and the
validation data picked its epoch (and are a few seconds on short sessions). So the share is judged on
out-of-fold predictions (`cross_fit`): the training rows are cut into CROSS_FIT_FOLDS contiguous time
blocks, and a network trained like the hybrid's own on all but one of them predicts the one left out.
Those networks see less data than the final one, so the share they earn is on the cautious side.

For one joint, r = the physics part's residual and m = the out-of-fold network output on the training
samples where the joint moves, cut into K contiguous time blocks (train.evaluation.block_uncertainty:
blocks of >= 3 s, 5 to 20 of them). The least-squares weight over all blocks is w_all = clip(r.m / m.m, 0, 1).
Leaving block k out, w_(k) = the same from the other blocks, and the held-out gain of the blend on block
k is the fraction of that block's physics error it removes,

    g_k = (|r_k|^2 - |r_k - w_(k) m_k|^2) / |r_k|^2,

on data the weight never saw. Each block counts alike, whatever the size of its error: the promise is
about every stretch of held-out data, and a network's error is not the same everywhere (where the
physics part is already good - a spring's joint near its rest angle - a network that overshoots makes
physics + w x network worse than the physics there, while it removes most of a large error elsewhere).
Then, with g the mean of the g_k, se = their spread / sqrt(K) and G_in = the same mean for w_all on
the data it was chosen on:

* w = 0 (the physics alone) unless the network helps out of sample by one standard error of caution:
  g - se > 0, with at least MIN_ROWS samples and 2 blocks;
* otherwise w = w_all x min(1, (g - se) / G_in): the part of the apparent gain that the held-out
  blocks support, counted one standard error below their mean. With plenty of data, and a network that
  helps alike in every block, that is G_in and w = w_all; with few blocks, or blocks that disagree, the
  share shrinks towards 0, continuously (w reaches 0 where the bound does).

Last, the share never makes the hybrid worse than its physics part on the validation samples where the
joint moves: w is capped at 2 r.m / m.m there (0 when the network's output there points against the
residual), the weight at which physics + w x network is exactly as good as the physics alone.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from crane_io.errors import CraneError

from ..evaluation.block_uncertainty import block_count, contiguous_ids

if TYPE_CHECKING:
    from collections.abc import Callable

MIN_ROWS = 50  # samples of a joint below which its network is not used
CROSS_FIT_FOLDS = 3  # time blocks of the training rows for the out-of-fold network predictions


@dataclass(frozen=True)
class Share:
    """One joint's network share `weight`, with what it was chosen from."""
    weight: float
    weight_all: float  # the least-squares weight on all the blocks
    blocks: int
    cv_gain: float  # mean over the blocks of the share of the physics' held-out error the blend removes
    cv_gain_se: float  # its standard error (from the spread over the blocks)
    in_sample_gain: float  # the same mean for w_all on the data it was chosen on
    reason: str


def _clip_weight(rm: float, mm: float) -> float:
    return 0.0 if mm <= 0 else float(np.clip(rm / mm, 0.0, 1.0))


def block_cv_share(r: np.ndarray, m: np.ndarray, rate_hz: float, count: int | None = None) -> Share:
    """The network share for residual r (n,) and out-of-fold network output m (n,) on n samples in time
    order at `rate_hz` (K from their duration unless `count` is given)."""
    r = np.asarray(r, dtype=float)
    m = np.asarray(m, dtype=float)
    n = len(r)
    k = block_count(n / rate_hz) if count is None else int(count)
    k = min(k, n)
    if n < MIN_ROWS or k < 2:
        return Share(0.0, 0.0, max(k, 0), 0.0, 0.0, 0.0,
                     f"{n} samples: too few to tell whether the network helps")
    ids = contiguous_ids(n, k)
    rm, mm, rr = (np.bincount(ids, weights=a, minlength=k) for a in (r * m, m * m, r * r))
    RM, MM = float(rm.sum()), float(mm.sum())
    w_all = _clip_weight(RM, MM)
    w_out = np.array([_clip_weight(RM - rm[i], MM - mm[i]) for i in range(k)])
    scale = np.maximum(rr, 1e-300)
    gains = (2 * w_out * rm - w_out ** 2 * mm) / scale  # share of |r_k|^2 removed by w_(k) m_k
    cv_gain = float(gains.mean())
    cv_se = float(gains.std(ddof=1) / np.sqrt(k))
    in_gain = float(np.mean((2 * w_all * rm - w_all ** 2 * mm) / scale))
    lower = cv_gain - cv_se
    if lower <= 0 or in_gain <= 0:
        return Share(0.0, w_all, k, cv_gain, cv_se, in_gain,
                     "the network does not lower the held-out error of the blocks (by more than one "
                     "standard error)")
    w = w_all * min(1.0, lower / in_gain)
    reason = ("weight shrunk to the part of the in-sample gain that the held-out blocks support (one "
              "standard error below their mean)" if w < w_all else "the network's full least-squares weight")
    return Share(float(w), w_all, k, cv_gain, cv_se, in_gain, reason)


def time_order(ds) -> np.ndarray:
    """Row indices of the Dataset `ds` in time order (by segment, then time)."""
    return np.lexsort((np.asarray(ds.t), np.asarray(ds.segment)))


def cross_fit(make_network: Callable[[], object], residual, val,
              folds: int = CROSS_FIT_FOLDS) -> np.ndarray | None:
    """(N, J) out-of-fold network predictions on the N rows of the Dataset `residual` (the physics part's
    residual as torque): its rows in `folds` contiguous time blocks, a network from make_network()
    trained on all but block k (validated on `val`) predicts block k. None when the data are too few to
    train on (a block's complement without two usable rows)."""
    n = len(residual)
    if n < folds * 2:
        return None
    ids = np.empty(n, dtype=int)
    ids[time_order(residual)] = contiguous_ids(n, folds)
    pred = np.zeros_like(np.asarray(residual.tau, dtype=float))
    for k in range(folds):
        keep, out = np.flatnonzero(ids != k), np.flatnonzero(ids == k)
        try:
            net = make_network().fit(residual.subset(keep), val)
        except CraneError:  # too few usable rows to train on
            return None
        pred[out] = net.predict(residual.q[out], residual.dq[out], residual.ddq[out])
    return pred


def validation_cap(r: np.ndarray, m: np.ndarray) -> float:
    """The largest weight at which physics + w x network is no worse than the physics alone on residual
    r and network output m (inf without samples): 2 r.m / m.m, 0 when r.m <= 0."""
    if len(r) == 0:
        return float("inf")
    rm, mm = float(r @ m), float(m @ m)
    return 0.0 if rm <= 0 or mm <= 0 else 2 * rm / mm
