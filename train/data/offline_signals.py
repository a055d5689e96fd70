"""What the offline (zero-phase) signals of a Dataset do beyond filtering (train.data.preprocess builds
Dataset.offline with them): the torque centred on the angle's instant, and the rows beside a stop left
out of the mask.

The torque's instant: crane-collect records, for each joint it drives, the current it commanded right
after reading the row's angle (`tau_source` "goal_current"), which then acts until the next read:
centred half a sample after the angle. Against a slope of the torque with the angle (gravity: about
-3 N m/rad on joint 2) that lead reads as a velocity term, and a viscous friction takes it (joint 2's
0.04 N m s/rad came out 0.0368 on the planted sessions, which record the same way). So for such columns
the offline torque of a row is the mean of the command before and after it, the torque that acted
around the angle's instant (`command_centred`); a column recorded as a measured current, imported, or
not declared is used as recorded. The loop model keeps the recorded pairing: it predicts the command
to send after a read.

The rows beside a stop:

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
from scipy.ndimage import maximum_filter1d

from crane_io.session_format import TAU_FROM_GOAL, TAU_SOURCE_ATTR

OFFLINE_REACH_TAUS = 3.0  # time constants of the offline low-pass (module docstring)


def near_rest(still: np.ndarray, segment: np.ndarray, reach_rows: float) -> np.ndarray:
    """(N, J) bool: the rows within `reach_rows` rows of a row where the joint is `still` (N, J) or of the
    ends of its continuous piece (`segment` (N,)), each piece on its own (beyond a piece's ends counts
    as still)."""
    k = int(np.ceil(reach_rows))
    out = still.astype(bool).copy()
    if k <= 0:
        return out
    bounds = [0, *(np.flatnonzero(np.diff(segment)) + 1).tolist(), len(segment)]
    for a, b in zip(bounds[:-1], bounds[1:]):
        out[a:b] = maximum_filter1d(out[a:b].astype(np.uint8), size=2 * k + 1, axis=0, mode="constant",
                                    cval=1) > 0
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


def commanded_columns(session, cols) -> np.ndarray:
    """(len(cols),) bool: the session's columns `cols` whose torque is the command sent after the row's
    read (`tau_source` "goal_current", module docstring); all False when the session does not say."""
    sources = session.attrs.get(TAU_SOURCE_ATTR)
    names = session.joint_names
    if sources is None or isinstance(sources, (str, bytes)) or len(sources) != len(names):
        return np.zeros(len(cols), dtype=bool)
    return np.array([str(sources[c]) == TAU_FROM_GOAL for c in cols], dtype=bool)


def command_centred(tau: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """`tau` (N, J) of one continuous piece with its `columns` (J,) bool replaced by the mean of each row's
    command and the one before it (the first row as it is): the torque that acted around each read."""
    columns = np.asarray(columns, dtype=bool)
    if not columns.any():
        return tau
    out = np.array(tau, dtype=float, copy=True)
    out[1:, columns] = 0.5 * (tau[1:, columns] + tau[:-1, columns])
    return out
