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
k is g_k = |r_k|^2 - |r_k - w_(k) m_k|^2 (what physics + w_(k) x network removes from the physics part's
squared error on data the weight never saw). Then

* w = 0 (the physics alone) unless the network helps out of sample: the total held-out gain sum_k g_k
  is positive by more than one standard error (sqrt(K) x the spread of the g_k), and at least
  MIN_ROWS validation samples and 2 blocks exist;
* otherwise w = w_all x min(1, sum_k g_k / G_in), G_in the gain of w_all on the data it was chosen on:
  the share of the apparent gain that survives cross-validation. With plenty of data the two gains
  agree and w = w_all; with little data the held-out gain is a smaller part of the in-sample one and
  the network's share shrinks towards 0.

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
    cv_gain: float  # held-out reduction of the squared error, summed over the blocks
    cv_gain_se: float  # its standard error (from the spread over the blocks)
    in_sample_gain: float
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
    gains = 2 * w_out * rm - w_out ** 2 * mm  # |r_k|^2 - |r_k - w_(k) m_k|^2
    cv_gain = float(gains.sum())
    cv_se = float(np.sqrt(k) * gains.std(ddof=1))
    in_gain = 2 * w_all * RM - w_all ** 2 * MM
    if cv_gain <= cv_se or in_gain <= 0:
        return Share(0.0, w_all, k, cv_gain, cv_se, in_gain,
                     "the network does not lower the held-out error of the blocks (by more than one "
                     "standard error)")
    w = w_all * min(1.0, cv_gain / in_gain)
    return Share(float(w), w_all, k, cv_gain, cv_se, float(in_gain),
                 "weight shrunk by the held-out share of the in-sample gain" if w < w_all
                 else "the network's full least-squares weight")


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
