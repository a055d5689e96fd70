"""The jackknife blocks of an identification: for excitation data, one block per speed of the trajectory's
speed cycle; otherwise contiguous time blocks (train.models.rigid_body.fit_blocks, as `fit` uses).

An excitation plays one period again and again (crane_io/physics/excitation_trajectory.py). An error
locked to the period's phase (a filter's attenuation of the period's harmonics, a friction mismatch at
the speeds it reaches) is then the same in every period played at the same speed, so periods at one
speed are not independent evidence, and a jackknife over time blocks cannot see such an error: every
block holds it alike. Periods at different speeds meet the error differently. So when the data are
excitation sessions whose trajectory cycles through at least MIN_SPEEDS speeds, the rows of each speed
(of each session) form one block, and the jackknife leaves out one speed at a time: the spread between
speeds is the uncertainty, a phase-locked error included as far as it changes with speed. A row before
the trajectory (the approach) joins the first period, a row after it (the rest) the last.

The session time of a row (Dataset.t) is the time since the start of its session's recording; the
sessions' rows follow each other in order, so a row whose time is below its predecessor's starts the
next session.
"""

from __future__ import annotations

import json
from collections.abc import Sequence

import numpy as np

from crane_io import session_format as sf

from ..evaluation.block_uncertainty import BlockPlan

MIN_SPEEDS = 3  # fewer speeds leave too few blocks for a spread (the t factor at 1 degree of freedom is 12.7)


def excitation_schedule(path) -> tuple[np.ndarray, np.ndarray] | None:
    """(period_starts (P + 1,) s of session time, speed (P,)) of the excitation recorded in the session
    at `path`, or None when it is not an excitation session."""
    import h5py

    from crane_io.physics.excitation_trajectory import from_dict

    with h5py.File(path, "r") as f:
        attrs = f.attrs
        if not bool(attrs.get(sf.EXCITATION_ATTR, False)) or sf.EXCITATION_TRAJECTORY_ATTR not in attrs:
            return None
        text = attrs[sf.EXCITATION_TRAJECTORY_ATTR]
        start = float(attrs.get(sf.EXCITATION_START_ATTR, 0.0))
    text = text.decode() if isinstance(text, bytes) else text
    traj = from_dict(json.loads(text), f"the trajectory of {path}")
    return start + traj.period_starts(), traj.period_speeds()


def session_of_rows(t: np.ndarray, segment: np.ndarray) -> np.ndarray:
    """(n,) the session each row comes from, counted from 0 (the module docstring): a new session
    starts at a segment whose first time lies below the previous segment's last time."""
    t, segment = np.asarray(t, float), np.asarray(segment, int)
    order = np.lexsort((t, segment))
    ts, ss = t[order], segment[order]
    new_segment = np.flatnonzero(np.diff(ss) != 0) + 1
    restart = np.zeros(len(t), dtype=int)
    restart[new_segment[ts[new_segment] < ts[new_segment - 1]]] = 1
    out = np.empty(len(t), dtype=int)
    out[order] = np.cumsum(restart)
    return out


def speed_blocks(full_t: np.ndarray, full_segment: np.ndarray, rows_t: np.ndarray, rows_segment: np.ndarray,
                 schedules: Sequence[tuple[np.ndarray, np.ndarray] | None],
                 rate_hz: float) -> BlockPlan | None:
    """The speed blocks (module docstring) of the rows (their times and segments, sampled at `rate_hz`) of
    a dataset whose every row has `full_t`, `full_segment` (to tell the sessions apart); `schedules`: one
    per session (excitation_schedule). None unless every session is an excitation of at least MIN_SPEEDS
    speeds."""
    if not schedules or any(s is None or len(np.unique(s[1])) < MIN_SPEEDS for s in schedules):
        return None
    first_rows = {}
    session_all = session_of_rows(full_t, full_segment)
    for seg, sess in zip(full_segment, session_all):
        first_rows.setdefault(int(seg), int(sess))
    session = np.array([first_rows.get(int(s), 0) for s in rows_segment], dtype=int)
    if session.max(initial=0) >= len(schedules):
        return None
    ids = np.empty(len(rows_t), dtype=int)
    offset = 0
    for k, (starts, speeds) in enumerate(schedules):
        mine = session == k
        period = np.clip(np.searchsorted(starts, rows_t[mine], side="right") - 1, 0, len(speeds) - 1)
        levels, which = np.unique(speeds[period], return_inverse=True)
        ids[mine] = offset + which
        offset += len(levels)
    used, ids = np.unique(ids, return_inverse=True)
    count = len(used)
    block_s = len(rows_t) / (count * rate_hz) if count and rate_hz > 0 else 0.0
    return BlockPlan(ids.reshape(-1), count, float(block_s), 0)
