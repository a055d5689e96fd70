"""Regressor columns whose angle-only part is filtered as the torque is (for the zero-phase estimates).

The zero-phase torque is the recorded torque low-passed twice, forward and backward (|L|^4 in
magnitude, train.data.preprocess). A regressor column computed from the equally filtered angle sees the
same filter only where it is linear in the signals (k q, I ddq, b dq): a fast function of the angle, such
as a 12/rev ripple sin(12 q) at 1-2 rad/s (12-24 rad/s, above the 25 rad/s cut-off's flat part), comes out
unattenuated from the filtered angle while its torque was attenuated, and its coefficient comes out low.

So the part of a column that is a function of the angle alone — the column with every joint at rest
(dq = ddq = 0: a cogging ripple, a spring, gravity, any angle-periodic term without velocity or
acceleration; zero for a friction or inertia column) — is computed from the unfiltered angle and
filtered with the torque's chain, each continuous piece on its own, in place of the same part computed
from the filtered angle:

    column = c(q_f, dq_f, ddq_f) + L4[c(q, 0, 0)] - c(L4[q], 0, 0)

where q is the unfiltered angle at the Dataset's rate and L4 the torque's zero-phase chain at that rate.
For a column affine in the angle the two last terms cancel exactly (the filters pass a constant
unchanged), so a spring's or an inertia's column is the same as without; velocity and acceleration
parts are untouched. The angle series (AngleSeries) spans every row of the preprocessed data in time
order; a Dataset's rows index into it (AngleRows), so a subset of the rows (a split, the moving samples)
takes its columns from the filtered series.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from .filters import lowpass

if TYPE_CHECKING:
    from collections.abc import Callable

    from .dataset import Dataset


@dataclass(frozen=True)
class AngleSeries:
    """The unfiltered angles of every row of preprocessed data, in time order, and the torque's filter."""

    t: np.ndarray  # (M,) s
    q: np.ndarray  # (M, J) rad, the learning joints' unfiltered angle
    context_q: np.ndarray | None  # (M, K) rad, the context joints' (None without any)
    segment: np.ndarray  # (M,) int: the continuous piece of each row (no filter runs across a boundary)
    rate_hz: float  # the rows' rate
    cutoff_rad_s: float  # the torque's low-pass (applied twice, zero-phase)

    def torque_filter(self, x: np.ndarray) -> np.ndarray:
        """x (M, ...) filtered along axis 0 as the zero-phase torque is, each piece on its own."""
        x = np.asarray(x, dtype=float)
        out = x.copy()
        for a, b in self.pieces:
            part = x[a:b]
            for _ in range(2):
                part = lowpass(part, self.cutoff_rad_s, self.rate_hz, zero_phase=True)
            out[a:b] = part
        return out

    @cached_property
    def pieces(self) -> list[tuple[int, int]]:
        """(first, end) rows of each continuous piece long enough to filter."""
        bounds = [0, *(np.flatnonzero(np.diff(self.segment)) + 1).tolist(), len(self.segment)]
        return [(a, b) for a, b in zip(bounds[:-1], bounds[1:]) if b - a >= 2]

    @cached_property
    def filtered(self) -> tuple[np.ndarray, np.ndarray | None]:
        """The learning and the context joints' angles filtered as the torque is."""
        context = None if self.context_q is None else self.torque_filter(self.context_q)
        return self.torque_filter(self.q), context


@dataclass(frozen=True)
class AngleRows:
    """Which rows of an AngleSeries a Dataset's rows are."""

    series: AngleSeries
    rows: np.ndarray  # (N,) int

    def subset(self, index) -> AngleRows:
        return AngleRows(self.series, np.asarray(self.rows)[np.asarray(index)])


def _at_rest(ds: Dataset, q: np.ndarray, context_q: np.ndarray | None) -> Dataset:
    """A Dataset of the series' rows with angles `q` (and the context joints' `context_q`), at rest."""
    from .dataset import Dataset

    s = ds.angle.series
    zero = np.zeros_like(q)
    ctx = {}
    if ds.context_names:
        czero = np.zeros_like(context_q)
        ctx = dict(context_names=ds.context_names, context_q=context_q, context_dq=czero, context_ddq=czero)
    return Dataset(ds.joint_names, s.t, q, zero, zero, zero, np.ones(q.shape, dtype=bool), s.rate_hz,
                   s.segment, dict(ds.meta), **ctx)


def angle_part_correction(ds: Dataset, columns: Callable[[Dataset], np.ndarray | None]) -> np.ndarray | None:
    """(N, ...) L4[c(q, 0, 0)] - c(L4[q], 0, 0) on `ds`'s rows (module docstring), for `columns`
    (a Dataset -> its (N, J, ...) columns); None when `ds` carries no angle series or the columns at rest
    are not finite (such columns are left as they are)."""
    if ds.angle is None:
        return None
    s = ds.angle.series
    if ds.context_names and (s.context_q is None or s.context_q.shape[1] != len(ds.context_names)):
        return None
    try:
        with np.errstate(all="ignore"):  # a column undefined at rest is left as it is
            raw = columns(_at_rest(ds, s.q, s.context_q))
            if raw is None:
                return None
            raw = np.asarray(raw, dtype=float)
            flat = raw.reshape(len(raw), -1)
            some = np.any(flat != 0, axis=0)  # the columns with an angle-only part (not friction, inertia)
            if not some.any():
                return np.zeros((len(ds.angle.rows), *raw.shape[1:]))
            smooth = columns(_at_rest(ds, *s.filtered))
    except (ArithmeticError, ValueError):
        return None
    if smooth is None:
        return None
    smooth = np.asarray(smooth, dtype=float)
    if raw.shape != smooth.shape or not (np.isfinite(raw).all() and np.isfinite(smooth).all()):
        return None
    out = np.zeros_like(flat)
    out[:, some] = s.torque_filter(flat[:, some]) - smooth.reshape(len(smooth), -1)[:, some]
    return out.reshape(raw.shape)[ds.angle.rows]


def columns_on(ds: Dataset, columns: Callable[[Dataset], np.ndarray | None]) -> np.ndarray | None:
    """`columns(ds)`, with its angle-only part filtered as the torque is when `ds` carries an angle
    series (the zero-phase signals of preprocessed data); exactly `columns(ds)` otherwise."""
    X = columns(ds)
    if X is None or ds.angle is None:
        return X
    X = np.asarray(X, dtype=float)
    correction = angle_part_correction(ds, columns)
    if correction is None or correction.shape != X.shape:
        return X
    return X + correction
