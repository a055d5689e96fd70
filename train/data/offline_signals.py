"""The offline (zero-phase) signals' own settings: their least cutoff and how far a stop reaches into them
(train.data.preprocess builds Dataset.offline with them; `crane-train identify` filters at the same
cutoff). Plain numpy, so that a command's --help can show the numbers without the data stack."""

from __future__ import annotations

import numpy as np

# rad/s: the least cutoff of the offline signals' low-pass and pseudo-derivative (a higher configured
# cutoff is kept). Filtered forward and backward a signal loses no phase, so the filters need only keep
# the acceleration's noise down; a lower cutoff smears each stop further.
OFFLINE_CUTOFF_RAD_S = 60.0
# A zero-phase filter looks both ways: the offline signals of the rows just before a joint stops (or just
# after it starts) mix in the stop, where the friction torque is whatever holds the joint rather than
# Coulomb's +-fc. A joint counts as moving in the offline mask only this many time constants of the
# offline low-pass (50 ms at 60 rad/s) or more away from a row where it stands still.
OFFLINE_REACH_TAUS = 3.0


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
