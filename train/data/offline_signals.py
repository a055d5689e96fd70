"""How far a stop reaches into the offline (zero-phase) signals, and the rows it reaches
(train.data.preprocess leaves them out of Dataset.offline's mask).

A zero-phase filter looks both ways: the offline signals of the rows just before a joint stops (or just
after it starts) mix in the stop, where the friction torque is whatever holds the joint rather than
Coulomb's +-fc, while the regressor's sign(dq) column already (or still) says +-1. Fitted with those
rows, a Coulomb friction comes out low (0.25 N m as 0.231 on the two-arm walkthrough session of
docs/modelling.md, 0.248 on average over the planted sessions). So a joint counts as moving in the
offline mask only OFFLINE_REACH_TAUS time constants of the low-pass (1 / cutoff: 120 ms at the default
25 rad/s) or more away from any row where it stands still and from the ends of its continuous piece
(where the backward pass starts)."""

from __future__ import annotations

import numpy as np

OFFLINE_REACH_TAUS = 3.0  # time constants of the offline low-pass (module docstring)


def near_rest(still: np.ndarray, segment: np.ndarray, reach_rows: float) -> np.ndarray:
    """(N, J) bool: the rows within `reach_rows` rows of a row where the joint is `still` (N, J) or of the
    ends of its continuous piece (`segment` (N,)), each piece on its own."""
    k = int(np.ceil(reach_rows))
    out = still.astype(bool).copy()
    if k <= 0:
        return out
    bounds = [0, *(np.flatnonzero(np.diff(segment)) + 1).tolist(), len(segment)]
    for a, b in zip(bounds[:-1], bounds[1:]):
        edge = np.ones((k, still.shape[1]), dtype=bool)
        piece = np.concatenate([edge, still[a:b].astype(bool), edge]).astype(np.int64)
        csum = np.concatenate([np.zeros((1, still.shape[1]), dtype=np.int64), np.cumsum(piece, axis=0)])
        n = b - a
        # row i of the piece (padded index i + k) is near when any padded row i .. i + 2k is still
        out[a:b] = (csum[2 * k + 1:2 * k + 1 + n] - csum[:n]) > 0
    return out
